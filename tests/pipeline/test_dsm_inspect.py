"""inspect_dsm: the description of a good DSM and a plain error for each bad one."""

import json

import numpy as np
import pytest
import rasterio
import shapely
from rasterio.transform import from_origin

from worker.pipeline.dsm_inspect import inspect_dsm
from worker.pipeline.errors import InputError
from worker.simulator.dsm_pair import make_dsm_pair, write_dsm_pair


def _write(path, data, crs="EPSG:32632", nodata=-9999.0, driver="GTiff", **extra):
    data = np.atleast_3d(data) if data.ndim == 2 else data
    if data.ndim == 3 and data.shape[0] > 16:
        data = data[np.newaxis, :, :, 0]
    profile = {
        "driver": driver,
        "height": data.shape[1],
        "width": data.shape[2],
        "count": data.shape[0],
        "dtype": data.dtype.name,
        **extra,
    }
    if crs is not None:
        profile["crs"] = crs
        profile["transform"] = from_origin(500000, 5100000, 0.5, 0.5)
    if nodata is not None:
        profile["nodata"] = nodata
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(data)
    return path


def test_describes_a_projected_dsm(tmp_path):
    pair = make_dsm_pair((300, 200), 0.5, slide=False, seed=1)
    pair.pre[:30, :] = np.nan
    paths = write_dsm_pair(pair, tmp_path)
    info = inspect_dsm(paths.pre)
    assert info.crs == "EPSG:32632"
    assert (info.width, info.height, info.band_count) == (200, 300, 1)
    assert info.resolution_m == (0.5, 0.5)
    assert info.bounds == (500000.0, 5099850.0, 500100.0, 5100000.0)
    assert info.nodata == -9999.0
    assert info.valid_fraction == pytest.approx(0.9)
    assert info.min_elevation_m == pytest.approx(float(np.nanmin(pair.pre)))
    assert info.max_elevation_m == pytest.approx(float(np.nanmax(pair.pre)))
    assert info.notes == []
    footprint = info.footprint
    assert footprint["type"] == "Polygon"
    ring = np.array(footprint["coordinates"][0])
    assert shapely.LinearRing(ring).is_ccw
    assert np.array_equal(ring, np.round(ring, 7))
    assert 8.99 < ring[:, 0].min() < ring[:, 0].max() < 9.01
    assert 46.05 < ring[:, 1].min() < ring[:, 1].max() < 46.06
    json.dumps(info.to_dict())


def test_geographic_resolution_is_in_metres(tmp_path):
    pair = make_dsm_pair((100, 100), 1.0, crs="EPSG:4326", origin=(9.5, 46.2), slide=False)
    info = inspect_dsm(write_dsm_pair(pair, tmp_path).pre)
    assert info.crs == "EPSG:4326"
    assert info.resolution_m[0] == pytest.approx(1.0, rel=0.01)
    assert info.resolution_m[1] == pytest.approx(1.0, rel=0.01)


def test_more_than_one_band_is_accepted_and_noted(tmp_path):
    data = np.stack([np.full((20, 20), 100.0), np.full((20, 20), 7.0)]).astype(np.float32)
    info = inspect_dsm(_write(tmp_path / "two.tif", data))
    assert info.band_count == 2
    assert info.min_elevation_m == info.max_elevation_m == 100.0
    assert "2 bands" in info.notes[0] and "band 1" in info.notes[0]


def test_not_a_raster(tmp_path):
    path = tmp_path / "notes.tif"
    path.write_text("this is not an image")
    with pytest.raises(InputError, match=r"notes\.tif is not a GeoTIFF, nor any raster file"):
        inspect_dsm(path)


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match=r"missing\.tif does not exist"):
        inspect_dsm(tmp_path / "missing.tif")


def test_not_a_geotiff(tmp_path):
    path = _write(
        tmp_path / "dsm.png", np.ones((1, 20, 20), np.uint8), crs=None, nodata=None, driver="PNG"
    )
    with pytest.raises(InputError, match=r"dsm.png is not a GeoTIFF \(it is a PNG file\)"):
        inspect_dsm(path)


def test_no_crs(tmp_path):
    path = tmp_path / "nocrs.tif"
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        height=20,
        width=20,
        count=1,
        dtype="float32",
        transform=from_origin(0, 20, 1, 1),
    ) as dst:
        dst.write(np.ones((1, 20, 20), np.float32))
    with pytest.raises(InputError, match=r"nocrs\.tif has no coordinate reference system"):
        inspect_dsm(path)


def test_truncated_file(tmp_path):
    pair = make_dsm_pair((512, 512), 1.0, slide=False)
    good = write_dsm_pair(pair, tmp_path).pre
    data = good.read_bytes()
    truncated = tmp_path / "truncated.tif"
    truncated.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(InputError, match=r"truncated\.tif is truncated or corrupt"):
        inspect_dsm(truncated)


@pytest.mark.parametrize("fill", [-9999.0, np.nan])
def test_all_nodata(tmp_path, fill):
    data = np.full((1, 20, 20), fill, np.float32)
    data[0, :3, :3] = np.nan  # NaN counts as nodata even when nodata is -9999
    path = _write(tmp_path / "empty.tif", data)
    with pytest.raises(InputError, match=r"empty\.tif contains only nodata"):
        inspect_dsm(path)
