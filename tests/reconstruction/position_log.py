"""A flight log of positions only, from positions in a UTM zone (the synthetic flights'
logs)."""

from __future__ import annotations

import numpy as np
from pyproj import Transformer

from worker.pipeline.ingest.flight_log import FlightLog, build_flight_log


def position_log(t: np.ndarray, positions: np.ndarray, epsg: int) -> FlightLog:
    """A generic CSV log with a row per time `t` at `positions` (N, 3: east, north, up
    in EPSG `epsg`)."""
    lon, lat = Transformer.from_crs(f"EPSG:{epsg}", "EPSG:4326", always_xy=True).transform(
        positions[:, 0], positions[:, 1]
    )
    rows = [
        {"line": i + 2, "t": float(t[i]), "lat": lat[i], "lon": lon[i], "alt": positions[i, 2]}
        for i in range(t.size)
    ]
    return build_flight_log("flight.csv", "generic_csv", rows)
