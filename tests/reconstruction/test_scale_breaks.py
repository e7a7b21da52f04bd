"""A monocular map whose scale collapses partway (as on a cross pattern's turn): the
break found against the log's distances, the segment cut there, the broken part left
out with the reason, the rest placed on its own (worker/pipeline/scale_breaks.py)."""

import numpy as np
import pytest
from pyproj import Transformer

from tests.reconstruction.position_log import position_log
from worker.pipeline.attitude import rotation_world_from_camera
from worker.pipeline.georef_map import MapGeorefOptions, georeference_map
from worker.pipeline.quality import survey_quality
from worker.pipeline.scale_breaks import ScaleBreakOptions, consistent_runs, local_scales
from worker.pipeline.slam.result import SparseMap

EPSG = 32633
ORIGIN = np.array([500_000.0, 5_200_000.0, 300.0])
K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 180.0], [0.0, 0.0, 1.0]])
BREAK_S = 60.0
TIMES = np.arange(0.0, 110.0, 0.5)  # keyframe times


def true_path(t: np.ndarray) -> np.ndarray:
    """Lines 40 m long flown at 2 m/s, 8 m apart, at 20 m (metres from ORIGIN)."""
    leg = np.floor(t / 20.0)
    along = (t % 20.0) * 2.0
    x = np.where(leg % 2 == 0, along, 40.0 - along)
    return np.column_stack([x, 8.0 * leg, np.full(t.size, 20.0)])


def stand_alone_log(seed: int):
    """Stand-alone GPS: a bias of metres, a slow random-walk drift, 0.3 m of noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 115.0, 0.1)
    drift = np.cumsum(rng.normal(0, 0.02, (t.size, 3)), axis=0)
    positions = ORIGIN + true_path(t) + [2.0, -1.5, 3.0] + drift + rng.normal(0, 0.3, (t.size, 3))
    return position_log(t, positions, EPSG)


def map_centres(collapse: bool) -> np.ndarray:
    """The camera centres as a SLAM map has them: the path at 0.4 of its size, turned
    a quarter and moved; with `collapse`, every step after BREAK_S shorter than the one
    before, as a scale that collapses (down to a twentieth by the end)."""
    truth = true_path(TIMES)
    steps = np.diff(truth, axis=0)
    if collapse:
        late = TIMES[1:] > BREAK_S
        steps[late] *= np.exp(-(TIMES[1:][late] - BREAK_S) / 16.0)[:, None]
    centres = 0.4 * np.vstack([truth[:1], truth[0] + np.cumsum(steps, axis=0)])
    turn = rotation_world_from_camera(90.0, 0.0, 0.0)
    return centres @ turn.T + [40.0, -7.0, 3.0]


def sparse_map(centres: np.ndarray) -> SparseMap:
    n = len(centres)
    turn = rotation_world_from_camera(90.0, 0.0, 0.0)
    world_from_cam = rotation_world_from_camera(np.full(n, 90.0), -90.0, np.zeros(n))
    r = np.einsum("ij,njk->nik", turn, world_from_cam).transpose(0, 2, 1)
    segment = np.zeros(n, np.int32)
    # One point under each keyframe, seen by it and the next one.
    obs_kf = np.concatenate([np.arange(n), np.arange(1, n)])
    obs_point = np.concatenate([np.arange(n), np.arange(n - 1)])
    order = np.argsort(obs_point, kind="stable")
    return SparseMap.from_keyframes(
        K,
        (640, 360),
        t=TIMES.copy(),
        r=r,
        tr=-np.einsum("nij,nj->ni", r, centres),
        segment=segment,
        obs_kf=obs_kf[order],
        obs_point=obs_point[order],
        obs_uv=np.full((2 * n - 1, 2), 100.0),
        point_id=np.arange(n),
        point_xyz=centres - [0.0, 0.0, 8.0],
        point_segment=segment,
    )


def log_positions(log, times: np.ndarray) -> np.ndarray:
    values = log.interpolate(times)
    east, north = Transformer.from_crs("EPSG:4326", f"EPSG:{EPSG}", always_xy=True).transform(
        values["lon"], values["lat"]
    )
    return np.column_stack([east, north, values["alt"]])


@pytest.mark.parametrize("seed", range(5))
def test_the_break_is_found_where_the_scale_collapses_and_nowhere_else(seed):
    world = log_positions(stand_alone_log(seed), TIMES)
    options = ScaleBreakOptions()
    steady = consistent_runs(local_scales(world, map_centres(False), 8.0), options)
    assert steady == [(0, TIMES.size)]
    runs = consistent_runs(local_scales(world, map_centres(True), 8.0), options)
    first_end = TIMES[runs[0][1]]
    # The local scale at a keyframe spans the next 8 m (4 s at 2 m/s): the break can be
    # seen from that much before it; a gradual collapse passes the 1.3 tolerance against
    # the run's median 4 s after it, and the median follows it a little.
    assert BREAK_S - 4.5 <= first_end <= BREAK_S + 8.0, runs
    assert runs[0][1] - runs[0][0] > 100


def test_a_collapsed_part_is_left_out_and_the_rest_placed_on_its_own():
    log = stand_alone_log(0)
    sparse = sparse_map(map_centres(True))
    result = georeference_map(sparse, log, 0.0, MapGeorefOptions(refine=False))
    (entry,) = result.segments
    (reason,) = result.warnings
    assert reason.startswith("segment 1 left out: the part of segment 0 from ")
    start_s = float(reason.split(" from ")[1].split(" s ")[0])
    assert BREAK_S - 4.5 <= start_s <= BREAK_S + 8.0
    assert "to 109.5 s: the reconstruction's scale broke there" in reason
    # What is kept is the flight before the break, now within the GPS's own noise.
    assert sparse.kf_t.max() < start_s and set(sparse.kf_segment.tolist()) == {0}
    after = entry["residuals_after_m"]
    assert np.hypot(after["rms_east"], after["rms_north"]) < 1.0
    cameras = sparse.kf_centres()
    truth = ORIGIN + true_path(sparse.kf_t) + [2.0, -1.5, 3.0]  # the log's bias
    assert np.sqrt(((cameras - truth)[:, :2] ** 2).sum(axis=1).mean()) < 1.0
    # The survey's report names the part left out and passes on what is kept.
    quality = survey_quality({"georeference": result.to_dict()})
    checks = {c["name"]: c for c in quality["checks"]}
    assert checks["segments_dropped"]["value"] == 1 and checks["segments_dropped"]["passed"]
    assert checks["georeference_residual"]["passed"]


def test_without_the_cut_the_collapsed_segment_misses_its_bound():
    """The same map with the cut turned off: one segment whose cameras miss the log by
    more than the stand-alone bound, the result the cut replaces."""
    sparse = sparse_map(map_centres(True))
    options = MapGeorefOptions(refine=False, scale_breaks=ScaleBreakOptions(enabled=False))
    result = georeference_map(sparse, stand_alone_log(0), 0.0, options)
    after = result.segments[0]["residuals_after_m"]
    assert np.hypot(after["rms_east"], after["rms_north"]) > 5.0
    quality = survey_quality({"georeference": result.to_dict()})
    assert not {c["name"]: c for c in quality["checks"]}["georeference_residual"]["passed"]


def test_a_steady_map_is_not_cut():
    sparse = sparse_map(map_centres(False))
    result = georeference_map(sparse, stand_alone_log(1), 0.0, MapGeorefOptions(refine=False))
    assert len(result.segments) == 1 and not result.warnings
    assert sparse.kf_t.size == TIMES.size


def test_split_segment_moves_keyframes_frames_and_points_after_the_cut():
    sparse = sparse_map(map_centres(False))
    cut = int(np.searchsorted(TIMES, 30.0))
    new = sparse.split_segment(0, cut)
    assert new == 1
    assert (sparse.kf_segment[:cut] == 0).all() and (sparse.kf_segment[cut:] == 1).all()
    assert (sparse.fr_segment == sparse.kf_segment).all()  # frames follow their keyframe
    # A point goes with the keyframe that saw it first: point cut - 1, seen by keyframes
    # cut - 1 and cut, stays.
    assert (sparse.point_segment[:cut] == 0).all() and (sparse.point_segment[cut:] == 1).all()
