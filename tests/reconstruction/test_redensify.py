"""Dense pairs matched again on the georeferenced poses (slam/redensify.py)."""

import numpy as np
import pytest

from tests.reconstruction.keyframe_maps import keyframe_map
from tests.reconstruction.test_slam_parts import K, render_gray, terrain  # noqa: F401
from worker.pipeline.slam.redensify import (
    KeyframePoses,
    RedensifyOptions,
    plan_redensify,
    redensify,
)

# Four keyframes along a line 60 m above the ground, 6 m apart (a baseline of a tenth of
# the depth, as the flights' pairs have).
CENTRES = np.array([[0.0, 6.0 * i - 9.0, 110.0] for i in range(4)])


def _turned(r_cw: np.ndarray, degrees: float) -> np.ndarray:
    """The camera turned by `degrees` about its own x axis."""
    a = np.radians(degrees)
    turn = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    return turn @ r_cw


def _survey(terrain):  # noqa: F811
    """The line's map on its true poses, its points the surface each keyframe sees, with
    one pair's points wrong (as SLAM left them on a wrong pose), and its images."""
    grid, dsm, renderer = terrain
    images, rotations = {}, []
    for i, centre in enumerate(CENTRES):
        images[i], r = render_gray(renderer, centre)
        rotations.append(r.T)
    r = np.array(rotations)
    tr = -np.einsum("nij,nj->ni", r, CENTRES)
    x, y = grid.mesh()
    points = np.column_stack(
        [x[::40, ::40].ravel(), y[::40, ::40].ravel(), dsm[::40, ::40].ravel()]
    )
    obs_kf, obs_point = [], []
    for i in range(len(CENTRES)):
        cam = points @ r[i].T + tr[i]
        u = K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 2]
        v = K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2]
        seen = np.flatnonzero((u >= 0) & (u < 640) & (v >= 0) & (v < 360))
        obs_kf += [i] * len(seen)
        obs_point += seen.tolist()
    sparse = keyframe_map(K, (640, 360), r, tr, obs_kf, obs_point, points)
    rng = np.random.default_rng(5)
    wrong = rng.uniform([-20, -10, 30], [20, 10, 90], (1000, 3)).astype(np.float32)
    sparse.dense_kf = np.zeros(1000, np.int32)
    sparse.dense_partner = np.ones(1000, np.int32)
    sparse.dense_xyz = wrong
    sparse.dense_baseline = np.full(1000, 6.0)
    return grid, dsm, sparse, images


def _errors(grid, dsm, world: np.ndarray) -> np.ndarray:
    col, row = grid.col_row(world[:, 0], world[:, 1])
    truth = dsm[
        np.clip(np.rint(row).astype(int), 0, grid.height - 1),
        np.clip(np.rint(col).astype(int), 0, grid.width - 1),
    ]
    return world[:, 2] - truth


def test_a_pair_whose_cameras_the_georeference_turned_is_matched_again(terrain):  # noqa: F811
    """SLAM had the second camera turned by 3° (its epipolar lines 22 px off): the pair's
    points are dropped and matched again on the corrected poses, and with an RTK log the
    keyframes without a pair get partners; all of them on the surface."""
    grid, dsm, sparse, images = _survey(terrain)
    tracked = KeyframePoses.of(sparse)
    tracked.r[1] = _turned(tracked.r[1], 3.0)
    # A stand-alone log: the pair only (the others' baselines are the log's metres).
    plan = plan_redensify(tracked, sparse, log_sigma_m=2.0)
    assert plan.redo == [(0, 1)] and plan.new == []
    # An RTK log: each of the others too, with the partners nearest a tenth and a fifth
    # of the depth.
    plan = plan_redensify(tracked, sparse, log_sigma_m=0.02)
    assert plan.redo == [(0, 1)]
    assert plan.new == [(1, 0), (1, 3), (2, 1), (2, 0), (3, 2), (3, 1)]
    report = redensify(sparse, images, plan)
    assert report.pairs_matched_again == 1 and report.points_dropped == 1000
    assert report.keyframes_paired == 3
    assert set(sparse.dense_kf.tolist()) == {0, 1, 2, 3}
    pair = (sparse.dense_kf == 0) & (sparse.dense_partner == 1)
    assert pair.sum() > 30000  # of the 57 600 pixels sampled
    err = _errors(grid, dsm, sparse.dense_points())
    assert report.points_added == len(err)
    # 1.4 m per pixel of disparity at this baseline: a twentieth of a pixel of bias,
    # under 0.3 px of noise, as one pair gives (test_slam_parts).
    assert abs(np.median(err)) < 0.1
    assert 1.4826 * np.median(np.abs(err - np.median(err))) < 0.3


@pytest.mark.parametrize(("baseline_turn", "relative_turn"), [(0.0, 0.5), (2.0, 0.0)])
def test_pairs_the_georeference_barely_moved_are_kept(terrain, baseline_turn, relative_turn):  # noqa: F811
    """A pair moved within what matching tolerates (up to 2.5° and 0.55° on flights
    whose tracking held) keeps its points; a scale change alone never counts."""
    _, _, sparse, _ = _survey(terrain)
    tracked = KeyframePoses.of(sparse)
    # Every camera turned alike (the baselines turn in their frames), then the second.
    for i in range(len(CENTRES)):
        tracked.r[i] = _turned(tracked.r[i], baseline_turn)
    tracked.r[1] = _turned(tracked.r[1], relative_turn)
    centres = tracked.centres() * 3.0  # the map's own scale, three times the world's
    tracked = KeyframePoses(tracked.t, tracked.r, -np.einsum("nij,nj->ni", tracked.r, centres))
    plan = plan_redensify(tracked, sparse, RedensifyOptions(), log_sigma_m=0.02)
    # Nor are keyframes without a pair given one: SLAM tried them on the same geometry.
    assert plan.redo == [] and plan.new == []
