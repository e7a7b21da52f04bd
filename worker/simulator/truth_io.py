"""Writing the ground truth: rasters as GeoTIFF (tiled, deflate, real CRS, nodata) and
camera trajectories as CSV."""

from __future__ import annotations

import csv
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import rasterio

from worker.simulator.camera import quaternion_from_rotation
from worker.simulator.georef import Grid, SceneFrame

DSM_NODATA = -9999.0
MASK_NODATA = 255


def write_raster(
    path: Path,
    data: np.ndarray,
    grid: Grid,
    frame: SceneFrame,
    nodata: float | int | None,
    description: str = "",
    band_names: list[str] | None = None,
) -> Path:
    """Write a (h, w) or (h, w, bands) array as a tiled, deflate-compressed GeoTIFF."""
    arr = data if data.ndim == 3 else data[..., None]
    h, w, bands = arr.shape
    if (h, w) != grid.shape:
        raise ValueError(f"raster {arr.shape[:2]} does not match grid {grid.shape}")
    dtype = arr.dtype
    predictor = 3 if np.issubdtype(dtype, np.floating) else 2
    profile = {
        "driver": "GTiff",
        "width": w,
        "height": h,
        "count": bands,
        "dtype": dtype.name,
        "crs": frame.crs,
        "transform": grid.transform(frame),
        "nodata": nodata,
        "tiled": True,
        "blockxsize": 256,
        "blockysize": 256,
        "compress": "deflate",
        "zlevel": 3,
        "predictor": predictor,
        "interleave": "pixel" if bands > 1 else "band",
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with rasterio.open(path, "w", **profile) as dst:
        for b in range(bands):
            dst.write(np.ascontiguousarray(arr[..., b]), b + 1)
            if band_names:
                dst.set_band_description(b + 1, band_names[b])
        if description:
            dst.update_tags(DESCRIPTION=description)
        if bands == 3 and dtype == np.uint8:
            dst.colorinterp = [
                rasterio.enums.ColorInterp.red,
                rasterio.enums.ColorInterp.green,
                rasterio.enums.ColorInterp.blue,
            ]
    return path


TRAJECTORY_COLUMNS = [
    "frame",
    "t_s",
    "utc",
    "e",
    "n",
    "u",
    "x_local",
    "y_local",
    "lat",
    "lon",
    "alt",
    "camera_yaw_deg",
    "camera_pitch_deg",
    "camera_roll_deg",
    "aircraft_yaw_deg",
    "aircraft_pitch_deg",
    "aircraft_roll_deg",
    "qw",
    "qx",
    "qy",
    "qz",
    "ve",
    "vn",
    "vu",
]


def write_trajectory_csv(
    path: Path,
    frame_ids: np.ndarray,
    times: np.ndarray,
    start_utc: datetime,
    frame: SceneFrame,
    position: np.ndarray,
    r_wc: np.ndarray,
    camera_ypr: np.ndarray,
    aircraft_ypr: np.ndarray,
    velocity: np.ndarray,
) -> int:
    """True camera poses, one row per frame (or image). Positions in the scene CRS (e, n, u)
    and WGS84 (lat, lon, alt = u); `q*` is the world-from-camera rotation (world = e, n,
    u; camera = x right, y down, z forward)."""
    e, n = frame.to_world(position[:, 0], position[:, 1])
    lon, lat = frame.lonlat(position[:, 0], position[:, 1])
    q = quaternion_from_rotation(r_wc)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(TRAJECTORY_COLUMNS)
        for i in range(len(times)):
            utc = start_utc + timedelta(seconds=float(times[i]))
            w.writerow(
                [
                    int(frame_ids[i]),
                    f"{times[i]:.6f}",
                    utc.strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z",
                    f"{e[i]:.4f}",
                    f"{n[i]:.4f}",
                    f"{position[i, 2]:.4f}",
                    f"{position[i, 0]:.4f}",
                    f"{position[i, 1]:.4f}",
                    f"{lat[i]:.9f}",
                    f"{lon[i]:.9f}",
                    f"{position[i, 2]:.4f}",
                    f"{camera_ypr[i, 0]:.4f}",
                    f"{camera_ypr[i, 1]:.4f}",
                    f"{camera_ypr[i, 2]:.4f}",
                    f"{aircraft_ypr[i, 0]:.4f}",
                    f"{aircraft_ypr[i, 1]:.4f}",
                    f"{aircraft_ypr[i, 2]:.4f}",
                    f"{q[i, 0]:.8f}",
                    f"{q[i, 1]:.8f}",
                    f"{q[i, 2]:.8f}",
                    f"{q[i, 3]:.8f}",
                    f"{velocity[i, 0]:.4f}",
                    f"{velocity[i, 1]:.4f}",
                    f"{velocity[i, 2]:.4f}",
                ]
            )
    return len(times)


def read_trajectory_csv(path: Path) -> dict[str, np.ndarray]:
    """Columns of a trajectory CSV as arrays (utc as strings)."""
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    out: dict[str, np.ndarray] = {}
    for col in TRAJECTORY_COLUMNS:
        vals = [r[col] for r in rows]
        out[col] = np.array(vals) if col == "utc" else np.array(vals, dtype=np.float64)
    return out
