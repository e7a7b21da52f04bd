"""align: one metric grid over the common footprint, nodata kept apart from elevations."""

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from worker.pipeline.align import AlignOptions, align
from worker.pipeline.errors import InputError
from worker.pipeline.raster_io import read_elevation, write_geotiff
from worker.simulator.dsm_pair import make_dsm_pair, write_dsm_pair


def _outputs(tmp_path):
    return tmp_path / "pre_aligned.tif", tmp_path / "post_aligned.tif"


def test_projected_pair_on_the_same_grid_is_kept_as_is(tmp_path):
    pair = make_dsm_pair((300, 300), 1.0, (0.6, 0.2, 0.1), slide=False, seed=1)
    paths = write_dsm_pair(pair, tmp_path / "in")
    pre_out, post_out = _outputs(tmp_path)
    result = align(paths.pre, paths.post, pre_out, post_out)
    assert result.crs == "EPSG:32632"
    assert result.shape == (300, 300) and result.resolution_m == 1.0
    assert result.bounds == (500000.0, 5099700.0, 500300.0, 5100000.0)
    assert result.overlap_area_m2 == 90000.0
    pre, _ = read_elevation(pre_out)
    np.testing.assert_array_equal(pre, pair.pre)
    with rasterio.open(post_out) as src:
        assert src.crs.to_epsg() == 32632 and src.nodata == -9999
        assert src.dtypes[0] == "float32"
        assert src.profile["tiled"] and src.compression.value == "DEFLATE"


def test_coarser_resolution_and_intersection_snapped_to_the_grid(tmp_path):
    fine = make_dsm_pair((400, 400), 0.5, slide=False, seed=2, origin=(500010.3, 5100000.0))
    coarse = make_dsm_pair((150, 150), 1.0, slide=False, seed=2, origin=(500000.0, 5099990.4))
    write_geotiff(tmp_path / "pre.tif", fine.pre, fine.transform, "EPSG:32632")
    write_geotiff(tmp_path / "post.tif", coarse.post, coarse.transform, "EPSG:32632")
    pre_out, post_out = _outputs(tmp_path)
    result = align(tmp_path / "pre.tif", tmp_path / "post.tif", pre_out, post_out)
    assert result.resolution_m == 1.0
    # pre covers x 500010.3..500210.3, y 5099800..5100000; post x 500000..500150,
    # y 5099840.4..5099990.4: intersection shrunk to whole metres.
    assert result.bounds == (500011.0, 5099841.0, 500150.0, 5099990.0)
    assert result.shape == (149, 139)
    explicit = align(
        tmp_path / "pre.tif",
        tmp_path / "post.tif",
        pre_out,
        post_out,
        AlignOptions(resolution_m=2.0, min_overlap_pixels=1000),
    )
    assert explicit.resolution_m == 2.0 and explicit.bounds == (
        500012.0,
        5099842.0,
        500150.0,
        5099990.0,
    )


def test_geographic_input_goes_to_the_utm_zone(tmp_path):
    pair = make_dsm_pair((200, 200), 1.0, crs="EPSG:4326", origin=(9.5, 46.2), seed=3)
    paths = write_dsm_pair(pair, tmp_path / "in")
    pre_out, post_out = _outputs(tmp_path)
    result = align(paths.pre, paths.post, pre_out, post_out)
    assert result.crs == "EPSG:32632"
    assert result.resolution_m == pytest.approx(1.0, abs=0.01)
    with rasterio.open(pre_out) as src:
        assert src.crs.to_epsg() == 32632
    assert result.valid_overlap_area_m2 > 0.9 * 200 * 200


def test_nodata_never_blends_into_elevations(tmp_path):
    pair = make_dsm_pair((200, 200), 1.0, slide=False, noise_m=0.0, seed=4)
    pair.post[80:120, 80:120] = np.nan
    # A half-pixel offset forces every output pixel to be interpolated.
    offset = from_origin(500000.5, 5099999.5, 1.0, 1.0)
    write_geotiff(tmp_path / "pre.tif", pair.pre, pair.transform, "EPSG:32632")
    write_geotiff(tmp_path / "post.tif", pair.post, offset, "EPSG:32632")
    pre_out, post_out = _outputs(tmp_path)
    align(tmp_path / "pre.tif", tmp_path / "post.tif", pre_out, post_out)
    post, _ = read_elevation(post_out)
    valid = post[np.isfinite(post)]
    assert valid.min() > np.nanmin(pair.post) - 1 and valid.max() < np.nanmax(pair.post) + 1
    hole = np.isnan(post)
    # The hole (40 x 40 source pixels) may grow by one pixel, never more.
    assert 40 * 40 <= np.count_nonzero(hole[1:-1, 1:-1]) <= 42 * 42


def test_no_overlap(tmp_path):
    a = make_dsm_pair((100, 100), slide=False, seed=1)
    b = make_dsm_pair((100, 100), slide=False, seed=1, origin=(600000.0, 5100000.0))
    write_geotiff(tmp_path / "a.tif", a.pre, a.transform, "EPSG:32632")
    write_geotiff(tmp_path / "b.tif", b.pre, b.transform, "EPSG:32632")
    pre_out, post_out = _outputs(tmp_path)
    with pytest.raises(InputError, match="pre and post DSMs do not overlap"):
        align(tmp_path / "a.tif", tmp_path / "b.tif", pre_out, post_out)
    assert not pre_out.exists() and not post_out.exists()


def test_overlap_too_small(tmp_path):
    a = make_dsm_pair((100, 100), slide=False, seed=1)
    b = make_dsm_pair((100, 100), slide=False, seed=1, origin=(500090.0, 5100000.0))
    write_geotiff(tmp_path / "a.tif", a.pre, a.transform, "EPSG:32632")
    write_geotiff(tmp_path / "b.tif", b.pre, b.transform, "EPSG:32632")
    with pytest.raises(InputError, match="overlap of the pre and post DSMs is too small"):
        align(tmp_path / "a.tif", tmp_path / "b.tif", *_outputs(tmp_path))


def test_post_all_nodata_in_the_overlap(tmp_path):
    a = make_dsm_pair((200, 200), slide=False, seed=1)
    b = make_dsm_pair((200, 200), slide=False, seed=1, origin=(500100.0, 5100000.0))
    b.post[:, :100] = np.nan  # the half that overlaps a
    write_geotiff(tmp_path / "a.tif", a.pre, a.transform, "EPSG:32632")
    write_geotiff(tmp_path / "b.tif", b.post, b.transform, "EPSG:32632")
    with pytest.raises(InputError, match="post DSM has no valid elevations where it overlaps"):
        align(tmp_path / "a.tif", tmp_path / "b.tif", *_outputs(tmp_path))
