"""The comparison's cnn method through the library API and the CLI; bad input."""

import json

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rio_cogeo.cogeo import cog_validate

from tests.cnn.conftest import cnn_options
from worker.commands.detect import detect
from worker.pipeline.cnn.detect_stage import detect_cnn
from worker.pipeline.comparison import (
    ComparisonOptions,
    compare_dsms,
    run_stage,
    stages_for,
)
from worker.pipeline.detection_methods import method_names
from worker.pipeline.errors import InputError
from worker.pipeline.raster_io import write_geotiff
from worker.training.evaluation import rasterize_detections

CNN_FILES = {
    "pre_aligned.tif",
    "post_aligned.tif",
    "post_coregistered.tif",
    "stable_mask.tif",
    "dh.tif",
    "significance.tif",
    "lod.tif",
    "error_model.json",
    "probability.tif",
    "cells.geojson",
    "detections.geojson",
}


def test_stages_per_method():
    assert method_names() == ("threshold", "scored", "cnn")
    assert stages_for("threshold") == ("align", "coregister", "difference", "vectorize")
    assert stages_for("cnn") == ("align", "coregister", "difference", "detect")
    with pytest.raises(InputError, match="unknown detection method"):
        stages_for("magic")
    with pytest.raises(InputError, match="unknown detection method"):
        ComparisonOptions.from_dict({"method": "magic"})
    options = ComparisonOptions.from_dict({"method": "cnn", "cnn": {"tile_px": 512}})
    assert options.detection.tile_px == 512
    assert ComparisonOptions.from_dict(options.to_dict()) == options


def test_layout_and_results(cnn_slide_run):
    work = cnn_slide_run.result.work_dir
    assert {p.name for p in work.iterdir()} == CNN_FILES
    assert list(cnn_slide_run.result.results) == list(stages_for("cnn"))
    detect_result = cnn_slide_run.result.results["detect"]
    assert detect_result["method"] == "cnn" and detect_result["detections"] == 1
    json.dumps(cnn_slide_run.result.results)
    valid, errors, _ = cog_validate(str(work / "probability.tif"), quiet=True)
    assert valid, errors
    with rasterio.open(work / "probability.tif") as src:
        prob = src.read(1, masked=True)
        assert src.dtypes[0] == "float32" and prob.min() >= 0 and prob.max() <= 1
    cells = json.loads((work / "cells.geojson").read_text())
    assert cells["cell_px"] == 32 and len(cells["features"]) == detect_result["positive_cells"]
    for cell in cells["features"]:
        assert cell["properties"]["fraction"] > 0.10
    feature = json.loads((work / "detections.geojson").read_text())["features"][0]
    # The one detection record of every method (detection_record.py); no intervals here.
    assert set(feature["properties"]) == {
        "area_m2",
        "volume_loss_m3",
        "volume_gain_m3",
        "max_abs_dh_m",
        "score",
        "method",
        "model_version",
        "uncertainty",
    }
    assert feature["properties"]["uncertainty"] is None
    assert 0 < feature["properties"]["score"] <= 1


def test_stages_of_another_method_are_refused(cnn_slide_run, tmp_path):
    pre, post = cnn_slide_run.paths
    with pytest.raises(InputError, match=r"not a stage of the comparison \(cnn\)"):
        run_stage("vectorize", pre, post, tmp_path, {"method": "cnn"})
    with pytest.raises(InputError, match=r"not a stage of the comparison \(threshold\)"):
        run_stage("detect", pre, post, tmp_path, {"method": "threshold"})


def test_different_resolution_and_crs_are_aligned_first(cnn_slide_run, tmp_path):
    """The post DSM in lon/lat at a coarser pixel: align brings it onto pre's grid."""
    src_crs = rasterio.crs.CRS.from_user_input("EPSG:32654")
    with rasterio.open(cnn_slide_run.paths[1]) as src:
        transform, width, height = rasterio.warp.calculate_default_transform(
            src.crs, "EPSG:4326", src.width, src.height, *src.bounds, resolution=2.6e-7
        )
        post = np.full((height, width), np.nan, np.float32)
        rasterio.warp.reproject(
            src.read(1),
            post,
            src_transform=src.transform,
            src_crs=src_crs,
            dst_transform=transform,
            dst_crs="EPSG:4326",
            src_nodata=-9999,
            dst_nodata=np.nan,
            resampling=rasterio.enums.Resampling.bilinear,
        )
    write_geotiff(tmp_path / "post.tif", post, transform, "EPSG:4326")
    result = compare_dsms(
        cnn_slide_run.paths[0],
        tmp_path / "post.tif",
        tmp_path / "work",
        cnn_options(),
    )
    assert result.results["align"]["crs"] == src_crs.to_string()
    assert result.summary()["detections"] == 1


def test_nodata_is_never_a_landslide(tmp_path, make_mound_pair):
    pair = make_mound_pair(True, 3)
    truth = pair.mask
    rows, _ = np.nonzero(truth)
    hole = np.zeros(truth.shape, bool)
    hole[rows.min() : (rows.min() + rows.max()) // 2, :] = True  # half of the slide
    pair.post[hole] = np.nan
    paths = pair.write(tmp_path / "input")
    result = compare_dsms(*paths, tmp_path / "work", cnn_options())
    work = result.work_dir
    with rasterio.open(work / "probability.tif") as src:
        prob = src.read(1, masked=True)
        found = rasterize_detections(result.detections_path, src.shape, src.transform, src.crs)
    with rasterio.open(work / "post_coregistered.tif") as src:
        missing = src.read(1, masked=True).mask
    assert prob.mask[missing].all()  # no probability where a DSM has no data
    assert not (found & missing).any()  # and no landslide polygon over it
    assert result.summary()["detections"] >= 1  # the visible half is still found


def test_rasters_smaller_than_a_patch_are_refused(tmp_path):
    transform = rasterio.transform.from_origin(500_000, 4_000_000, 0.05, 0.05)
    z = np.full((40, 60), 10.0)
    for name in ("pre", "post", "dh"):
        write_geotiff(tmp_path / f"{name}.tif", z, transform, "EPSG:32632")
    write_geotiff(tmp_path / "sig.tif", np.zeros((40, 60), np.uint8), transform, "EPSG:32632")
    with pytest.raises(InputError, match="at least one 42 x 42-pixel patch"):
        detect_cnn(
            tmp_path / "pre.tif",
            tmp_path / "post.tif",
            tmp_path / "dh.tif",
            tmp_path / "sig.tif",
            tmp_path / "p.tif",
            tmp_path / "c.geojson",
            tmp_path / "d.geojson",
        )


def test_detect_command_with_the_cnn(cnn_slide_run, tmp_path):
    # The slide's quarter of the pair (300 x 300 pixels): co-registration is quicker.
    pair = cnn_slide_run.pair
    rows, cols = np.nonzero(pair.mask)
    r0, c0 = max(rows.min() - 60, 0), max(cols.min() - 60, 0)
    crop = (slice(r0, r0 + 300), slice(c0, c0 + 300))
    transform = pair.transform * rasterio.Affine.translation(c0, r0)
    for name, array in (("pre", pair.pre), ("post", pair.post)):
        write_geotiff(tmp_path / f"{name}.tif", array[crop], transform, "EPSG:32654")
    out = tmp_path / "found.geojson"
    result = CliRunner().invoke(
        detect,
        [
            "--pre",
            str(tmp_path / "pre.tif"),
            "--post",
            str(tmp_path / "post.tif"),
            "--out",
            str(out),
            "--work-dir",
            str(tmp_path / "work"),
            "--method",
            "cnn",
        ],
    )
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["detections"] == 1
    assert json.loads(out.read_text())["features"][0]["properties"]["method"] == "cnn"
    assert (tmp_path / "work" / "probability.tif").exists()
    args = ["--pre", "a.tif", "--post", "b.tif", "--out", str(out), "--method", "threshold"]
    refused = CliRunner().invoke(detect, [*args, "--model", "x.json"])
    assert refused.exit_code == 2 and "the threshold method runs no model" in refused.stderr
