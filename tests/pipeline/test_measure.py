"""Profiles and volumes drawn on the map, against rasters whose answer is known."""

from pathlib import Path

import numpy as np
import pytest
import rasterio
from pyproj import Transformer
from rasterio.transform import from_origin

from worker.pipeline.errors import InputError
from worker.pipeline.measure import elevation_profile, heights_at, polygon_volume

CRS = "EPSG:32654"
ORIGIN = (419300.0, 3990900.0)  # west, north
RES = 0.5
TO_LONLAT = Transformer.from_crs(CRS, "EPSG:4326", always_xy=True)


def write(path: Path, values: np.ndarray, nodata: float | None = -9999.0) -> Path:
    with rasterio.open(
        path, "w", driver="GTiff", width=values.shape[1], height=values.shape[0], count=1,
        dtype="float32", crs=CRS, transform=from_origin(*ORIGIN, RES, RES), nodata=nodata,
    ) as dst:  # fmt: skip
        dst.write(values.astype(np.float32), 1)
    return path


def lonlat(*points: tuple[float, float]) -> list[list[float]]:
    return [list(TO_LONLAT.transform(ORIGIN[0] + e, ORIGIN[1] - s)) for e, s in points]


def test_a_profile_follows_the_slope_of_each_dsm(tmp_path: Path) -> None:
    cols = np.arange(200) * RES + RES / 2
    plane = np.tile(100.0 + 0.1 * cols, (120, 1))
    pre = write(tmp_path / "pre.tif", plane)
    post = write(tmp_path / "post.tif", plane - 2.0)
    line = {"type": "LineString", "coordinates": lonlat((10.0, 30.0), (60.0, 30.0))}
    profile = elevation_profile(line, {"pre": pre, "post": post}, samples=51)
    assert profile.length_m == pytest.approx(50.0, abs=0.01)
    assert profile.distance_m[-1] == pytest.approx(50.0, abs=0.01) and profile.step_m == 1.0
    expected = 100.0 + 0.1 * (10.0 + np.array(profile.distance_m))
    assert np.allclose(profile.heights_m["pre"], expected, atol=0.01)
    assert np.allclose(profile.heights_m["post"], expected - 2.0, atol=0.01)


def test_a_profile_beyond_the_dsm_has_gaps_not_errors(tmp_path: Path) -> None:
    dsm = write(tmp_path / "dsm.tif", np.full((40, 40), 5.0))  # 20 m square
    line = {"type": "LineString", "coordinates": lonlat((10.0, 10.0), (40.0, 10.0))}
    heights = elevation_profile(line, {"dsm": dsm}, samples=31).heights_m["dsm"]
    assert heights[0] == 5.0 and heights[-1] is None
    # Cell centres reach 19.75 m east: the samples from 20 m on have no height.
    assert sum(h is None for h in heights) == 21


def test_volume_counts_cut_and_fill_and_what_is_beyond_the_lod(tmp_path: Path) -> None:
    dh = np.zeros((100, 100))
    dh[20:40, 20:40] = -2.0  # 10 x 10 m lost, 2 m deep: 200 m³
    dh[90:100, 90:100] = 0.3  # 5 x 5 m gained by 0.3 m: 7.5 m³, under a 0.5 m LoD
    path = write(tmp_path / "dh.tif", dh)
    polygon = {
        "type": "Polygon",
        "coordinates": [lonlat((5.0, 5.0), (45.0, 5.0), (45.0, 45.0), (5.0, 45.0), (5.0, 5.0))],
    }
    volume = polygon_volume(polygon, path, lod=0.5)
    assert volume.area_m2 == pytest.approx(1600.0, rel=1e-3)
    assert volume.cut_m3 == pytest.approx(200.0, rel=0.02) and volume.fill_m3 == 0.0
    assert volume.net_m3 == pytest.approx(-200.0, rel=0.02)
    everything = {
        "type": "Polygon",
        "coordinates": [lonlat((0, 0), (50, 0), (50, 50), (0, 50), (0, 0))],
    }
    both = polygon_volume(everything, path, lod=0.5)
    assert both.fill_m3 == pytest.approx(7.5, rel=0.02) and both.fill_beyond_lod_m3 == 0.0
    assert both.cut_beyond_lod_m3 == pytest.approx(200.0, rel=0.02) and both.lod_m == 0.5


def test_bad_geometries_are_refused_with_the_reason(tmp_path: Path) -> None:
    path = write(tmp_path / "dh.tif", np.zeros((10, 10)))
    with pytest.raises(InputError, match="Polygon with an area"):
        polygon_volume({"type": "Point", "coordinates": [139.0, 36.0]}, path)
    far = {"type": "Polygon", "coordinates": [[[0, 0], [0.001, 0], [0.001, 0.001], [0, 0]]]}
    with pytest.raises(InputError, match="outside"):
        polygon_volume(far, path)
    with pytest.raises(InputError, match="LineString"):
        elevation_profile({"type": "LineString", "coordinates": [[1, 1], [1, 1]]}, {"d": path})
    with pytest.raises(InputError, match="not valid GeoJSON"):
        elevation_profile({"type": "LineString", "coordinates": "x"}, {"d": path})


def test_heights_under_the_cursor(tmp_path: Path) -> None:
    cols = np.arange(200) * RES + RES / 2
    pre = write(tmp_path / "pre.tif", np.tile(100.0 + 0.1 * cols, (120, 1)))
    (lon, lat), (far_lon, far_lat) = lonlat((20.0, 30.0), (500.0, 30.0))
    assert heights_at(lon, lat, {"pre": pre}) == {"pre": pytest.approx(102.0, abs=0.01)}
    assert heights_at(far_lon, far_lat, {"pre": pre}) == {"pre": None}
