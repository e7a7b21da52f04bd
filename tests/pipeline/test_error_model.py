"""The error model of a DSM difference: sigma(slope), its correlation, and the coverage
of the per-pixel LoD and of a polygon's 95 % intervals over seeded trials."""

import json

import numpy as np
import pytest
from rasterio.warp import transform as transform_points
from scipy import ndimage
from shapely.geometry import Point
from shapely.geometry import shape as to_shape

from tests.pipeline.change_rasters import change_rasters
from worker.pipeline.change_regions import (
    ChangeRasters,
    RegionOptions,
    describe_region,
    label_regions,
    min_area_m2,
    significant_regions,
)
from worker.pipeline.difference import ERROR_MODEL_FILE, LOD_FILE
from worker.pipeline.error_model import (
    LOD_Z,
    ErrorModelOptions,
    _fill_and_make_monotone,
    fit_error_model,
    terrain_attributes,
)
from worker.pipeline.raster_io import write_geotiff
from worker.pipeline.vectorize import VectorizeOptions, vectorize

PIXEL = 0.5


def _valley(n: int = 400) -> np.ndarray:
    """Slopes from flat to about 45 degrees across the raster."""
    y, x = np.mgrid[0:n, 0:n] * PIXEL
    return (0.006 * (x - 40) ** 2 + 2 * np.sin(y / 12)).astype(np.float32)


def _correlated(rng: np.random.Generator, shape, sigma_px: float) -> np.ndarray:
    field = ndimage.gaussian_filter(rng.normal(size=shape), sigma_px)
    return field / field.std()


def _true_sigma(slope_deg: np.ndarray) -> np.ndarray:
    return 0.05 + 0.25 * np.tan(np.radians(slope_deg))


def test_recovers_a_known_sigma_of_slope_within_10_percent():
    rng = np.random.default_rng(3)
    surface = _valley()
    slope, curvature = terrain_attributes(surface, PIXEL)
    noise = 0.6 * rng.normal(size=surface.shape) + 0.8 * _correlated(rng, surface.shape, 2)
    dh = (noise * _true_sigma(slope)).astype(np.float32)
    dh[100:140, 250:300] -= 3.0  # a landslide must not inflate its bins
    model = fit_error_model(dh, slope, curvature, PIXEL).model
    sigma = model.sigma(slope, curvature)
    ratios = []
    for low in range(0, 45, 5):
        band = (slope >= low) & (slope < low + 5)
        band[95:145, 245:305] = False
        if np.count_nonzero(band) > 2000:
            ratios.append(float(np.median(sigma[band] / _true_sigma(slope[band]))))
    assert len(ratios) >= 6
    assert all(0.9 <= r <= 1.1 for r in ratios), ratios
    # The errors' short correlation range: a 2-pixel gaussian is about 4 pixels wide.
    assert PIXEL <= model.correlation_length_m <= 8 * PIXEL


def test_the_sigma_table_never_falls_with_slope_or_curvature():
    """A bin that reads low (few pixels, or change in its neighbour) must not make a
    steeper or rougher bin's LoD lower than a gentler one's: the table is monotone along
    both axes, nearest to the binned values where they are already in order."""
    rng = np.random.default_rng(5)
    sigma = np.sort(rng.uniform(0.03, 0.12, size=(4, 13)), axis=1)
    sigma[:, 2] += 0.05  # a contaminated gentle bin above the steeper ones
    sigma[3, 0] = 0.002  # a rough flat bin below the smooth one
    counts = rng.integers(10, 100_000, size=sigma.shape)
    table = _fill_and_make_monotone(sigma, counts, fallback=0.05)
    assert (np.diff(table, axis=1) >= 0).all()
    assert (np.diff(table, axis=0) >= 0).all()
    ordered = np.tile(np.linspace(0.03, 0.2, 13), (4, 1)) * np.linspace(1.0, 1.3, 4)[:, None]
    np.testing.assert_allclose(_fill_and_make_monotone(ordered, counts, 0.05), ordered)


def test_per_pixel_lod_covers_95_percent_on_flat_and_steep_ground():
    exceed = {"flat": [], "steep": []}
    for seed in range(5):
        rng = np.random.default_rng(seed)
        surface = _valley(300)
        slope, curvature = terrain_attributes(surface, PIXEL)
        dh = (rng.normal(size=surface.shape) * _true_sigma(slope)).astype(np.float32)
        model = fit_error_model(dh, slope, curvature, PIXEL).model
        lod = LOD_Z * model.sigma(slope, curvature)
        beyond = np.abs(dh - model.median_dh_m) > lod
        exceed["flat"].append(beyond[slope < 10].mean())
        exceed["steep"].append(beyond[slope > 30].mean())
    for where, shares in exceed.items():
        assert 0.035 <= float(np.mean(shares)) <= 0.065, (where, shares)


def test_effective_samples_match_the_spread_of_area_means():
    rng = np.random.default_rng(7)
    shape = (600, 600)
    dh = (0.1 * (0.5 * rng.normal(size=shape) + 0.85 * _correlated(rng, shape, 3))).astype(
        np.float32
    )
    flat = np.zeros(shape, np.float32)
    model = fit_error_model(dh, flat, flat, PIXEL).model
    side = 20  # 10 m squares: the mean over each, compared with sigma / sqrt(n_eff)
    means = [
        dh[r : r + side, c : c + side].mean()
        for r in range(0, 600, side * 2)
        for c in range(0, 600, side * 2)
    ]
    predicted = model.nmad_m * model.mean_error_factor((side * PIXEL) ** 2)
    assert float(np.std(means)) == pytest.approx(predicted, rel=0.3)


def test_polygon_intervals_cover_the_planted_slide():
    covered_volume, covered_area, trials = 0, 0, 40
    for seed in range(trials):
        rng = np.random.default_rng(100 + seed)
        shape = (200, 200)
        noise = 0.15 * (0.6 * rng.normal(size=shape) + 0.8 * _correlated(rng, shape, 2))
        true_dh = np.zeros(shape, np.float32)
        true_dh[60:100, 70:120] = -1.2
        dh = (true_dh + noise).astype(np.float32)
        flat = np.zeros(shape, np.float32)
        model = fit_error_model(dh, flat, flat, PIXEL).model
        lod = (LOD_Z * model.sigma(flat, flat)).astype(np.float32)
        rasters = change_rasters((dh - model.median_dh_m).astype(np.float32), lod, model, PIXEL)
        options = RegionOptions()
        labels, keep, windows = label_regions(
            significant_regions(rasters, options), rasters, options
        )
        on_slide = [k for k in keep if labels[80, 95] == k]
        assert on_slide, f"seed {seed}: the slide was not found"
        k = on_slide[0]
        region = describe_region(rasters, labels, k, windows[keep.index(k)], options)
        truth_volume = 1.2 * 40 * 50 * PIXEL**2
        low, high = region.properties["volume_loss_m3_ci95"]
        covered_volume += low <= truth_volume <= high
        a_low, a_high = region.properties["area_m2_ci95"]
        covered_area += a_low <= 40 * 50 * PIXEL**2 <= a_high
    assert covered_volume / trials >= 0.9
    assert covered_area / trials >= 0.9


def _no_change_rasters(seed: int, width_px: float, planted: bool) -> ChangeRasters:
    """Correlated errors (and a collapsed mound of 36 m2 at -0.8 m when planted)."""
    rng = np.random.default_rng(200 + seed)
    shape = (300, 300)
    dh = 0.1 * (0.4 * rng.normal(size=shape) + 0.9 * _correlated(rng, shape, width_px))
    if planted:
        dh[100:112, 140:152] -= 0.8
        dh[200:203, 60:63] += 3.0  # a spike of the reconstruction, 2.25 m2
    dh = dh.astype(np.float32)
    flat = np.zeros(shape, np.float32)
    model = fit_error_model(dh, flat, flat, PIXEL).model
    lod = (LOD_Z * model.sigma(flat, flat)).astype(np.float32)
    return change_rasters((dh - model.median_dh_m).astype(np.float32), lod, model, PIXEL)


def test_a_small_strong_change_is_kept_and_correlated_error_is_not():
    """Below the correlation area, only change twice its LoD on average is kept."""
    options = RegionOptions()
    strict = RegionOptions(small_region_lod_ratio=None)  # the minimum area alone

    def kept(rasters: ChangeRasters, opts: RegionOptions) -> tuple[np.ndarray, set[int]]:
        labels, keep, _ = label_regions(significant_regions(rasters, opts), rasters, opts)
        return labels, set(keep)

    for seed in range(8):
        noise = _no_change_rasters(seed, (2, 4, 6, 10)[seed % 4], planted=False)
        assert kept(noise, options)[1] == kept(noise, strict)[1], f"seed {seed}"

        # Errors correlated over 6-10 pixels: the minimum area is 90-170 m2.
        rasters = _no_change_rasters(seed, (6, 10)[seed % 2], planted=True)
        assert min_area_m2(rasters, options) > 36, "the mound must be below the minimum area"
        labels, keep = kept(rasters, options)
        _, keep_strict = kept(rasters, strict)
        mound = int(labels[106, 146])
        assert keep - keep_strict == {mound}, f"seed {seed}: added {keep - keep_strict}"
        assert mound not in keep_strict
        assert labels[201, 61] not in keep  # the spike: narrower than the errors resolve


def test_sigma_is_the_bilinear_table_clamped_beyond_its_centres():
    """The per-pixel lookup, worked in bands, equals scipy's linear interpolation of the
    table over a raster of several bands, with NaN where an attribute is NaN."""
    from scipy.interpolate import RegularGridInterpolator

    from worker.pipeline.error_model import ErrorModel, VariogramModel

    rng = np.random.default_rng(9)
    slopes = [2.5, 7.5, 12.5, 22.5, 47.5]
    curvatures = [0.2, 0.9, 3.0]
    table = np.sort(rng.uniform(0.02, 0.5, size=(3, 5)), axis=1)
    model = ErrorModel(
        pixel_size=0.2,
        slope_centres_deg=slopes,
        curvature_centres=curvatures,
        sigma_table=table.tolist(),
        median_dh_m=0.0,
        nmad_m=0.1,
        stable_pixels=1,
        variogram=VariogramModel(nugget=1.0, ranges_m=[], psills=[]),
    )
    shape = (640, 700)  # 448 000 pixels: the lookup's bands are 262 144
    slope = rng.uniform(0.0, 70.0, shape).astype(np.float32)
    curvature = rng.uniform(-4.0, 4.0, shape).astype(np.float32)  # |curvature| is used
    slope[5, 7] = np.nan
    curvature[600, 9] = np.nan
    sigma = model.sigma(slope, curvature)
    reference = RegularGridInterpolator((curvatures, slopes), table)(
        np.stack(
            [
                np.clip(np.nan_to_num(np.abs(curvature)), curvatures[0], curvatures[-1]),
                np.clip(np.nan_to_num(slope), slopes[0], slopes[-1]),
            ],
            axis=-1,
        ).reshape(-1, 2)
    ).reshape(shape)
    assert sigma.dtype == np.float32
    assert np.isnan(sigma[5, 7]) and np.isnan(sigma[600, 9])
    finite = np.isfinite(slope) & np.isfinite(curvature)
    assert np.count_nonzero(np.isnan(sigma)) == 2
    np.testing.assert_allclose(sigma[finite], reference[finite], rtol=1e-6)


def test_change_over_much_of_the_steep_ground_does_not_inflate_its_sigma():
    """Where change covers nearly half the steep ground (as on a small site whose mounds
    collapsed), its shallow flanks pass the 4-sigma pixel exclusion and the steep bins
    learn from them, until the regions whose |dh| averages twice their LoD are left out
    and the table fitted again."""
    rng = np.random.default_rng(21)
    surface = _valley(500)
    slope, curvature = terrain_attributes(surface, PIXEL)
    true_sigma = _true_sigma(slope)
    dh = (rng.normal(size=surface.shape) * true_sigma).astype(np.float32)
    steep = slope > 30
    # Pits 8 m square on a 12 m grid over the steep ground, 12 true sigmas deep at the
    # centre and shallowing to nothing at the edge.
    rows, cols = np.mgrid[0 : surface.shape[0], 0 : surface.shape[1]] % 24 - 7.5
    depth = np.clip(1.0 - np.maximum(np.abs(rows), np.abs(cols)) / 8.0, 0.0, None)
    pits = steep & (depth > 0)
    dh[pits] -= (12.0 * depth[pits] * true_sigma[pits]).astype(np.float32)
    assert 0.4 < pits.sum() / steep.sum() < 0.5

    def steep_ratio(options: ErrorModelOptions) -> float:
        sigma = fit_error_model(dh, slope, curvature, PIXEL, options).sigma
        band = steep & ~pits
        return float(np.median(sigma[band] / true_sigma[band]))

    once = steep_ratio(ErrorModelOptions(strong_change_lod_ratio=None))
    again = steep_ratio(ErrorModelOptions())
    assert once > 1.1, once  # the pits' flanks inflate the steep bins
    assert 0.95 <= again <= 1.06, again


def _write_change(folder, rasters: ChangeRasters) -> tuple:
    """The difference stage's files for `rasters`: dh, significance, lod, error model."""
    folder.mkdir(parents=True, exist_ok=True)
    write_geotiff(folder / "dh.tif", rasters.dh, rasters.transform, rasters.crs)
    write_geotiff(folder / "significance.tif", rasters.significance, rasters.transform, rasters.crs)
    write_geotiff(folder / LOD_FILE, rasters.lod, rasters.transform, rasters.crs)
    (folder / ERROR_MODEL_FILE).write_text(json.dumps(rasters.model.to_dict()))
    return folder / "dh.tif", folder / "significance.tif"


def test_correlated_error_past_the_pixel_lod_is_dropped_by_its_volume(tmp_path):
    """Errors correlated at two scales (3 and 40 pixels) leave patches of pixels just past
    their LoD whose volume is within 3 standard errors of zero; a 0.5 m loss of 120 m2
    (2.5 LoD) is kept in every trial."""
    dropped = chance = 0
    for seed in range(12):
        rng = np.random.default_rng(300 + seed)
        shape = (300, 300)
        dh = 0.1 * (
            0.4 * rng.normal(size=shape)
            + 0.5 * _correlated(rng, shape, 3)
            + 0.8 * _correlated(rng, shape, 40)
        )
        dh[100:124, 140:160] -= 0.5
        dh = dh.astype(np.float32)
        flat = np.zeros(shape, np.float32)
        model = fit_error_model(dh, flat, flat, PIXEL).model
        lod = (LOD_Z * model.sigma(flat, flat)).astype(np.float32)
        rasters = change_rasters((dh - model.median_dh_m).astype(np.float32), lod, model, PIXEL)
        dh_path, sig_path = _write_change(tmp_path / f"seed{seed}", rasters)
        x, y = rasters.transform * (150, 112)
        centre = Point(*(c[0] for c in transform_points(rasters.crs, "EPSG:4326", [x], [y])))
        out = tmp_path / f"seed{seed}" / "detections.geojson"
        counts = {}
        for test in (3.0, None):
            vectorize(dh_path, sig_path, out, VectorizeOptions(min_volume_z=test))
            features = json.loads(out.read_text())["features"]
            slide = [f for f in features if to_shape(f["geometry"]).contains(centre)]
            assert len(slide) == 1, f"seed {seed}: the planted loss was not kept"
            low, high = slide[0]["properties"]["uncertainty"]["volume_loss_m3_ci95"]
            assert low <= 0.5 * 120 <= high
            counts[test] = len(features) - 1
        chance += counts[None]
        dropped += counts[None] - counts[3.0]
    assert chance >= 20  # the pixel LoD alone passes patches of such errors
    assert dropped >= chance / 3  # 16 of 42 when written


def test_a_first_round_on_gentle_ground_still_gives_a_table_of_every_slope():
    """A first round limited to candidate pixels (as the simple baseline's, which may be
    a co-registration's mask without the steep ground) is the fit those pixels give
    alone; the model returned is fitted again over every pixel, steep bins included."""
    rng = np.random.default_rng(3)
    surface = _valley()
    slope, curvature = terrain_attributes(surface, PIXEL)
    noise = 0.6 * rng.normal(size=surface.shape) + 0.8 * _correlated(rng, surface.shape, 2)
    dh = (noise * _true_sigma(slope)).astype(np.float32)
    gentle = slope < 15.0
    model, _, first = fit_error_model(dh, slope, curvature, PIXEL, first_candidates=gentle)
    alone = fit_error_model(
        dh, slope, curvature, PIXEL, ErrorModelOptions(strong_change_lod_ratio=None), gentle
    ).model
    assert first.sigma_table == alone.sigma_table
    assert first.correlation_length_m == alone.correlation_length_m
    assert max(first.slope_centres_deg) < 15.0 < max(model.slope_centres_deg)
    steep = slope > 35.0
    ratio = np.median(model.sigma(slope, curvature)[steep] / _true_sigma(slope[steep]))
    assert 0.9 < ratio < 1.1
