"""The adjustments of one straight flight line keep the rotation the attitude-aided fit
gave it: the pose-prior bundle adjustment (worker/pipeline/georef_map.py
`_refine_segment`, `world_adjust=False`) and the world-frame adjustment
(worker/pipeline/georef_world.py, the default, where the logged tilt holds the roll),
with RTK positions and with positions that state no accuracy.

Positions along a straight line say nothing of a roll about it, so COLMAP's alignment to
the priors may turn the segment about the line; the undo must see that turn in the
cameras' viewing directions, not in their centres alone (measured on a simulated 8-s
flight over the mounds: an 8.5 deg roll, the DSM tilted 15 cm per metre)."""

import numpy as np
import pytest

from tests.reconstruction.line_survey import ORIGIN, RTK, line_log, line_map
from worker.pipeline.attitude import rotation_angle_deg, rotation_world_from_camera
from worker.pipeline.georef import GeorefOptions
from worker.pipeline.georef_map import MapGeorefOptions, georeference_map


@pytest.mark.parametrize(
    ("world", "stated"),
    [(False, RTK), (True, RTK), (True, None)],
    ids=["pose-prior BA", "world adjustment, RTK", "world adjustment, no stated accuracy"],
)
def test_a_straight_line_keeps_its_roll_through_the_adjustment(world, stated):
    for seed in (1, 2, 3):
        sparse, truth, _ = line_map(seed)
        # Adjusted although straight (the pose-prior BA does not adjust straight lines by
        # default, see the test below).
        options = MapGeorefOptions(
            refine=True,
            refine_min_straightness=0.0,
            world_adjust=world,
            georef=GeorefOptions(position_sigma_m=stated),
        )
        result = georeference_map(sparse, line_log(seed), 0.0, options)
        refinement = result.segments[0]["refinement"]
        assert refinement["kept"] if world else refinement["priors_used"] > 0
        down = rotation_world_from_camera(np.zeros(12), -90.0, np.zeros(12))
        tilt = rotation_angle_deg(sparse.kf_r.transpose(0, 2, 1), down)
        assert tilt.max() < 0.5, (seed, tilt.max())
        heights = sparse.point_xyz[:, 2] - ORIGIN[2] - truth[:, 2]
        # A roll of 1 deg would tilt the ground by 1.7 cm per metre, 20 cm at its edges
        # (the old undo left it turned by 42 deg here).
        across = np.polyfit(truth[:, 0], heights, 1)[0]
        along = np.polyfit(truth[:, 1], heights, 1)[0]
        assert abs(across) < 0.003 and abs(along) < 0.005, (seed, across, along)
        # Two-view depth noise of 2-m baselines at 18 m, not a tilt.
        assert np.percentile(np.abs(heights - np.median(heights)), 95) < 0.25


def test_a_straight_line_is_not_adjusted_by_the_pose_prior_ba():
    sparse, _, _ = line_map(1)
    before = sparse.point_xyz.copy()
    result = georeference_map(sparse, line_log(1), 0.0, MapGeorefOptions(world_adjust=False))
    assert result.segments[0]["refinement"]["skipped"].startswith("a near-straight track")
    # The points moved by the fitted similarity alone: distances between them kept,
    # times its scale of 2.
    pairs = np.random.default_rng(0).integers(0, len(before), (200, 2))
    ratio = np.linalg.norm(
        sparse.point_xyz[pairs[:, 0]] - sparse.point_xyz[pairs[:, 1]], axis=1
    ) / np.maximum(np.linalg.norm(before[pairs[:, 0]] - before[pairs[:, 1]], axis=1), 1e-9)
    assert np.median(ratio) == pytest.approx(2.0, rel=0.01)
    assert np.ptp(ratio[np.isfinite(ratio) & (ratio > 0)]) < 1e-6
