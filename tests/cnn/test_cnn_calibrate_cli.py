"""`slidewatch calibrate` on small mound pairs with the shipped model."""

import json
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from tests.cnn.conftest import CRS, mound_pair
from worker.commands.calibrate import calibrate
from worker.pipeline.cnn.options import default_model_path
from worker.pipeline.raster_io import write_geotiff
from worker.training.dataset import write_manifest


def write_pair_dataset(folder: Path, slide: bool, seed: int) -> Path:
    pair = mound_pair(slide, seed)
    pre, post = pair.write(folder)
    write_geotiff(folder / "mask.tif", pair.mask.astype(np.uint8), pair.transform, CRS)
    write_manifest(
        folder / "dataset.json",
        {
            "name": f"mound-{'slide' if slide else 'still'}",
            "pairs": [{"id": "p", "pre": pre.name, "post": post.name, "mask": "mask.tif"}],
        },
    )
    return folder / "dataset.json"


def test_calibrate_finds_the_slide_and_chooses_a_min_score(tmp_path):
    still = write_pair_dataset(tmp_path / "still", False, 4)
    slide = write_pair_dataset(tmp_path / "slide", True, 3)
    result = CliRunner().invoke(
        calibrate,
        [
            "--model",
            str(default_model_path()),
            "--no-change",
            str(still),
            "--slides",
            f"{slide}#p",
            "--work-dir",
            str(tmp_path / "work"),
        ],
    )
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    # The planted slide (24 m2) is found as one landslide well above every false alarm.
    (biggest, *_) = sorted(report["landslides_score_area_m2"], key=lambda g: -g[1])
    assert biggest[1] > 15 and biggest[0] > 0.85
    assert all(area < 1 for _, area in report["false_alarms_score_area_m2"])
    assert 0 < report["min_score"] <= biggest[0]
    assert "published" not in report


def test_calibrate_names_an_unreadable_dataset(tmp_path):
    result = CliRunner().invoke(
        calibrate,
        [
            "--model",
            str(default_model_path()),
            "--no-change",
            str(tmp_path / "missing.json"),
            "--slides",
            str(tmp_path / "missing.json"),
            "--work-dir",
            str(tmp_path / "work"),
        ],
    )
    assert result.exit_code == 2
    assert "cannot read the dataset manifest" in result.output
