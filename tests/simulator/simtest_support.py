"""Shared, cached simulator runs for the tests in this directory (one per session)."""

from __future__ import annotations

import atexit
import functools
import shutil
import tempfile
from pathlib import Path

import numpy as np
import rasterio

from worker.simulator.georef import Grid
from worker.simulator.manifest import Manifest
from worker.simulator.simulate import SimulationOptions, simulate_scenario

SHORT_OPTIONS = SimulationOptions(
    seed=7, steps=2, video_seconds=3.0, gnss="standalone", log_time_offset_s=0.25
)


def _tmpdir(prefix: str) -> Path:
    d = Path(tempfile.mkdtemp(prefix=prefix))
    atexit.register(shutil.rmtree, d, True)
    return d


@functools.cache
def short_run() -> Manifest:
    """paper-mounds, 2 steps, 3 s of 640x360 video per step, stand-alone GNSS."""
    return simulate_scenario("paper-mounds", _tmpdir("simtest-short-") / "run", SHORT_OPTIONS)


@functools.cache
def truth_only_run(seed: int) -> Manifest:
    """The same scenario and options, truth only (no survey files)."""
    opts = SimulationOptions(
        seed=seed, steps=2, video_seconds=3.0, survey="none", log_time_offset_s=0.25
    )
    return simulate_scenario("paper-mounds", _tmpdir(f"simtest-truth{seed}-") / "run", opts)


@functools.cache
def image_run() -> Manifest:
    """One step flown as an image set (small images), without GNSS errors."""
    opts = SimulationOptions(
        seed=11,
        steps=1,
        survey="images",
        gnss="none",
        image_width=456,
        image_height=304,
        image_overlap=0.6,
        csv_units="meters",
    )
    return simulate_scenario("paper-mounds", _tmpdir("simtest-images-") / "run", opts)


# SfM options light enough for image_run's small photos (no upsampling before SIFT, fewer
# features and pairs): every photo is still registered, in a fifth of the time.
LIGHT_SFM = {
    "max_features": 1500,
    "first_octave": 0,
    "sequential_overlap": 4,
    "spatial_neighbors": 8,
}


def read_raster(path: Path) -> tuple[np.ndarray, rasterio.Affine, str, float | None]:
    with rasterio.open(path) as src:
        return src.read(1), src.transform, src.crs.to_string(), src.nodata


def local_grid(manifest: Manifest) -> Grid:
    """The truth grid in the manifest's local frame."""
    g = manifest.data["grid"]
    f = manifest.data["frame"]
    return Grid(
        x_left=g["west"] - f["origin_e"],
        y_top=g["north"] - f["origin_n"],
        res=g["res_m"],
        width=g["width"],
        height=g["height"],
    )
