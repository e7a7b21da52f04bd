"""The benchmark's pair generators: deterministic, honest truth, errors that add up.

Each generator is built three times per module run (pair and twin of one seed, and a
second seed) by a module-scoped fixture; pytest runs all tests of one generator before
building the next, so only one generator's arrays are alive at a time.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass

import numpy as np
import pytest
import rasterio
from scipy import ndimage

from worker.pairgen import GENERATORS, DsmPair, PairGenerator, SlideTruth, make_pair
from worker.pairgen.errors import ERRORS, draw_errors
from worker.pairgen.generators import PairParts
from worker.pairgen.pair import PAIR_CRS, PAIR_ORIGIN_EN
from worker.pairgen.real_terrain import sample_dem
from worker.pairgen.slides import KINDS, SlideSpec, make_slide, place_slide
from worker.pairgen.surfaces import Scene, Trees, apply_slides, render
from worker.pairgen.terrain import TERRAINS

SEED = 3
NAMES = (
    "fractal-forest",
    "ridge-debris",
    "terraced-strips",
    "agri-shallow",
    "urban-rockfall",
    "mountain-deep",
    "real-relief",
)
# Errors whose value at a pixel depends on the DSM around it (resampling, inpainting):
# a pair and its twin differ there near the slides, and only there.
CONTENT_DEPENDENT = {"shift", "rotation", "resolution", "holes"}
NEAR_SLIDE_PX = 16


@dataclass
class Built:
    gen: PairGenerator
    parts: PairParts
    twin: PairParts
    other: DsmPair  # another seed

    @property
    def pair(self) -> DsmPair:
        return self.parts.pair


@pytest.fixture(scope="module", params=NAMES)
def built(request: pytest.FixtureRequest) -> Built:
    gen = GENERATORS[request.param]
    return Built(gen, gen.build(SEED), gen.build(SEED, no_change=True), gen.make(SEED + 1))


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True)


def _nmad(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


ARRAYS = ("pre", "post", "true_dh", "slide_labels", "surface_change", "observation_error")


def test_registry_names_and_declarations() -> None:
    assert tuple(GENERATORS) == NAMES
    for name, gen in GENERATORS.items():
        assert gen.name == name
        assert gen.summary and "\n" not in gen.summary
        assert set(gen.slides) <= set(KINDS) and len(gen.slides) == 2
        assert set(gen.errors) <= set(ERRORS)
        assert 0 < gen.pixel_size[0] <= gen.pixel_size[1]
        assert gen.side_px == (384, 640)
    with pytest.raises(dataclasses.FrozenInstanceError):
        GENERATORS["fractal-forest"].name = "other"  # type: ignore[misc]


def test_same_seed_same_pair(built: Built) -> None:
    again = built.gen.make(SEED)
    for key in ARRAYS:
        assert _same(getattr(built.pair, key), getattr(again, key)), key
    assert again.slides == built.pair.slides
    assert again.description == built.pair.description


def test_other_seed_other_pair(built: Built) -> None:
    a, b = built.pair, built.other
    assert a.shape != b.shape or not np.array_equal(a.pre, b.pre, equal_nan=True)
    assert a.description["noise_sigma_m"] != b.description["noise_sigma_m"]


def test_grid_and_dtypes(built: Built) -> None:
    pair, gen = built.pair, built.gen
    assert all(384 <= side <= 640 for side in pair.shape)
    assert gen.pixel_size[0] <= pair.pixel_size <= gen.pixel_size[1]
    for key in ("pre", "post", "true_dh", "observation_error"):
        assert getattr(pair, key).dtype == np.float32 and getattr(pair, key).shape == pair.shape
    assert pair.slide_labels.dtype == np.int16 and pair.surface_change.dtype == bool
    json.dumps(pair.truth_dict())  # the description is JSON as it stands


def test_slides_of_declared_kinds_and_depths(built: Built) -> None:
    specs = {s.kind: s for s in built.gen.slide_specs}
    for pair in (built.pair, built.other):
        assert 1 <= len(pair.slides) <= 2
        assert [s.id for s in pair.slides] == list(range(1, len(pair.slides) + 1))
        for slide in pair.slides:
            assert slide.kind in built.gen.slides
            lo, hi = specs[slide.kind].depth_m
            assert lo * 0.999 <= slide.max_depth_m <= hi * 1.001, slide
            # Realisable at the pixel size: at least ~8 x 8 pixels and 8 pixels long.
            assert slide.area_px >= 64 and slide.length_m >= 8 * pair.pixel_size


def test_truth_agrees_with_arrays(built: Built) -> None:
    for pair in (built.pair, built.other):
        dh, labels, area = pair.true_dh.astype(np.float64), pair.slide_labels, pair.pixel_size**2
        assert np.all(dh[labels == 0] == 0)
        assert set(np.unique(labels)) == {0, *(s.id for s in pair.slides)}
        for s in pair.slides:
            on = dh[labels == s.id]
            assert s.area_px == on.size and s.area_m2 == pytest.approx(on.size * area)
            assert s.volume_loss_m3 == pytest.approx(-on[on < 0].sum() * area, rel=1e-4)
            assert s.volume_gain_m3 == pytest.approx(on[on > 0].sum() * area, rel=1e-4)
            assert s.max_depth_m == pytest.approx(np.abs(on).max(), rel=1e-5)
            # The footprint is where |dh| passes the threshold, nowhere else.
            assert np.abs(on).min() > max(0.01, 0.01 * s.max_depth_m) * (1 - 1e-5)
            assert s.length_m <= np.hypot(*pair.shape) * pair.pixel_size
        assert not (pair.surface_change & (labels > 0)).any()


def test_heights_add_up(built: Built) -> None:
    parts, pair = built.parts, built.pair
    finite = np.isfinite(pair.pre) & np.isfinite(pair.post)
    assert finite.mean() > 0.9
    left = pair.post.astype(np.float64) - pair.pre
    right = pair.true_dh.astype(np.float64) + parts.surface_heights + pair.observation_error
    # float32 storage of heights of hundreds of metres: 0.1 mm of rounding.
    np.testing.assert_allclose(left[finite], right[finite], atol=1e-3)
    # The observation error is what the error models added to each survey, nothing else.
    added = (pair.post - parts.post_true) - (pair.pre - parts.pre_true)
    np.testing.assert_allclose(pair.observation_error[finite], added[finite], atol=1e-3)
    assert np.array_equal(np.isfinite(pair.observation_error), finite)
    # Ground + surface: surfaces stand on the ground (grass, crowns, roofs never below).
    assert (parts.pre_true - parts.ground_pre).min() >= -1e-9
    # The ground moved by the slides alone (true_dh is its float32 copy).
    assert np.abs(parts.ground_post - parts.ground_pre - pair.true_dh).max() < 1e-5


def test_error_nmad_is_plausible(built: Built) -> None:
    pair, sigma = built.pair, built.parts.sigma_m
    lo, hi = built.gen.noise_sigma_m
    assert lo <= sigma <= hi
    # Two independent surveys of noise sigma make sqrt(2) sigma; the other error models
    # add to that, registration on trees or steep slopes most.
    assert 1.0 * sigma <= pair.error_nmad_m <= 5.0 * sigma
    assert pair.error_nmad_m == pytest.approx(_nmad(pair.observation_error))
    lods = [s["depth_lod"] for s in pair.description["slides"]]
    assert lods == pytest.approx([s.max_depth_m / (1.96 * pair.error_nmad_m) for s in pair.slides])


def test_twin_is_the_pair_without_slides(built: Built) -> None:
    pair, twin = built.pair, built.twin.pair
    assert twin.no_change and not pair.no_change
    assert twin.slides == [] and not twin.slide_labels.any() and not twin.true_dh.any()
    assert _same(pair.pre, twin.pre)
    assert twin.description["errors"] == pair.description["errors"]
    assert twin.description["noise_sigma_m"] == pair.description["noise_sigma_m"]
    # Resampling errors depend on the surface around a pixel: where the slides changed
    # the true post surface (their footprints, trees they took) and nearby, they differ.
    changed = built.parts.post_true != built.twin.post_true
    # (Under a crown that overhangs a slide the DSM is the crown's, unchanged.)
    assert changed[pair.slide_labels > 0].mean() > 0.5
    near = ndimage.binary_dilation(changed, iterations=NEAR_SLIDE_PX)
    a, b = pair.observation_error, twin.observation_error
    differs = ~((np.isnan(a) & np.isnan(b)) | (np.abs(a - b) <= 1e-4))
    if set(built.gen.errors) & CONTENT_DEPENDENT:
        # Inpainting reaches as far as a hole is wide: a few pixels may differ further.
        assert differs[~near].mean() < 0.002
    else:
        assert not differs.any()
    # Without slides the surface changes are the non-landslide ones, the same as the pair's
    # away from its slides.
    far = ~ndimage.binary_dilation(near, iterations=int(8.0 / pair.pixel_size))
    assert np.array_equal(pair.surface_change[far], twin.surface_change[far])


def test_make_pair_and_unknown_name() -> None:
    pair = make_pair("ridge-debris", 11, no_change=True)
    assert pair.generator == "ridge-debris" and pair.seed == 11 and pair.slides == []
    with pytest.raises(KeyError, match="available"):
        make_pair("no-such-generator", 1)


def test_write_geotiffs_and_truth(tmp_path) -> None:
    pair = make_pair("terraced-strips", 5)
    paths = pair.write(tmp_path)
    for key in ("pre", "post"):
        with rasterio.open(paths[key]) as src:
            assert src.transform == pair.transform and src.crs == PAIR_CRS
            assert (src.height, src.width) == pair.shape
            assert src.transform.c == PAIR_ORIGIN_EN[0] and src.transform.f == PAIR_ORIGIN_EN[1]
            assert src.transform.a == pytest.approx(pair.pixel_size)
            data = src.read(1, masked=True)
            expected = getattr(pair, key)
            assert np.array_equal(data.mask, np.isnan(expected))
            assert np.array_equal(data.filled(np.nan), expected, equal_nan=True)
    with rasterio.open(paths["truth"]) as src:
        assert src.transform == pair.transform
        assert np.array_equal(src.read(1), pair.slide_labels.astype(np.uint8))
    truth = json.loads(paths["truth_json"].read_text())
    assert truth["generator"] == "terraced-strips" and truth["seed"] == 5
    assert [SlideTruth(**s) for s in truth["slides"]] == pair.slides
    assert truth["error_nmad_m"] == pytest.approx(pair.error_nmad_m)


def _shift_peak(pre: np.ndarray, post: np.ndarray) -> tuple[float, float]:
    """Where `post` matches `pre` best (rows, cols), by phase correlation of the
    high-passed surfaces, refined to sub-pixel by a parabola through the peak."""
    a = pre - ndimage.gaussian_filter(pre, 4)
    b = post - ndimage.gaussian_filter(post, 4)
    fa, fb = np.fft.fft2(a), np.fft.fft2(b)
    cross = np.conj(fa) * fb
    corr = np.fft.ifft2(cross / np.maximum(np.abs(cross), 1e-12)).real
    peak = np.unravel_index(np.argmax(corr), corr.shape)
    out = []
    for axis, size in enumerate(corr.shape):
        i = peak[axis]
        step = [0, 0]
        step[axis] = 1
        left = corr[(peak[0] - step[0]) % corr.shape[0], (peak[1] - step[1]) % corr.shape[1]]
        right = corr[(peak[0] + step[0]) % corr.shape[0], (peak[1] + step[1]) % corr.shape[1]]
        centre = corr[peak]
        sub = 0.5 * (left - right) / (left - 2 * centre + right)
        out.append(((i + size // 2) % size - size // 2) + sub)
    return out[0], out[1]


@pytest.mark.parametrize("shift_px", [0.0, 1.5, 2.5])
def test_registration_shift_is_visible(shift_px: float) -> None:
    # Bare twin with the shift as its only error: nothing else differs between surveys.
    gen = dataclasses.replace(
        GENERATORS["fractal-forest"],
        surface="bare",
        errors=("shift",),
        error_params={"shift_px": (shift_px, shift_px), "shift_angle_deg": (0.0, 0.0)},
    )
    pair = gen.make(2, no_change=True)
    rows, cols = _shift_peak(pair.pre.astype(np.float64), pair.post.astype(np.float64))
    assert rows == pytest.approx(0.0, abs=0.2)
    assert cols == pytest.approx(shift_px, abs=0.2)
    assert pair.description["errors"]["shift"]["cols_px"] == pytest.approx(shift_px)


def test_error_draws_ignore_the_dsms() -> None:
    """Strip steps, holes and spikes are drawn from the grid alone: same seed, same draw."""
    rng = [np.random.default_rng(4) for _ in range(2)]
    names = ("white", "strips", "holes", "outliers")
    a = draw_errors(names, (400, 500), 0.1, 0.05, rng[0], {"holes_nan_chance": 1.0})
    b = draw_errors(names, (400, 500), 0.1, 0.05, rng[1], {"holes_nan_chance": 1.0})
    assert np.array_equal(a.post.additive, b.post.additive)
    assert not a.pre.holes_fill and 0.004 < a.pre.holes.mean() < 0.04
    spikes = np.abs(a.pre.outliers[a.pre.outliers != 0])
    assert spikes.min() >= 5 * 0.05 and spikes.max() <= 30 * 0.05
    # Steps between neighbouring strips are 0.5-3 sigma.
    steps = a.description["pre"]["strips"]["mean_step_sigma"]
    assert 0.5 <= steps <= 3.0


# Terrain, pixel size and spec on which each kind of slide is made in isolation.
SLIDE_CASES = {
    "rotational": ("fractal", 0.2, SlideSpec("rotational", (30.0, 40.0), (2.0, 3.0))),
    "translational": ("fractal", 0.2, SlideSpec("translational", (30.0, 40.0), (2.0, 3.0))),
    "shallow": ("ridge-valley", 0.2, SlideSpec("shallow", (8.0, 12.0), (0.5, 0.8))),
    "deep-seated": ("mountain", 0.8, SlideSpec("deep-seated", (120.0, 150.0), (12.0, 15.0))),
    "debris-flow": ("mountain", 0.8, SlideSpec("debris-flow", (15.0, 20.0), (2.0, 3.0))),
    "rockfall": ("urban", 0.3, SlideSpec("rockfall", (5.0, 8.0), (1.0, 2.0))),
}


@pytest.mark.parametrize("kind", list(SLIDE_CASES))
def test_slide_model_shapes(kind: str) -> None:
    terrain, pixel, spec = SLIDE_CASES[kind]
    rng = np.random.default_rng(21)
    ground = TERRAINS[terrain]((448, 448), pixel, rng)
    plan = spec.draw(rng)
    slide = make_slide(plan, ground, pixel, rng)
    assert slide is not None and slide.kind == kind
    truth = slide.truth(1, pixel)
    assert truth.max_depth_m == pytest.approx(plan.depth_m)
    rows, cols = np.nonzero(slide.footprint)
    margin = max(8, int(0.04 * 448))
    assert rows.min() >= margin and cols.min() >= margin
    assert rows.max() < 448 - margin and cols.max() < 448 - margin
    gain_over_loss = truth.volume_gain_m3 / truth.volume_loss_m3
    expected = {  # the volume each model puts back for what it removes
        "rotational": (0.98, 1.02),
        "translational": (0.98, 1.02),
        "deep-seated": (0.99, 1.06),
        "shallow": (0.78, 1.01),
        "debris-flow": (0.99, 1.16),
        "rockfall": (1.28, 1.62),
    }[kind]
    assert expected[0] <= gain_over_loss <= expected[1]
    if kind == "debris-flow":
        # Runout several times the source: 4-7 source lengths from head to fan toe.
        assert truth.length_m >= 3.5 * plan.length_m
    else:
        assert truth.length_m <= 1.3 * plan.length_m or kind == "rockfall"
    # Loss upslope, gain downslope: the centroid of the gain lies below that of the loss.
    z = ndimage.gaussian_filter(ground, 3)
    loss_z = z[slide.dh < 0].mean()
    gain_z = z[slide.dh > 0].mean()
    assert gain_z < loss_z


def test_trees_on_slides_are_carried_or_removed() -> None:
    rng = np.random.default_rng(8)
    ground = TERRAINS["fractal"]((400, 400), 0.2, rng)
    plan = SlideSpec("translational", (40.0, 40.0), (3.0, 3.0)).draw(rng)
    slab = make_slide(plan, ground, 0.2, rng)
    assert slab is not None
    on_slab = np.argwhere(slab.carried & slab.footprint)[0].astype(float)
    off = np.array([5.0, 5.0])
    trees = Trees(
        np.array([on_slab[0], off[0]]),
        np.array([on_slab[1], off[1]]),
        np.array([20.0, 20.0]),
        np.array([3.0, 3.0]),
        np.array([0.6, 0.6]),
        np.array([False, False]),
    )
    moved = apply_slides(Scene(trees=trees), [slab], 0.2).trees
    d_row, d_col = slab.displacement_m
    assert np.hypot(d_row, d_col) == pytest.approx(slab.description["displacement_m"])
    assert moved.row[0] == pytest.approx(on_slab[0] + d_row / 0.2)
    assert moved.col[0] == pytest.approx(on_slab[1] + d_col / 0.2)
    assert (moved.row[1], moved.col[1]) == (off[0], off[1])
    # A shallow slip uproots what stands on it.
    slip = dataclasses.replace(slab, kind="shallow")
    assert len(apply_slides(Scene(trees=trees), [slip], 0.2).trees) == 1
    # The crown stands on its trunk's ground: top = ground + height.
    dsm = render(Scene(trees=trees), ground, 0.2)
    r, c = int(off[0]), int(off[1])
    assert dsm[r, c] == pytest.approx(ground[r, c] + 20.0, abs=0.2)


def test_kind_functions_return_dh_footprint_and_truth() -> None:
    rng = np.random.default_rng(5)
    ground = TERRAINS["mountain"]((400, 400), 0.8, rng)
    out = place_slide("debris-flow", ground, 0.8, rng, length_m=15.0, depth_m=2.0, slide_id=2)
    assert out is not None
    dh, footprint, truth = out
    assert truth.id == 2 and truth.kind == "debris-flow"
    assert not dh[~footprint].any() and truth.area_px == np.count_nonzero(footprint)
    assert truth.max_depth_m == pytest.approx(2.0)
    # Next to it, another slide keeps its distance.
    other = place_slide(
        "debris-flow", ground, 0.8, rng, length_m=15.0, depth_m=2.0, occupied=footprint
    )
    assert other is not None
    gap = ndimage.distance_transform_edt(~footprint)[other[1]].min()
    assert gap > 6


def test_real_relief_keeps_the_real_slopes() -> None:
    # Windows of the sample DEM scaled down to 0.5-1 m pixels keep the angles of the
    # real Cumberland Mountains: median slope 13° over the whole DEM.
    dem, row_m, col_m = sample_dem()
    gy, gx = np.gradient(dem, row_m, col_m)
    real = float(np.degrees(np.arctan(np.median(np.hypot(gx, gy)))))
    slopes = []
    for seed in range(6):
        pixel = 0.5 + 0.1 * seed
        ground = TERRAINS["real"]((400, 400), pixel, np.random.default_rng(seed))
        sy, sx = np.gradient(ndimage.gaussian_filter(ground, 3 / pixel), pixel)
        slopes.append(float(np.degrees(np.arctan(np.median(np.hypot(sx, sy))))))
    assert real == pytest.approx(13.3, abs=0.5)
    assert np.median(slopes) == pytest.approx(real, rel=0.25)
    assert np.array_equal(
        TERRAINS["real"]((64, 64), 0.5, np.random.default_rng(1)),
        TERRAINS["real"]((64, 64), 0.5, np.random.default_rng(1)),
    )
