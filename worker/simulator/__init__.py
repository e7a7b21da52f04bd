"""Synthetic drone surveys of landslides with known truth (issue 3).

A plain library (no web, queue or database imports): `simulate_scenario` builds a
seeded scene (`paper-mounds`, the paper's one-tenth-scale sand field, or `hillslope`,
a real-scale forested slope), lets landslides happen step by step, renders drone
surveys (MP4 video with DJI SRT, AirData CSV, or JPEG image sets with EXIF/XMP) and
writes the truth (DSM/DEM/ortho/masks as GeoTIFF, camera trajectories) with a
`manifest.json` describing every file.
"""

from typing import Any

__all__ = ["Manifest", "SimulationOptions", "simulate_scenario"]


def __getattr__(name: str) -> Any:
    # Lazy, so that render worker processes do not import the whole simulator.
    if name == "Manifest":
        from worker.simulator.manifest import Manifest

        return Manifest
    if name in ("SimulationOptions", "simulate_scenario"):
        from worker.simulator import simulate

        return getattr(simulate, name)
    raise AttributeError(name)
