"""Dense stereo pairs made to agree (worker/pipeline/pair_adjustment.py): one plane per
pair found where pairs overlap and taken out, the survey's own height and tilt kept."""

import numpy as np
import pytest

from worker.pipeline.pair_adjustment import PairAdjustOptions, apply_planes, pair_planes


def _ground(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 50 + 0.8 * np.sin(x / 3.0) + 0.5 * np.cos(y / 4.0) + 0.3 * np.sin(x * y / 15.0)


def _pairs(
    seed: int,
    count: int = 30,
    offset_sigma: float = 0.05,
    tilt_deg: float = 0.5,
    noise: float = 0.02,
    far_off: dict[int, float] | None = None,
):
    """Dense points of `count` pairs along a line of flight (footprints 6 x 4 m, each 0.5 m
    on from the last, as keyframes 0.5 m apart), each pair's heights off by its own
    plane (offset and tilt drawn, plus `far_off` metres for the pairs named), and the
    true planes at each point."""
    rng = np.random.default_rng(seed)
    points, pair, error = [], [], []
    for p in range(count):
        x0 = 0.5 * p
        x = rng.uniform(x0, x0 + 6.0, 20_000)
        y = rng.uniform(0, 4.0, x.size)
        offset = rng.normal(0, offset_sigma) + (far_off or {}).get(p, 0.0)
        gx, gy = np.tan(np.radians(rng.normal(0, tilt_deg, 2)))
        plane = offset + gx * (x - x0 - 3.0) + gy * (y - 2.0)
        z = _ground(x, y) + plane + rng.normal(0, noise, x.size)
        points.append(np.column_stack([x, y, z]))
        pair.append(np.full(x.size, 100 + 7 * p))  # labels need not be 0..n-1
        error.append(plane)
    return np.concatenate(points), np.concatenate(pair), np.concatenate(error)


def _fitted_plane(points: np.ndarray, values: np.ndarray) -> np.ndarray:
    design = np.column_stack([np.ones(len(points)), points[:, 0], points[:, 1]])
    return np.linalg.lstsq(design, values, rcond=None)[0]


def _dsm_plane(points: np.ndarray, values: np.ndarray, cell_m: float) -> np.ndarray:
    """The plane fitted to each DSM cell's mean of `values`, about the cells' centre."""
    corner = points[:, :2].min(axis=0)
    cells, cell = np.unique(
        np.floor((points[:, :2] - corner) / cell_m), axis=0, return_inverse=True
    )
    cell = cell.ravel()
    per_cell = np.bincount(cell, weights=values) / np.bincount(cell)
    centres = (cells + 0.5) * cell_m
    return _fitted_plane(centres - centres.mean(axis=0), per_cell)


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2)))


def _pair_means(values: np.ndarray, pair: np.ndarray) -> np.ndarray:
    """Each pair's mean of `values`, in the order the pairs were flown."""
    return np.array([values[pair == label].mean() for label in np.unique(pair)])


def test_pairs_made_to_agree_and_the_survey_plane_kept():
    points, pair, error = _pairs(1)
    planes = pair_planes(points, pair, 0.05)
    assert planes.tied.all()
    taken = planes.correction(points, pair)
    # Neighbouring pairs disagree by their own offsets and tilts (5 cm and 0.5 deg
    # drawn); what the overlaps see is taken out: less than a third left between
    # consecutive pairs.
    before = np.diff(_pair_means(error, pair))
    after = np.diff(_pair_means(error - taken, pair))
    assert _rms(before) > 0.04
    assert _rms(after) < 0.33 * _rms(before)
    # What they cannot see, the survey's own height and tilt (as its cameras put it), is
    # kept: the corrections hold no plane of their own over the DSM's cells.
    plane = _dsm_plane(points, taken, 0.05)
    assert abs(plane[0]) < 0.005
    assert np.abs(plane[1:]).max() < 5e-4
    z = points[:, 2].copy()
    apply_planes(points, pair, planes)
    np.testing.assert_allclose(points[:, 2], z - taken)
    figures = planes.to_dict()
    assert figures["pairs"] == figures["pairs_tied"] == 30
    assert figures["disagreement_after_m"] < 0.6 * figures["disagreement_before_m"]


def test_a_pair_metres_off_is_moved_onto_the_others():
    points, pair, error = _pairs(2, far_off={12: 2.0})
    planes = pair_planes(points, pair, 0.05)
    far = pair == 100 + 7 * 12
    taken = planes.correction(points, pair)
    # Moved onto the others (its true offset from them: 2 m and its own 5 cm draw) ...
    true = float(np.mean(error[far]) - np.mean(error[~far]))
    assert float(np.mean(taken[far])) == pytest.approx(true, abs=0.05)
    # ... and the others not pulled towards it.
    assert abs(float(np.mean(taken[~far]))) < 0.01


def test_one_pair_and_pairs_that_never_overlap_are_left_as_they_are():
    points, pair, _ = _pairs(3, count=1)
    planes = pair_planes(points, pair, 0.05)
    assert not planes.tied.any()
    z = points[:, 2].copy()
    apply_planes(points, pair, planes)
    np.testing.assert_array_equal(points[:, 2], z)
    # Two pairs 20 m apart share no cell.
    a, pa, _ = _pairs(4, count=1)
    b, pb, _ = _pairs(5, count=1)
    b[:, 0] += 20.0
    planes = pair_planes(np.concatenate([a, b]), np.concatenate([pa, pb + 1]), 0.1)
    assert not planes.tied.any()
    assert not planes.planes.any()


def test_memory_stays_bounded_by_sampling():
    points, pair, _ = _pairs(6, count=12)
    full = pair_planes(points, pair, 0.05)
    sampled = pair_planes(points, pair, 0.05, PairAdjustOptions(max_points=60_000))
    # A quarter of the points: the same planes to a centimetre.
    assert np.abs(sampled.planes[:, 0] - full.planes[:, 0]).max() < 0.01


def test_a_stray_point_takes_the_plane_at_its_pair_s_edge():
    points, pair, _ = _pairs(7, count=10, tilt_deg=1.0)
    planes = pair_planes(points, pair, 0.05)
    label = pair[0]
    index = int(np.searchsorted(planes.labels, label))
    centre, reach = planes.centres[index], planes.reach[index]
    # A wrong match of the first pair 40 m along x: the plane at the footprint's edge,
    # not its tilt carried 40 m (up to 0.7 m at 1 deg).
    stray = np.array([[centre[0] + 40.0, centre[1], 50.0]])
    edge = np.array([[centre[0] + reach[0], centre[1], 50.0]])
    assert planes.correction(stray, pair[:1]) == pytest.approx(planes.correction(edge, pair[:1]))
    # The reach is about the footprint's half-width: 6 x 4 m, uniform (2 sigma: 3.5, 2.3 m).
    assert reach == pytest.approx([3.46, 2.31], rel=0.05)


@pytest.mark.parametrize("seed", [8, 10])
def test_the_dsm_keeps_its_height_and_tilt_where_pairs_overlap_unevenly(seed):
    """Where more pairs overlap, a DSM cell holds more points (the first half of this
    line holds five times as many): the planes hold the DSM's own height and tilt cell
    by cell, not the points' (a stand-alone flight's DSM was tilted by 1 cm per 100
    cells when the sums were over the points)."""
    # Tilts only (pairs far off what most needed are moved onto the others and left
    # out of the sums: none here).
    points, pair, _ = _pairs(seed, offset_sigma=0.0, tilt_deg=1.0)
    keep = (points[:, 0] < 9.0) | (np.random.default_rng(seed).random(len(points)) < 0.2)
    points, pair = points[keep], pair[keep]
    cell_m = 0.05
    planes = pair_planes(points, pair, cell_m)
    taken = planes.correction(points, pair)
    plane = _dsm_plane(points, taken, cell_m)
    # Sums over the points left 0.5-1.2 mm and 0.02-0.13 % here.
    assert abs(plane[0]) < 0.0003
    assert np.abs(plane[1:]).max() < 2.5e-4
