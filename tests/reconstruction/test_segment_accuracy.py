"""A video segment's georeference checked against the log's accuracy: within it, missed
(reported), or broken beyond repair (left out with the reason when another segment holds;
worker/pipeline/georef_map.py `_check_segments`)."""

import numpy as np
import pytest

from tests.reconstruction.position_log import position_log
from worker.pipeline.attitude import rotation_world_from_camera
from worker.pipeline.georef import GeorefOptions
from worker.pipeline.georef_map import MapGeorefOptions, georeference_map
from worker.pipeline.quality import survey_quality
from worker.pipeline.slam.result import SparseMap

EPSG = 32633
ORIGIN = np.array([500_000.0, 5_200_000.0, 300.0])
K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 180.0], [0.0, 0.0, 1.0]])
RTK = (0.02, 0.02, 0.04)


def _true_path(t: np.ndarray) -> np.ndarray:
    """A weaving flight at 20 m: 1 m/s east, +-5 m north."""
    return np.column_stack([t, 5.0 * np.sin(t / 6.0), np.full(t.size, 20.0)]) + ORIGIN


def _log(seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 120.0, 0.5)
    positions = _true_path(t) + rng.normal(0, 1.0, (t.size, 3)) * RTK
    return position_log(t, positions, EPSG)


def _map(segments: list[tuple[np.ndarray, bool]], seed: int = 1) -> SparseMap:
    """Keyframes of each (times, broken) segment in a local frame (the true path moved
    by an offset and a quarter turn, 2 cm of noise); a broken one is bent by metres."""
    rng = np.random.default_rng(seed)
    turn = rotation_world_from_camera(90.0, 0.0, 0.0)
    centres, seg, times, rots = [], [], [], []
    for k, (t, broken) in enumerate(segments):
        c = _true_path(t) - ORIGIN + rng.normal(0, 0.02, (t.size, 3))
        if broken:
            mid = t.mean()
            c[:, 1] *= 0.2
            c[:, 2] += 0.02 * (t - mid) ** 2
        centres.append(c @ turn.T + [40.0, -7.0, 3.0])
        seg.append(np.full(t.size, k, np.int32))
        times.append(t)
        world_from_cam = rotation_world_from_camera(np.full(t.size, 90.0), -90.0, np.zeros(t.size))
        rots.append(np.einsum("ij,njk->nik", turn, world_from_cam).transpose(0, 2, 1))
    c, r = np.concatenate(centres), np.concatenate(rots)
    tr = -np.einsum("nij,nj->ni", r, c)
    segment = np.concatenate(seg)
    return SparseMap.from_keyframes(
        K,
        (640, 360),
        t=np.concatenate(times),
        r=r,
        tr=tr,
        segment=segment,
        obs_kf=np.zeros(0),
        obs_point=np.zeros(0),
        obs_uv=np.zeros((0, 2)),
        point_id=np.arange(len(c)),
        point_xyz=c - [0.0, 0.0, 20.0],
        point_segment=segment,
    )


def _options(position_sigma=RTK) -> MapGeorefOptions:
    return MapGeorefOptions(refine=False, georef=GeorefOptions(position_sigma_m=position_sigma))


GOOD = np.arange(0.0, 50.0, 1.0)
LATER = np.arange(55.0, 115.0, 1.0)


def test_a_broken_segment_is_left_out_with_the_reason():
    sparse = _map([(GOOD, False), (LATER, True)])
    result = georeference_map(sparse, _log(), 0.0, _options())
    assert [s["segment"] for s in result.segments] == [0]
    assert result.segments[0]["within_stated_accuracy"] is True
    (reason,) = [w for w in result.warnings if "left out" in w]
    assert reason.startswith("segment 1 left out") and "10 times" in reason
    # Its keyframes and points are gone from the map: they cannot widen the DSM.
    assert set(sparse.kf_segment.tolist()) == {0} and set(sparse.point_segment.tolist()) == {0}


def test_a_broken_segment_alone_is_kept_and_called_unreliable():
    sparse = _map([(LATER, True)])
    result = georeference_map(sparse, _log(), 0.0, _options())
    assert result.segments[0]["within_stated_accuracy"] is False
    assert any("the result is unreliable" in w for w in result.warnings)
    # The survey's verdict fails on it, with the figures after the adjustment.
    quality = survey_quality({"georeference": result.to_dict()})
    (check,) = [c for c in quality["checks"] if c["name"] == "georeference_accuracy"]
    assert not quality["passed"] and not check["passed"]
    assert check["value"] > 10 * check["bound"] and check["bound"] == pytest.approx(0.135, abs=1e-3)


def test_a_segment_within_the_accuracy_says_so_and_without_one_nothing_is_checked():
    result = georeference_map(_map([(GOOD, False), (LATER, False)]), _log(), 0.0, _options())
    assert [s["within_stated_accuracy"] for s in result.segments] == [True, True]
    assert not result.warnings
    assert survey_quality({"georeference": result.to_dict()})["passed"]
    # A log stating no accuracy, none declared: nothing to check against, nothing left out.
    plain = georeference_map(_map([(GOOD, False), (LATER, True)]), _log(), 0.0, _options(None))
    assert len(plain.segments) == 2
    assert all("within_stated_accuracy" not in s for s in plain.segments)


def test_a_segment_missing_the_accuracy_by_a_little_is_reported_not_dropped():
    # 30 cm of extra noise on one segment: beyond 3 x 2.8 cm + 5 cm, within 10 times that.
    sparse = _map([(GOOD, False), (LATER, False)])
    rng = np.random.default_rng(5)
    later = sparse.kf_segment == 1
    c = sparse.kf_centres()
    c[later] += rng.normal(0, 0.3, (later.sum(), 3))
    sparse.kf_tr[later] = -np.einsum("nij,nj->ni", sparse.kf_r[later], c[later])
    result = georeference_map(sparse, _log(), 0.0, _options())
    assert [s["within_stated_accuracy"] for s in result.segments] == [True, False]
    assert any(w.startswith("segment 1: the georeference misses") for w in result.warnings)
