"""The pose-prior bundle adjustment of one straight flight line keeps the rotation the
attitude-aided fit gave it (worker/pipeline/georef_map.py `_refine_segment`).

Positions along a straight line say nothing of a roll about it, so COLMAP's alignment to
the priors may turn the segment about the line; the undo must see that turn in the
cameras' viewing directions, not in their centres alone (measured on a simulated 8-s
flight over the mounds: an 8.5 deg roll, the DSM tilted 15 cm per metre)."""

import numpy as np
import pytest
from pyproj import Transformer

from worker.pipeline.attitude import rotation_angle_deg, rotation_world_from_camera
from worker.pipeline.georef import GeorefOptions
from worker.pipeline.georef_map import MapGeorefOptions, georeference_map
from worker.pipeline.ingest.flight_log import build_flight_log
from worker.pipeline.slam.result import SparseMap

EPSG = 32633
ORIGIN = np.array([500_000.0, 5_200_000.0, 300.0])
K = np.array([[400.0, 0.0, 320.0], [0.0, 400.0, 180.0], [0.0, 0.0, 1.0]])
SIZE = (640, 360)
HEIGHT_M = 18.0
RTK = (0.02, 0.02, 0.04)


def _ground(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 0.3 * np.sin(x / 2.0) * np.cos(y / 3.0)


def _log(seed: int):
    """An RTK log of a flight north at 2 m/s, 18 m up, camera looking straight down."""
    rng = np.random.default_rng(seed)
    t = np.arange(-1.0, 13.0, 0.1)
    pos = np.column_stack([np.zeros(t.size), 2.0 * t, np.full(t.size, HEIGHT_M)]) + ORIGIN
    pos += rng.normal(0, 1.0, pos.shape) * RTK
    lon, lat = Transformer.from_crs(f"EPSG:{EPSG}", "EPSG:4326", always_xy=True).transform(
        pos[:, 0], pos[:, 1]
    )
    rows = [
        {
            "line": i + 2,
            "t": float(t[i]),
            "lat": lat[i],
            "lon": lon[i],
            "alt": pos[i, 2],
            "gimbal_yaw": 0.0,
            "gimbal_pitch": -90.0,
            "gimbal_roll": 0.0,
        }
        for i in range(t.size)
    ]
    return build_flight_log("flight.csv", "generic_csv", rows)


def _map(seed: int) -> tuple[SparseMap, np.ndarray]:
    """12 keyframes along the line in a local frame (turned, scaled, shifted), the ground
    points they see with half a pixel of noise; returns the map and the true points."""
    rng = np.random.default_rng(seed)
    t = np.arange(12.0)
    centres = np.column_stack([np.zeros(t.size), 2.0 * t, np.full(t.size, HEIGHT_M)])
    r_wc = rotation_world_from_camera(np.zeros(t.size), -90.0, np.zeros(t.size))
    gx, gy = np.meshgrid(np.arange(-12.0, 12.0, 0.8), np.arange(-8.0, 31.0, 0.8))
    truth = np.column_stack([gx.ravel(), gy.ravel(), _ground(gx.ravel(), gy.ravel())])
    r_cw = r_wc.transpose(0, 2, 1)
    obs_kf, obs_point, obs_uv = [], [], []
    for k in range(t.size):
        cam = (truth - centres[k]) @ r_cw[k].T
        uv = cam[:, :2] / cam[:, 2:] * [K[0, 0], K[1, 1]] + K[:2, 2]
        seen = np.flatnonzero((uv[:, 0] > 5) & (uv[:, 0] < 635) & (uv[:, 1] > 5) & (uv[:, 1] < 355))
        obs_kf.append(np.full(seen.size, k))
        obs_point.append(seen)
        obs_uv.append(uv[seen] + rng.normal(0, 0.5, (seen.size, 2)))
    # Only points seen three times or more, as the tracker keeps them.
    obs_kf, obs_point, obs_uv = map(np.concatenate, (obs_kf, obs_point, obs_uv))
    ids, counts = np.unique(obs_point, return_counts=True)
    kept = ids[counts >= 3]
    seen = np.isin(obs_point, kept)
    truth = truth[kept]
    obs_kf, obs_point, obs_uv = obs_kf[seen], np.searchsorted(kept, obs_point[seen]), obs_uv[seen]
    # The local frame: a quarter turn, half the scale, moved away.
    turn = rotation_world_from_camera(90.0, 0.0, 0.0)
    to_local = lambda x: 0.5 * x @ turn.T + [3.0, -4.0, 1.0]  # noqa: E731
    local_r_cw = np.einsum("nij,kj->nik", r_cw, turn)
    local_c = to_local(centres)
    sparse = SparseMap.from_keyframes(
        K,
        SIZE,
        t=t,
        r=local_r_cw,
        tr=-np.einsum("nij,nj->ni", local_r_cw, local_c),
        segment=np.zeros(t.size, np.int32),
        obs_kf=obs_kf,
        obs_point=obs_point,
        obs_uv=obs_uv,
        point_id=np.arange(len(truth)),
        point_xyz=to_local(truth) + rng.normal(0, 0.01, truth.shape),
        point_segment=np.zeros(len(truth), np.int32),
    )
    return sparse, truth


def test_a_straight_line_keeps_its_roll_through_the_adjustment():
    for seed in (1, 2, 3):
        sparse, truth = _map(seed)
        # Adjusted although straight (by default it is not, see the test below).
        options = MapGeorefOptions(
            refine=True, refine_min_straightness=0.0, georef=GeorefOptions(position_sigma_m=RTK)
        )
        result = georeference_map(sparse, _log(seed), 0.0, options)
        assert result.segments[0]["refinement"]["priors_used"] > 0
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


def test_a_straight_line_is_not_adjusted_by_default():
    sparse, _ = _map(1)
    before = sparse.point_xyz.copy()
    options = MapGeorefOptions(georef=GeorefOptions(position_sigma_m=RTK))
    result = georeference_map(sparse, _log(1), 0.0, options)
    assert result.segments[0]["refinement"]["skipped"].startswith("a near-straight track")
    # The points moved by the fitted similarity alone: distances between them kept,
    # times its scale of 2.
    pairs = np.random.default_rng(0).integers(0, len(before), (200, 2))
    ratio = np.linalg.norm(
        sparse.point_xyz[pairs[:, 0]] - sparse.point_xyz[pairs[:, 1]], axis=1
    ) / np.maximum(np.linalg.norm(before[pairs[:, 0]] - before[pairs[:, 1]], axis=1), 1e-9)
    assert np.median(ratio) == pytest.approx(2.0, rel=0.01)
    assert np.ptp(ratio[np.isfinite(ratio) & (ratio > 0)]) < 1e-6
