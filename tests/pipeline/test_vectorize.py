"""vectorize: planted slide found with the right area and volumes; nothing from noise."""

import json

import numpy as np
import pytest
import shapely
from rasterio.transform import from_origin
from shapely.geometry import shape

from worker.pipeline.errors import InputError
from worker.pipeline.raster_io import read_elevation, write_geotiff
from worker.pipeline.vectorize import VectorizeOptions, vectorize


def _collection(run):
    return json.loads(run.result.detections_path.read_text())


def test_planted_slide_area_and_volumes(slide_run):
    features = _collection(slide_run)["features"]
    assert len(features) == 1
    props = features[0]["properties"]
    truth = slide_run.pair.truth
    assert abs(props["area_m2"] / truth.area_m2 - 1) < 0.05
    assert abs(props["volume_loss_m3"] / truth.volume_loss_m3 - 1) < 0.10
    assert abs(props["volume_gain_m3"] / truth.volume_gain_m3 - 1) < 0.10
    assert props["max_abs_dh_m"] == pytest.approx(2.5, abs=0.3)
    assert 0.9 <= props["score"] <= 1.0
    assert props["method"] == "threshold"


def test_geojson_is_rfc7946(slide_run):
    collection = _collection(slide_run)
    assert collection["type"] == "FeatureCollection" and "crs" not in collection
    assert collection["metric_crs"] == "EPSG:32632"
    feature = collection["features"][0]
    assert feature["id"] == 1 and feature["type"] == "Feature"
    # The one detection record of every method (detection_record.py).
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
    assert set(feature["properties"]["uncertainty"]) == {
        "area_m2_ci95",
        "volume_loss_m3_ci95",
        "volume_gain_m3_ci95",
        "lod_m",
    }
    assert feature["properties"]["model_version"] is None
    geometry = shape(feature["geometry"])
    polygons = getattr(geometry, "geoms", [geometry])
    for polygon in polygons:
        assert polygon.exterior.is_ccw
        assert all(not interior.is_ccw for interior in polygon.interiors)
    coords = shapely.get_coordinates(geometry)
    assert np.array_equal(coords, np.round(coords, 7))
    assert np.all((coords[:, 0] > 8.9) & (coords[:, 0] < 9.1))  # lon first
    assert np.all((coords[:, 1] > 46.0) & (coords[:, 1] < 46.1))
    west, south, east, north = feature["bbox"]
    assert west < east and south < north


def test_no_detection_from_noise_and_shift(noise_run):
    assert _collection(noise_run)["features"] == []
    assert noise_run.result.summary()["detections"] == 0


def test_nodata_hole_makes_no_detection_and_no_nan(hole_run):
    assert _collection(hole_run)["features"] == []
    dh, _ = read_elevation(hole_run.result.work_dir / "dh.tif")
    rows, cols = np.mgrid[0:300, 0:300]
    hole = (rows - 120) ** 2 + (cols - 170) ** 2 < 30**2
    assert np.all(np.isnan(dh[hole]))
    assert np.nanmax(np.abs(dh)) < 1.0  # no -9999 or blended edge values leak into dh
    for name in ("post_coregistered.tif", "pre_aligned.tif"):
        values, _ = read_elevation(hole_run.result.work_dir / name)
        assert np.nanmin(values) > 0
    results = hole_run.result.results
    assert all(np.isfinite(v) for v in results["difference"].values() if isinstance(v, float))


def test_speckle_is_removed_and_min_area_applies(tmp_path):
    transform = from_origin(500000, 5100000, 1.0, 1.0)
    sig = np.zeros((200, 200), np.uint8)
    dh = np.zeros((200, 200), np.float32)
    rng = np.random.default_rng(1)
    speckle = rng.random(sig.shape) < 0.05
    sig[speckle] = 1
    dh[speckle] = -0.3
    sig[50:60, 50:60], dh[50:60, 50:60] = 2, 1.0  # 100 m2
    sig[150:154, 150:154], dh[150:154, 150:154] = 1, -1.0  # 16 m2, below 25 m2
    write_geotiff(tmp_path / "dh.tif", dh, transform, "EPSG:32632")
    write_geotiff(tmp_path / "sig.tif", sig, transform, "EPSG:32632", tags={"LOD_M": "0.2"})
    result = vectorize(tmp_path / "dh.tif", tmp_path / "sig.tif", tmp_path / "out.geojson")
    assert result.detections == 1
    props = json.loads((tmp_path / "out.geojson").read_text())["features"][0]["properties"]
    assert props["area_m2"] == pytest.approx(100.0, abs=12)
    assert props["volume_gain_m3"] == pytest.approx(100.0, abs=12)
    smaller = vectorize(
        tmp_path / "dh.tif",
        tmp_path / "sig.tif",
        tmp_path / "out.geojson",
        VectorizeOptions(min_area_m2=10.0),
    )
    assert smaller.detections == 2


def test_unknown_method(slide_run, tmp_path):
    work = slide_run.result.work_dir
    with pytest.raises(InputError, match="unknown detection method 'magic'"):
        vectorize(
            work / "dh.tif", work / "significance.tif", tmp_path / "x.geojson", method="magic"
        )
    assert not (tmp_path / "x.geojson").exists()
