"""The simulator-video generator's pair, assembled from a simulation's truth and two
reconstructed DSMs (hand-made here: simulating and reconstructing take minutes)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rasterio.transform import from_origin

from worker.detection_bench.reconstructed_pairs import (
    SUMMARY_FILE,
    ReconstructedPairs,
    _pair,
    _reconstructed,
)
from worker.pairgen.pair import PairUnavailable
from worker.pipeline.raster_io import write_geotiff

CRS = "EPSG:32654"
WEST, NORTH, TRUTH_PX, RECON_PX = 370_000.0, 4_074_000.0, 0.2, 0.4
ROWS, COLS = 100, 150  # truth grid: 20 m x 30 m


class Manifest:
    """The part of a simulation's manifest the generator reads."""

    def __init__(self, folder: Path, truth: dict[tuple[int, str], np.ndarray]) -> None:
        self.data: dict[str, Any] = {
            "crs": CRS,
            "grid": {
                "west": WEST,
                "north": NORTH,
                "east": WEST + COLS * TRUTH_PX,
                "south": NORTH - ROWS * TRUTH_PX,
                "res_m": TRUTH_PX,
            },
        }
        self.paths = {}
        for (step, key), values in truth.items():
            path = folder / f"step{step}-{key}.tif"
            write_geotiff(path, values, from_origin(WEST, NORTH, TRUTH_PX, TRUTH_PX), CRS)
            self.paths[(step, key)] = path

    def truth(self, step: int, key: str = "dsm") -> Path:
        return self.paths[(step, key)]


def _scene() -> tuple[dict[tuple[int, str], np.ndarray], np.ndarray]:
    rows, cols = np.mgrid[0:ROWS, 0:COLS].astype(np.float32)
    dem1 = 500.0 + 0.3 * rows * TRUTH_PX + 0.1 * cols * TRUTH_PX
    events = np.zeros((ROWS, COLS), np.float32)
    events[20:40, 30:60] = 1  # seen by both surveys
    events[60:100, 100:120] = 2  # seen on a fifth of it: left out
    dem2 = dem1 - 2.0 * (events == 1) - 1.0 * (events == 2)
    trees1 = np.zeros_like(dem1)
    trees1[10:20, 90:100] = 8.0  # felled before the second survey
    trees1[50:56, 10:16] = 6.0  # stands in both
    trees2 = trees1.copy()
    trees2[10:20, 90:100] = 0.0
    truth = {
        (1, "dem"): dem1,
        (2, "dem"): dem2,
        (1, "dsm"): dem1 + trees1,
        (2, "dsm"): dem2 + trees2,
        (2, "events"): events,
    }
    return truth, dem1


def _reconstruction(path: Path, dsm: np.ndarray, offset_m: float) -> None:
    """The truth DSM at 0.4 m over rows 0-67 (of the truth grid), raised by offset_m."""
    coarse = dsm.reshape(ROWS // 2, 2, COLS // 2, 2).mean(axis=(1, 3))[:34] + offset_m
    write_geotiff(
        path, coarse.astype(np.float32), from_origin(WEST, NORTH, RECON_PX, RECON_PX), CRS
    )


def test_the_pair_holds_what_both_surveys_saw(tmp_path):
    truth, _ = _scene()
    manifest = Manifest(tmp_path, truth)
    _reconstruction(tmp_path / "pre.tif", truth[(1, "dsm")], 0.0)
    _reconstruction(tmp_path / "post.tif", truth[(2, "dsm")], 0.3)
    surveys = [{"dsm": str(tmp_path / "pre.tif")}, {"dsm": str(tmp_path / "post.tif")}]

    pair = _pair(ReconstructedPairs(tmp_path), manifest, surveys, seed=3, no_change=False)

    assert pair.generator == "simulator-video" and pair.pixel_size == RECON_PX
    # Cut to where both surveys have elevations (resampling loses the last column).
    assert pair.shape == (34, 74)
    (slide,) = pair.slides  # the slide seen on a fifth is left out
    assert slide.id == 1 and slide.area_px == 10 * 15
    assert slide.max_depth_m == pytest.approx(2.0, abs=0.01)
    assert slide.volume_loss_m3 == pytest.approx(2.0 * 4.0 * 6.0, rel=0.01)
    assert set(np.unique(pair.slide_labels)) == {0, 1}
    assert np.all(np.isnan(pair.pre[30:34, 50:60])) and np.all(np.isnan(pair.post[30:34, 50:60]))
    # The surveys' own error: the post survey 0.3 m too high, nothing else.
    error = pair.observation_error[np.isfinite(pair.observation_error)]
    assert np.median(error) == pytest.approx(0.3, abs=0.01) and pair.error_nmad_m < 0.01
    # The felled stand is a surface change; the standing tree is not.
    assert pair.surface_change[5:10, 45:50].all()
    assert not pair.surface_change[25:28, 5:8].any()
    assert pair.description["gnss"] in ("rtk", "standalone")
    json.dumps(pair.truth_dict())  # written beside the pair as it stands


def test_a_flight_that_failed_to_reconstruct_makes_the_pair_unavailable(tmp_path):
    folder = tmp_path / "step2"
    folder.mkdir()
    (folder / SUMMARY_FILE).write_text('{"error": "step 2: the reconstruction failed: no motion"}')
    with pytest.raises(PairUnavailable, match="no motion"):
        _reconstructed(manifest=None, step=2, folder=folder)


def test_pairs_and_twins_differ_only_by_the_slides(tmp_path):
    generator = ReconstructedPairs(tmp_path)
    pair, twin = generator.simulation(5, False), generator.simulation(5, True)
    assert pair.seed == twin.seed and pair.gnss == twin.gnss
    assert pair.slides and 3 <= pair.random_slides <= 6
    assert not twin.slides and twin.random_slides == 0
    assert generator.simulation(6, False) != pair
