"""difference: dh, the per-pixel LoD95 of the error model, and the significance coding."""

import json
import math

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin
from scipy import ndimage

from tests.pipeline.change_rasters import change_rasters, uniform_error_model
from worker.pipeline.change_regions import (
    BaselineTest,
    RegionOptions,
    label_regions,
    load_change_rasters,
    min_area_m2,
    significant_regions,
)
from worker.pipeline.difference import DifferenceOptions, difference
from worker.pipeline.error_model import VariogramModel
from worker.pipeline.errors import InputError
from worker.pipeline.raster_io import read_elevation, write_geotiff

TRANSFORM = from_origin(500000, 5100000, 1.0, 1.0)


def _inputs(tmp_path, sigma=0.1, seed=0):
    rng = np.random.default_rng(seed)
    pre = np.full((200, 200), 100.0, np.float32)
    post = (pre + rng.normal(0.0, sigma, pre.shape)).astype(np.float32)
    post[20:40, 20:40] -= 2.0  # loss
    post[100:120, 150:170] += 1.5  # gain
    pre[180:, 180:] = np.nan  # nodata
    write_geotiff(tmp_path / "pre.tif", pre, TRANSFORM, "EPSG:32632")
    write_geotiff(tmp_path / "post.tif", post, TRANSFORM, "EPSG:32632")
    return tmp_path / "pre.tif", tmp_path / "post.tif"


def _run(tmp_path, options=None, stable_mask_path=None):
    pre, post = _inputs(tmp_path)
    return difference(
        pre,
        post,
        tmp_path / "dh.tif",
        tmp_path / "sig.tif",
        options,
        stable_mask_path=stable_mask_path,
    )


def test_uniform_lod95_is_1_96_times_nmad_and_significance_is_coded(tmp_path):
    result = _run(tmp_path, DifferenceOptions(error_model="uniform"))
    assert result.error_model == "uniform"
    assert result.nmad_m == pytest.approx(0.1, rel=0.05)
    assert result.lod95_m == pytest.approx(1.96 * result.nmad_m)
    assert result.lod_m == pytest.approx(result.lod95_m)
    assert abs(result.median_dh_m) < 0.01
    with rasterio.open(tmp_path / "sig.tif") as src:
        sig = src.read(1)
        assert src.nodata == 255 and src.tags()["LOD_M"] == repr(result.lod_m)
        assert "BASELINE_LOD_M" not in src.tags()  # the uniform LoD is the baseline
    assert np.all(sig[20:40, 20:40] == 1) and np.all(sig[100:120, 150:170] == 2)
    assert np.all(sig[180:, 180:] == 255)
    noise = sig[50:90, 50:140]
    assert 0.02 < np.count_nonzero(noise) / noise.size < 0.08  # about 5 % beyond LoD95
    assert result.significant_loss_pixels >= 400 and result.significant_gain_pixels >= 400
    dh, _ = read_elevation(tmp_path / "dh.tif")
    assert np.all(np.isnan(dh[180:, 180:]))
    assert dh[30, 30] == pytest.approx(-2.0, abs=0.5)


def test_heteroscedastic_lod_on_uniform_noise_matches_the_nmad(tmp_path):
    result = _run(tmp_path)
    assert result.error_model == "heteroscedastic"
    # White noise of 0.1 m on flat ground: every pixel's LoD is about 1.96 * 0.1 m.
    assert result.lod_m == pytest.approx(0.196, rel=0.05)
    assert result.lod_p10_m > 0.8 * 0.196 and result.lod_p90_m < 1.2 * 0.196
    lod, _ = read_elevation(tmp_path / "lod.tif")
    assert np.all(np.isnan(lod[180:, 180:]))
    sig = rasterio.open(tmp_path / "sig.tif").read(1)
    noise = sig[50:90, 50:140]
    assert 0.02 < np.count_nonzero(noise) / noise.size < 0.08
    assert json.loads((tmp_path / "error_model.json").read_text())["stable_pixels"] > 30_000
    # The baseline's own test travels with the mask, for its regions to be judged.
    tags = rasterio.open(tmp_path / "sig.tif").tags()
    assert float(tags["BASELINE_LOD_M"]) == pytest.approx(result.lod95_m)
    assert float(tags["BASELINE_MEDIAN_M"]) == pytest.approx(result.median_dh_m, abs=0.01)


def test_floor_and_fixed_lod(tmp_path):
    floored = _run(tmp_path, DifferenceOptions(min_lod_m=0.5))
    assert floored.lod_m == 0.5 and floored.lod95_m < 0.5
    fixed = _run(tmp_path, DifferenceOptions(lod_m=1.0))
    assert fixed.lod_m == 1.0 and fixed.error_model == "fixed"
    assert fixed.significant_loss_pixels == 400 and fixed.significant_gain_pixels == 400


def test_stable_mask_selects_the_noise_estimate(tmp_path):
    mask = np.zeros((200, 200), np.uint8)
    mask[:, :100] = 1
    mask[15:45, 15:45] = 0  # the co-registration excluded the loss and its fringe
    write_geotiff(tmp_path / "stable.tif", mask, TRANSFORM, "EPSG:32632")
    options = DifferenceOptions(error_model="uniform")
    result = _run(tmp_path, options, stable_mask_path=tmp_path / "stable.tif")
    assert result.stable_pixels == 200 * 100 - 30 * 30
    assert result.nmad_m == pytest.approx(0.1, rel=0.05)


def test_grids_must_match(tmp_path):
    pre, _ = _inputs(tmp_path)
    write_geotiff(tmp_path / "small.tif", np.ones((50, 50), np.float32), TRANSFORM, "EPSG:32632")
    with pytest.raises(InputError, match="same grid"):
        difference(pre, tmp_path / "small.tif", tmp_path / "dh.tif", tmp_path / "sig.tif")


def _flat_and_steep(tmp_path, seed=0, flank_m=0.0):
    """Flat ground with little noise beside a 40-degree slope with much: the per-pixel
    LoD is below the raster's one-NMAD LoD on the flat and above it on the slope. With
    `flank_m`, the deep loss on the slope has a 10-pixel flank that much shallower."""
    rng = np.random.default_rng(seed)
    cols = np.mgrid[0:300, 0:300][1].astype(np.float32)
    steep = cols >= 100
    pre = np.where(steep, (cols - 100) * np.tan(np.radians(40.0)), 0.0).astype(np.float32)
    sigma = np.where(steep, 0.40, 0.03)
    post = (pre + rng.normal(size=pre.shape) * sigma).astype(np.float32)
    post[40:80, 30:70] -= 0.2  # a shallow loss on the flat: over 3 per-pixel LoDs
    post[190:250, 190:250] -= flank_m
    post[200:240, 200:240] -= 4.0 - flank_m  # a deep loss on the slope
    write_geotiff(tmp_path / "pre.tif", pre, TRANSFORM, "EPSG:32632")
    write_geotiff(tmp_path / "post.tif", post, TRANSFORM, "EPSG:32632")
    return tmp_path / "pre.tif", tmp_path / "post.tif", steep


def _significance(tmp_path, name, options, flank_m=0.0):
    pre, post, steep = _flat_and_steep(tmp_path, flank_m=flank_m)
    result = difference(pre, post, tmp_path / f"dh-{name}.tif", tmp_path / f"{name}.tif", options)
    return result, rasterio.open(tmp_path / f"{name}.tif").read(1), steep


def test_default_marks_no_change_the_uniform_baseline_does_not(tmp_path):
    """The default is never looser than the simple baseline: every pixel it marks, the
    one-NMAD LoD marks with the same sign, and its LoD is nowhere below that one; on the
    slope, where errors are larger, it marks far less noise than the baseline does."""
    default, sig, steep = _significance(tmp_path, "default", None)
    uniform, base, _ = _significance(tmp_path, "uniform", DifferenceOptions(error_model="uniform"))
    marked = (sig == 1) | (sig == 2)
    assert np.count_nonzero(marked) > 1600
    assert np.all(base[marked] == sig[marked])
    lod, _ = read_elevation(tmp_path / "lod.tif")
    assert np.nanmin(lod) >= np.float32(uniform.lod95_m) * (1 - 1e-6)
    assert default.lod_p10_m == pytest.approx(uniform.lod95_m, rel=1e-6)
    noise = steep.copy()
    noise[190:250, 190:250] = False
    default_noise = _marked_share(sig, noise)
    uniform_noise = _marked_share(base, noise)
    assert default_noise < 0.08 and uniform_noise > 0.2, (default_noise, uniform_noise)
    assert np.all(sig[205:235, 205:235] == 1)  # the deep loss on the slope is found


def test_without_the_uniform_floor_a_shallow_change_on_quiet_ground_is_marked(tmp_path):
    """What the floor gives up: a loss of 0.2 m on ground whose own error is 3 cm passes
    the per-pixel LoD alone, not the raster's LoD raised by the noisy slope."""
    _, floored, _ = _significance(tmp_path, "default", None)
    _, alone, _ = _significance(tmp_path, "alone", DifferenceOptions(uniform_floor=False))
    shallow = (slice(45, 75), slice(35, 65))
    assert np.mean(alone[shallow] == 1) > 0.95
    assert np.mean(floored[shallow] == 1) < 0.05


def test_the_flanks_of_a_deep_loss_on_steep_ground_join_it(tmp_path):
    """A 0.6 m flank around a deep loss on ground with 0.4 m of noise: under the per-pixel
    LoD (0.78 m) at most pixels, past the baseline's (0.37 m) at most, and significant
    as an area: it joins the loss it touches. Noise elsewhere on the slope does not."""
    flank = np.zeros((300, 300), bool)
    flank[190:250, 190:250] = True
    flank[200:240, 200:240] = False
    _, joined, steep = _significance(tmp_path, "joined", None, flank_m=0.6)
    options = DifferenceOptions(flank_area_z=None)
    _, alone, _ = _significance(tmp_path, "alone", options, flank_m=0.6)
    _, base, _ = _significance(
        tmp_path, "base", DifferenceOptions(error_model="uniform"), flank_m=0.6
    )
    assert np.mean(alone[flank] == 1) < 0.45
    assert np.mean(joined[flank] == 1) > 0.6
    assert np.all(base[joined == 1] == 1)  # still nothing the baseline does not mark
    noise = steep.copy()
    noise[180:260, 180:260] = False
    assert _marked_share(joined, noise) < _marked_share(alone, noise) + 0.005


def _marked_share(significance, where):
    marked = (significance == 1) | (significance == 2)
    return np.count_nonzero(marked & where) / np.count_nonzero(where)


def test_the_default_keeps_no_region_smaller_than_the_baselines_minimum(tmp_path):
    """The default's minimum area comes from the longer of its own correlation length and
    the simple baseline's, which the difference stage records beside the baseline's LoD:
    the default never keeps a patch of correlated error the baseline's minimum area
    rejects."""
    rng = np.random.default_rng(3)
    pre = np.full((300, 300), 100.0, np.float32)
    # Errors correlated over a few metres, on 0.5 m pixels.
    noise = ndimage.gaussian_filter(rng.normal(size=pre.shape), 4.0)
    post = (pre + 0.05 * noise / noise.std()).astype(np.float32)
    post[100:160, 100:160] -= 1.0
    transform = from_origin(500000, 5100000, 0.5, 0.5)
    write_geotiff(tmp_path / "pre.tif", pre, transform, "EPSG:32632")
    write_geotiff(tmp_path / "post.tif", post, transform, "EPSG:32632")

    def rasters(name, options):
        out = tmp_path / name
        out.mkdir()
        result = difference(
            tmp_path / "pre.tif", tmp_path / "post.tif", out / "dh.tif", out / "sig.tif", options
        )
        return result, load_change_rasters(out / "dh.tif", out / "sig.tif")

    uniform, base = rasters("uniform", DifferenceOptions(error_model="uniform"))
    default, own = rasters("default", None)
    assert own.baseline is not None and base.baseline is None
    assert own.baseline.correlation_length_m == pytest.approx(uniform.correlation_length_m)
    assert default.baseline_correlation_length_m == own.baseline.correlation_length_m
    assert uniform.baseline_correlation_length_m is None
    assert uniform.correlation_length_m > 1.0  # the errors' correlation was found
    options = RegionOptions()
    assert min_area_m2(own, options) >= min_area_m2(base, options) - 1e-9
    expected = max(default.correlation_length_m, uniform.correlation_length_m)
    assert min_area_m2(own, options) == pytest.approx(
        max(options.min_area_px * 0.25, math.pi * (expected / 2) ** 2)
    )


def test_a_patch_under_the_baselines_minimum_area_is_not_kept():
    """A patch of change whose area lies between the minimum the default's own
    correlation length gives and the baseline's is dropped (when not strong enough for
    the small-region rule), and kept when no baseline length is recorded."""
    pixel = 0.5
    dh = np.zeros((100, 100), np.float32)
    dh[40:50, 40:50] = -0.15  # 25 m2 at 1.5 LoDs
    lod = np.full(dh.shape, 0.1, np.float32)
    model = uniform_error_model(pixel, 0.1 / 1.96, dh.size)
    model.variogram = VariogramModel(nugget=0.2, ranges_m=[5.0], psills=[0.8])  # L = 5 m
    rasters = change_rasters(dh, lod, model, pixel)
    options = RegionOptions(opening_px=0, closing_px=0)
    own = min_area_m2(rasters, options)
    assert own == pytest.approx(math.pi * 2.5**2)  # 19.6 m2
    _, keep, _ = label_regions(significant_regions(rasters, options), rasters, options)
    assert len(keep) == 1
    rasters.baseline = BaselineTest(0.0, 0.1, correlation_length_m=6.0)  # 28.3 m2
    assert min_area_m2(rasters, options) == pytest.approx(math.pi * 3.0**2)
    _, keep, _ = label_regions(significant_regions(rasters, options), rasters, options)
    assert keep == []
