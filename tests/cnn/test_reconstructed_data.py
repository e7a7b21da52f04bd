"""Detection datasets on slidewatch's own reconstructions of simulated flights.

`register_to_truth` is checked on hand-made rasters (a known shift on another grid);
`reconstructed_dataset` end to end on a short simulation of the paper's field: two steps,
each survey video reconstructed by the SLAM pipeline, registered onto the truth grid, the
simulator's masks as labels.
"""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from rasterio.transform import from_origin

from worker.pipeline.cnn.patches import extract_patches
from worker.pipeline.raster_io import read_elevation, write_geotiff
from worker.training.dataset import load_manifest, load_pair
from worker.training.reconstructed_data import (
    REGISTRATION,
    RegistrationToTruth,
    reconstructed_dataset,
    register_to_truth,
    survey_simulation,
)

CRS = "EPSG:32654"


def mounds(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Two sand mounds on a gently tilted floor (metres)."""
    z = 25.0 + 0.01 * x
    for cx, cy, r in ((3.0, 3.0, 2.0), (7.0, 6.0, 1.5)):
        z = z + 1.2 * np.clip(1 - ((x - cx) ** 2 + (y - cy) ** 2) / r**2, 0, None) ** 1.5
    return z


def test_register_to_truth_removes_a_known_shift_and_lands_on_the_truth_grid(tmp_path: Path):
    west, north, px = 419000.0, 3990010.0, 0.02
    rows, cols = np.mgrid[0:500, 0:500]
    x, y = (cols + 0.5) * px, 10.0 - (rows + 0.5) * px
    write_geotiff(tmp_path / "truth.tif", mounds(x, y), from_origin(west, north, px, px), CRS)
    # The "reconstruction": 3 cm pixels on another origin, displaced by (+0.25, -0.15,
    # +0.08) m, with 1 cm noise and a hole.
    shift = np.array([0.25, -0.15, 0.08])
    rpx = 0.03
    rr, rc = np.mgrid[0:300, 0:300]
    rx, ry = 0.5 + (rc + 0.5) * rpx, 9.5 - (rr + 0.5) * rpx
    rng = np.random.default_rng(0)
    recon = mounds(rx - shift[0], ry - shift[1]) + shift[2] + rng.normal(0, 0.01, rx.shape)
    recon[100:130, 100:130] = np.nan
    write_geotiff(
        tmp_path / "recon.tif",
        recon.astype(np.float32),
        from_origin(west + 0.5, north - 0.5, rpx, rpx),
        CRS,
    )

    result = register_to_truth(tmp_path / "recon.tif", tmp_path / "truth.tif", tmp_path / "out.tif")

    # The correction applied is minus the displacement, within 1 cm horizontally and
    # 5 mm vertically.
    np.testing.assert_allclose(result.shift_enu_m[:2], -shift[:2], atol=0.01)
    assert abs(result.shift_enu_m[2] + shift[2]) < 0.005
    out, profile = read_elevation(tmp_path / "out.tif")
    truth, truth_profile = read_elevation(tmp_path / "truth.tif")
    assert out.shape == truth.shape and profile["transform"] == truth_profile["transform"]
    both = np.isfinite(out) & np.isfinite(truth)
    error = (out - truth)[both]
    assert 1.4826 * np.median(np.abs(error - np.median(error))) < 0.015
    assert result.nmad_after_m < min(0.015, result.nmad_before_m)
    # The footprint of the reconstruction (9 x 9 m of the 10 x 10 m grid, less the hole).
    assert 0.75 < result.valid_fraction < 0.81


def test_a_reconstruction_far_from_its_truth_is_refused_with_its_figures():
    good = RegistrationToTruth((0.01, 0.0, 0.0), 0.05, 0.04, 0.5)
    good.check(0.02, "step 1")  # 2 pixels
    bad = RegistrationToTruth((-1.26, -1.77, 2.04), 0.78, 0.63, 0.2)
    with pytest.raises(ValueError, match=r"step 3: .* NMAD of 0\.630 m \(31\.5 pixels\)"):
        bad.check(0.02, "step 3")


@pytest.fixture(scope="module")
def short_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """paper-mounds, 2 steps, 4 s of video at 15 fps each, reconstructed."""
    out = tmp_path_factory.mktemp("reconstructed")
    simulation = dataclasses.replace(
        survey_simulation(seed=3, steps=2), video_seconds=4.0, fps=15.0, workers=1
    )
    return reconstructed_dataset(out, "paper-mounds", simulation, log=lambda _: None)


def test_reconstructed_dataset_pairs_reconstructed_dsms_with_the_simulators_masks(
    short_dataset: Path,
):
    raw = json.loads(short_dataset.read_text())
    assert raw["interim"] is False
    assert raw["dsm_source"] == "slidewatch reconstruction of the simulated surveys"
    manifest = load_manifest(short_dataset)
    (spec,) = manifest.pairs
    assert spec.id == "step1-step2"
    assert "reconstruction/step1/" in str(spec.pre) and "reconstruction/step2/" in str(spec.post)
    pair = load_pair(spec, truth=True)
    assert pair.pixel_size_m == pytest.approx(0.02)
    for dsm, truth in ((pair.pre, pair.truth_pre), (pair.post, pair.truth_post)):
        both = np.isfinite(dsm) & np.isfinite(truth)
        assert both.mean() > 0.15  # a 4 s pass covers a strip of the 36 m field
        error = (dsm - truth)[both]
        # Reconstruction error remains (it is the point), at the size of a few pixels.
        nmad = 1.4826 * np.median(np.abs(error - np.median(error)))
        assert 0.005 < nmad < 0.08
        assert abs(np.median(error)) < 0.02
    patches = extract_patches(pair.pre, pair.post, pair.mask, pair.pixel_size_m, group=spec.id)
    assert patches.labels.sum() > 10, "the step-2 slides lie inside the reconstructed strip"
    summaries = sorted(short_dataset.parent.glob(f"reconstruction/*/{REGISTRATION}"))
    assert [p.parent.name for p in summaries] == ["step1", "step2"]
    for path in summaries:
        summary = json.loads(path.read_text())
        assert summary["method"] == "slam"
        assert summary["registration_to_truth"]["nmad_after_m"] < 0.08


def test_reconstructed_dataset_is_not_redone(short_dataset: Path):
    registered = sorted(short_dataset.parent.glob("reconstruction/*/registered.tif"))
    stamps = [p.stat().st_mtime_ns for p in registered]
    simulation = dataclasses.replace(
        survey_simulation(seed=3, steps=2), video_seconds=4.0, fps=15.0, workers=1
    )
    again = reconstructed_dataset(short_dataset.parent, "paper-mounds", simulation)
    assert again == short_dataset
    assert [p.stat().st_mtime_ns for p in registered] == stamps
