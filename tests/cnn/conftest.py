"""Small DSM pairs like the paper's: a sand mound at 2 cm/pixel, before and after a slide
on its flank (the simulator's landslide model), and a pair with no change at all. Both
DSMs of a pair are degraded independently by the reconstruction-noise model, as the
model's training DSMs are. Runs of the cnn comparison are session-scoped.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from rasterio.transform import Affine, from_origin

from worker.pipeline.comparison import ComparisonOptions, ComparisonResult, compare_dsms
from worker.pipeline.raster_io import write_geotiff
from worker.simulator.georef import Grid
from worker.simulator.landslide import SlideSpec, apply_slide
from worker.training.dataset import write_manifest
from worker.training.recon_noise import degrade

PIXEL_M = 0.02
SIZE_M = 12.0
CRS = "EPSG:32654"


@dataclass
class MoundPair:
    pre: np.ndarray
    post: np.ndarray
    mask: np.ndarray  # bool: cells the slide changed
    volume_loss_m3: float
    transform: Affine

    def write(self, folder: Path) -> tuple[Path, Path]:
        write_geotiff(folder / "pre.tif", self.pre, self.transform, CRS)
        write_geotiff(folder / "post.tif", self.post, self.transform, CRS)
        return folder / "pre.tif", folder / "post.tif"


def mound_pair(slide: bool, seed: int) -> MoundPair:
    """A 1.3 m sand mound (radii 2.4 x 2.0 m); with `slide`, its SSE flank collapses."""
    grid = Grid.centered(SIZE_M, SIZE_M, PIXEL_M)
    x, y = grid.mesh()
    radius = 2.4
    floor = 25.0 + 0.004 * x
    ground = (
        floor + 1.3 * np.clip(1 - (x / radius) ** 2 - (y / (0.85 * radius)) ** 2, 0, None) ** 1.5
    )
    post = ground.copy()
    mask = np.zeros(ground.shape, bool)
    loss = 0.0
    if slide:
        azimuth = np.radians(150.0)
        d = np.array([np.sin(azimuth), np.cos(azimuth)])
        reach = 1 / np.sqrt((d[0] / radius) ** 2 + (d[1] / (0.85 * radius)) ** 2)
        spec = SlideSpec(
            name="fixture",
            toe_xy=(0.97 * reach * d[0], 0.97 * reach * d[1]),
            azimuth_deg=150.0,
            length_m=1.35 * reach,
            width_m=1.43 * 0.85 * radius,
            failure_angle_deg=11.2,
            head_angle_deg=33.0,
            flank_angle_deg=31.0,
            runout_m=0.58 * reach,
            deposit_angle_deg=20.0,
        )
        result = apply_slide(ground, grid, spec, np.random.default_rng(seed), floor=floor)
        post[result.rows, result.cols] += result.delta
        mask[result.rows, result.cols] = result.changed
        loss = result.depleted_m3
    return MoundPair(
        pre=degrade(ground, PIXEL_M, np.random.default_rng([seed, 1])),
        post=degrade(post, PIXEL_M, np.random.default_rng([seed, 2])),
        mask=mask,
        volume_loss_m3=loss,
        transform=from_origin(419_000.0, 3_990_000.0, PIXEL_M, PIXEL_M),
    )


@dataclass
class CnnRun:
    pair: MoundPair
    paths: tuple[Path, Path]
    result: ComparisonResult


def cnn_options() -> ComparisonOptions:
    """The cnn method, co-registration fitted on 50 k pixels instead of 200 k: the same
    detections on these 0.36 Mpx pairs (measured), in a third of the time."""
    options = ComparisonOptions(method="cnn")
    options.coregister.subsample = 50_000
    return options


def run_cnn(base: Path, pair: MoundPair) -> CnnRun:
    paths = pair.write(base / "input")
    result = compare_dsms(*paths, base / "work", cnn_options())
    return CnnRun(pair, paths, result)


@pytest.fixture(scope="session")
def make_mound_pair():
    """The pair builder itself, for tests that alter a pair before running it."""
    return mound_pair


@pytest.fixture(scope="session")
def cnn_slide_run(tmp_path_factory: pytest.TempPathFactory) -> CnnRun:
    return run_cnn(tmp_path_factory.mktemp("cnn-slide"), mound_pair(True, 3))


@pytest.fixture(scope="session")
def cnn_still_run(tmp_path_factory: pytest.TempPathFactory) -> CnnRun:
    return run_cnn(tmp_path_factory.mktemp("cnn-still"), mound_pair(False, 4))


def write_separable_dataset(base: Path) -> Path:
    """Two 240 x 240 pairs at 2 cm: rough flat ground; square pits 0.4 m deep are slides.
    Returns the dataset manifest; its test region is the top half of pair p1."""
    rng = np.random.default_rng(0)
    transform = from_origin(500_000, 4_000_000, PIXEL_M, PIXEL_M)
    pairs = []
    for k in range(2):
        pre = 10 + rng.normal(0, 0.01, (240, 240))
        post = pre + rng.normal(0, 0.01, (240, 240))
        mask = np.zeros((240, 240), np.uint8)
        for r, c in rng.integers(10, 180, size=(4, 2)):
            post[r : r + 50, c : c + 50] -= 0.4
            mask[r : r + 50, c : c + 50] = 1
        for name, array in (("pre", pre), ("post", post), ("mask", mask)):
            write_geotiff(base / f"{name}{k}.tif", array, transform, CRS)
        pairs.append(
            {"id": f"p{k}", "pre": f"pre{k}.tif", "post": f"post{k}.tif", "mask": f"mask{k}.tif"}
        )
    region = np.zeros((240, 240), np.uint8)
    region[:120] = 1
    write_geotiff(base / "region.tif", region, transform, CRS)
    write_manifest(
        base / "dataset.json",
        {
            "name": "separable",
            "interim": True,
            "pairs": pairs,
            "regions": {"top": "region.tif"},
            "test": {"pair": "p1", "region": "top"},
        },
    )
    return base / "dataset.json"
