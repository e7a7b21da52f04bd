"""The vectorised Nuth & Kääb and binned NMAD give xdem's figures (xdem is the reference
implementation they replace for speed)."""

import warnings

import numpy as np
import pytest
from rasterio.crs import CRS
from rasterio.transform import from_origin

from worker.pipeline.binned import bin_index, binned_median, binned_nmad
from worker.pipeline.nuth_kaab import NuthKaabError, nuth_kaab_shift


def test_binned_nmad_is_xdems_nd_binning_nmad():
    import xdem.spatialstats as xss
    from geoutils.stats import nmad

    rng = np.random.default_rng(0)
    slope = rng.uniform(0, 60, 50_000)
    curvature = rng.exponential(2.0, 50_000)
    values = rng.normal(0, 0.05 + slope / 300, 50_000)
    slope_edges = np.array([0.0, 10, 20, 30, 45, 60])
    curvature_edges = np.quantile(curvature, [0, 0.5, 0.9, 1.0])
    curvature_edges[-1] += 1e-9
    cells = bin_index(slope, slope_edges) + 5 * bin_index(curvature, curvature_edges)
    counts, nmads = binned_nmad(values, cells, 15)

    table = xss.nd_binning(
        values,
        [slope, curvature],
        ["slope", "curvature"],
        list_var_bins=[slope_edges, curvature_edges],
        statistics=["count", nmad],
    )
    table = table[table["slope"].notna() & table["curvature"].notna()]
    assert len(table) == 15
    for _, row in table.iterrows():
        i = np.searchsorted(slope_edges, row["slope"].mid) - 1
        j = np.searchsorted(curvature_edges, row["curvature"].mid) - 1
        assert counts[j * 5 + i] == row["count"]
        assert nmads[j * 5 + i] == pytest.approx(row["nmad"], rel=1e-12)


def test_bin_index_closes_the_last_bin_and_drops_what_is_outside():
    edges = np.array([0.0, 1.0, 2.0])
    values = np.array([-0.1, 0.0, 0.99, 1.0, 2.0, 2.01, np.nan])
    assert bin_index(values, edges).tolist() == [-1, 0, 0, 1, 1, -1, -1]


def hills(shape: tuple[int, int], pixel: float, shift: tuple[float, float]) -> np.ndarray:
    """Smooth hills in every direction, sampled with the surface moved by `shift` (m)."""
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float64)
    x, y = cols * pixel - shift[0], -rows * pixel - shift[1]
    return 3 * np.sin(x / 7.0) * np.cos(y / 5.0) + 2 * np.sin((x + y) / 11.0) + 0.05 * x


def test_nuth_kaab_shift_is_xdems_nuthkaab():
    import xdem

    pixel = 0.5
    reference = hills((300, 300), pixel, (0.0, 0.0))
    moving = hills((300, 300), pixel, (0.8, -0.6))  # moved 0.8 m east, 0.6 m south
    moving += np.random.default_rng(1).normal(0, 0.02, moving.shape)
    stable = np.ones(reference.shape, dtype=bool)
    options = {"max_iterations": 20, "tolerance_px": 0.005, "subsample": 50_000, "seed": 42}
    ours = nuth_kaab_shift(reference, moving, stable, (pixel, pixel), **options)

    coreg = xdem.coreg.NuthKaab(max_iterations=20, offset_threshold=0.005, subsample=50_000)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        coreg.fit(
            reference,
            moving,
            inlier_mask=stable,
            transform=from_origin(500_000, 4_000_000, pixel, pixel),
            crs=CRS.from_epsg(32632),
            random_state=42,
        )
    theirs = coreg.meta["outputs"]["affine"]
    # The correction undoes the move, and both give it within a hundredth of a pixel.
    assert ours == pytest.approx((-0.8, 0.6), abs=0.05 * pixel)
    assert ours[0] == pytest.approx(theirs["shift_x"], abs=0.01 * pixel)
    assert ours[1] == pytest.approx(theirs["shift_y"], abs=0.01 * pixel)


def test_nuth_kaab_on_flat_ground_says_there_is_nothing_to_fit():
    flat = np.full((50, 50), 10.0)
    with pytest.raises(NuthKaabError, match="no stable pixel with a slope"):
        nuth_kaab_shift(
            flat, flat, np.ones(flat.shape, bool), (1.0, 1.0),
            max_iterations=5, tolerance_px=0.01, subsample=1000, seed=0,
        )  # fmt: skip


def test_binned_median_is_each_bins_median():
    """Every bin's median as numpy gives it, for odd and even counts, ties, empty bins
    and values outside every bin."""
    rng = np.random.default_rng(5)
    values = np.round(rng.normal(size=50_001), 2)  # rounded: many ties
    bins = rng.integers(-1, 40, values.size)
    bins[bins == 7] = 8  # bin 7 empty
    counts, medians = binned_median(values, bins, 41)
    for b in range(41):
        inside = values[bins == b]
        assert counts[b] == inside.size
        if inside.size:
            assert medians[b] == np.median(inside)
        else:
            assert np.isnan(medians[b])
