"""The fast paths of the slam pipeline give what the plain ones gave: the in-place
outlier filter and compaction, the map file with its dense runs stored once, dense points
written into a given array, frames decoded ahead, and image motion measured at half size."""

import threading

import cv2
import numpy as np
import pytest

from worker.pipeline.dsm_export import grid_points
from worker.pipeline.frames import MotionMeter, prefetched
from worker.pipeline.pointcloud import compact_rows, grid_outliers
from worker.pipeline.slam.result import SparseMap


def _plain_grid_outliers(points, cell_m, k=3.0, min_points=5, min_spread_m=0.05):
    """The filter's definition, cell by cell (lower median, lower median deviation)."""
    ix = np.floor((points[:, 0] - points[:, 0].min()) / cell_m).astype(int)
    iy = np.floor((points[:, 1] - points[:, 1].min()) / cell_m).astype(int)
    keep = np.ones(len(points), bool)
    for cell in set(zip(ix.tolist(), iy.tolist(), strict=True)):
        members = np.flatnonzero((ix == cell[0]) & (iy == cell[1]))
        if len(members) < min_points:
            continue
        z = np.sort(points[members, 2])
        median = z[(len(z) - 1) // 2]
        dev = np.abs(points[members, 2] - median)
        mad = np.sort(dev)[(len(z) - 1) // 2]
        keep[members] = dev <= k * max(1.4826 * mad, min_spread_m)
    return keep


def test_grid_outliers_follow_the_definition():
    rng = np.random.default_rng(3)
    n = 6000
    pts = np.column_stack(
        [419000 + rng.uniform(0, 4, n), 3990000 + rng.uniform(0, 3, n), rng.normal(30, 0.1, n)]
    )
    pts[rng.choice(n, 40, replace=False), 2] += rng.uniform(0.5, 2.0, 40)
    expected = _plain_grid_outliers(pts, 0.5, k=3.5)
    assert (~expected).sum() >= 40
    np.testing.assert_array_equal(grid_outliers(pts, 0.5, k=3.5), expected)
    np.testing.assert_array_equal(grid_outliers(pts, 0.5, k=3.5, threads=2), expected)


def test_compact_rows_is_boolean_indexing_in_place():
    rng = np.random.default_rng(4)
    array = rng.normal(size=(1000, 3))
    keep = rng.random(900) < 0.7
    expected = array[:900][keep].copy()
    tail = array[900:].copy()
    n = compact_rows(array, keep, chunk=64)
    assert n == keep.sum()
    np.testing.assert_array_equal(array[:n], expected)
    np.testing.assert_array_equal(array[900:], tail)  # rows beyond `keep` are left alone
    assert compact_rows(array, np.zeros(0, bool)) == 0


def test_grid_points_of_points_outside_given_bounds():
    pts = np.array([[0.5, 0.5, 1.0], [1.5, 0.5, 3.0], [9.0, 9.0, 5.0], [np.nan, 0.5, 7.0]])
    grid = grid_points(pts, 1.0, bounds=(0.0, 0.0, 2.0, 1.0))
    np.testing.assert_array_equal(grid.values, [[1.0, 3.0]])
    np.testing.assert_array_equal(grid.counts, [[1, 1]])


def _map_with_dense_runs() -> SparseMap:
    n_kf = 4
    r = np.broadcast_to(np.eye(3), (n_kf, 3, 3)).copy()
    centres = np.column_stack([np.arange(n_kf, dtype=float), np.zeros(n_kf), np.full(n_kf, 10)])
    tr = -np.einsum("nij,nj->ni", r, centres)
    runs = [(0, 1, 1.0, 5), (1, 3, 2.0, 3), (1, 3, 2.5, 2), (2, 0, 2.0, 4)]
    rng = np.random.default_rng(5)
    return SparseMap(
        k=np.array([[400.0, 0, 320], [0, 400.0, 180], [0, 0, 1]]),
        size=(640, 360),
        kf_id=np.arange(n_kf, dtype=np.int32),
        kf_segment=np.zeros(n_kf, np.int32),
        kf_t=np.arange(n_kf, dtype=float),
        kf_r=r,
        kf_tr=tr,
        obs_kf=np.zeros(0, np.int32),
        obs_point=np.zeros(0, np.int64),
        obs_uv=np.zeros((0, 2), np.float32),
        point_id=np.array([1], np.int64),
        point_xyz=np.zeros((1, 3)),
        point_segment=np.zeros(1, np.int32),
        fr_t=np.arange(n_kf, dtype=float),
        fr_segment=np.zeros(n_kf, np.int32),
        fr_r=r.copy(),
        fr_tr=tr.copy(),
        fr_is_kf=np.ones(n_kf, bool),
        fr_ref_kf=np.arange(n_kf, dtype=np.int32),
        fr_rel_r=r.copy(),
        fr_rel_t=np.zeros((n_kf, 3)),
        dense_kf=np.concatenate([np.full(m, a, np.int32) for a, _, _, m in runs]),
        dense_partner=np.concatenate([np.full(m, b, np.int32) for _, b, _, m in runs]),
        dense_xyz=(rng.normal(0, 1, (14, 3)) + np.array([0.0, 0.0, 10.0])).astype(np.float32),
        dense_baseline=np.concatenate([np.full(m, base) for _, _, base, m in runs]),
    )


def test_map_file_keeps_dense_runs_once(tmp_path):
    m = _map_with_dense_runs()
    m.save(tmp_path / "map.npz")
    with np.load(tmp_path / "map.npz") as data:
        assert "dense_kf" not in data.files
        np.testing.assert_array_equal(data["dense_run_start"], [0, 5, 8, 10])
    again = SparseMap.load(tmp_path / "map.npz")
    for name in ("dense_kf", "dense_partner", "dense_baseline", "dense_xyz"):
        assert getattr(again, name).dtype == getattr(m, name).dtype
        np.testing.assert_array_equal(getattr(again, name), getattr(m, name))
    np.testing.assert_array_equal(again.dense_points(), m.dense_points())


def test_map_files_with_a_value_per_dense_point_still_load(tmp_path):
    m = _map_with_dense_runs()
    arrays = {n: getattr(m, n) for n in m.__dataclass_fields__ if n not in ("size", "stats")}
    np.savez(tmp_path / "old.npz", **arrays, meta=np.array('{"size": [640, 360], "stats": {}}'))
    old = SparseMap.load(tmp_path / "old.npz")
    np.testing.assert_array_equal(old.dense_baseline, m.dense_baseline)
    np.testing.assert_array_equal(old.dense_points(), m.dense_points())


def test_dense_points_into_a_given_array():
    m = _map_with_dense_runs()
    buffer = np.full((16, 3), np.nan)
    assert m.dense_points(out=buffer[:14]) is not None
    np.testing.assert_array_equal(buffer[:14], m.dense_points())
    assert np.isnan(buffer[14:]).all()
    with pytest.raises(ValueError):
        m.dense_points(out=np.empty((13, 3)))


def test_prefetched_keeps_the_order_and_raises_what_the_source_raises():
    threads = set()

    def source():
        for i in range(10):
            threads.add(threading.current_thread().name)
            yield i
        raise RuntimeError("damaged")

    out = []
    with pytest.raises(RuntimeError, match="damaged"):
        for item in prefetched(source(), depth=3):
            out.append(item)
    assert out == list(range(10))
    assert all(name.startswith("prefetch") for name in threads)
    assert list(prefetched(iter([]))) == []


def test_motion_at_half_size_is_the_motion_at_full_size():
    rng = np.random.default_rng(6)
    small = rng.random((60, 110)).astype(np.float32)
    base = cv2.resize(small, (1100, 600), interpolation=cv2.INTER_CUBIC)
    base = cv2.normalize(base, None, 20, 235, cv2.NORM_MINMAX).astype(np.uint8)
    speeds = {}
    for scale in (1, 2):
        meter = MotionMeter((360, 640), scale=scale)
        speeds[scale] = [meter.update(i / 30, base[100:460, 7 * i : 7 * i + 640]) for i in range(6)]
    assert np.isnan(speeds[1][0]) and np.isnan(speeds[2][0])
    np.testing.assert_allclose(speeds[1][1:], 7 * 30, rtol=0.02)
    np.testing.assert_allclose(speeds[2][1:], speeds[1][1:], rtol=0.02)
