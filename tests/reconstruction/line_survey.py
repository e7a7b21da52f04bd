"""A synthetic straight flight line north over gently rolling ground, as a reconstruction
(`SparseMap`, in a local frame: turned, scaled, shifted and optionally warped along the
line as monocular scale drift warps it) and as the RTK flight log that goes with it.

The aircraft flies at `speed(t) = speed + accel * t` m/s, `HEIGHT_M` up, camera looking
straight down; the log's clock is the video's (offset 0)."""

from __future__ import annotations

import numpy as np
from pyproj import Transformer

from worker.pipeline.attitude import rotation_world_from_camera
from worker.pipeline.ingest.flight_log import FlightLog, build_flight_log
from worker.pipeline.slam.result import SparseMap

EPSG = 32633
ORIGIN = np.array([500_000.0, 5_200_000.0, 300.0])
K = np.array([[400.0, 0.0, 320.0], [0.0, 400.0, 180.0], [0.0, 0.0, 1.0]])
SIZE = (640, 360)
HEIGHT_M = 18.0
RTK = (0.02, 0.02, 0.04)


def ground(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 0.3 * np.sin(x / 2.0) * np.cos(y / 3.0)


def north(t: np.ndarray, speed: float = 2.0, accel: float = 0.0) -> np.ndarray:
    return speed * t + 0.5 * accel * t**2


def line_log(
    seed: int,
    speed: float = 2.0,
    accel: float = 0.0,
    heading_bias_deg: float = 0.0,
    attitude: bool = True,
    end_s: float = 12.9,
    pitch_bias_deg: float = 0.0,
) -> FlightLog:
    """The RTK log of the flight (centimetre noise) from -1 s to `end_s`, gimbal pointing
    down; the compass heading off by `heading_bias_deg`, the gimbal's pitch by
    `pitch_bias_deg` (the camera truly looks straight down); without any attitude when
    not `attitude`."""
    rng = np.random.default_rng(seed)
    t = np.round(np.arange(-1.0, end_s + 0.05, 0.1), 6)
    pos = np.column_stack([np.zeros(t.size), north(t, speed, accel), np.full(t.size, HEIGHT_M)])
    pos = pos + ORIGIN + rng.normal(0, 1.0, pos.shape) * RTK
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
            "gimbal_yaw": heading_bias_deg,
            "gimbal_pitch": -90.0 + pitch_bias_deg,
            "gimbal_roll": 0.0,
        }
        for i in range(t.size)
    ]
    if not attitude:
        rows = [{k: v for k, v in row.items() if not k.startswith("gimbal")} for row in rows]
    return build_flight_log("flight.csv", "generic_csv", rows)


def line_map(
    seed: int, speed: float = 2.0, accel: float = 0.0, warp_per_m: float = 0.0
) -> tuple[SparseMap, np.ndarray, np.ndarray]:
    """12 keyframes along the line in a local frame (turned, half the scale, shifted;
    stretched along the line by `warp_per_m` times the distance flown, as scale drift
    stretches a map), the ground points they see with half a pixel of noise. Returns the
    map, the true points and the true camera centres (both relative to ORIGIN)."""
    rng = np.random.default_rng(seed)
    t = np.arange(12.0)
    centres = np.column_stack([np.zeros(t.size), north(t, speed, accel), np.full(t.size, HEIGHT_M)])
    r_wc = rotation_world_from_camera(np.zeros(t.size), -90.0, np.zeros(t.size))
    reach = float(centres[-1, 1])
    gx, gy = np.meshgrid(np.arange(-12.0, 12.0, 0.8), np.arange(-8.0, reach + 8.0, 0.8))
    truth = np.column_stack([gx.ravel(), gy.ravel(), ground(gx.ravel(), gy.ravel())])
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

    def warp(x: np.ndarray) -> np.ndarray:
        out = x.copy()
        out[:, 1] = x[:, 1] * (1.0 + warp_per_m * x[:, 1])
        return out

    # The local frame: a quarter turn, half the scale, moved away.
    turn = rotation_world_from_camera(90.0, 0.0, 0.0)
    to_local = lambda x: 0.5 * warp(x) @ turn.T + [3.0, -4.0, 1.0]  # noqa: E731
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
    return sparse, truth, centres


def cut_map(sparse: SparseMap, first: int) -> np.ndarray:
    """Cut the map (in place) as a loss of tracking at keyframe `first` cuts it: that
    keyframe and the later ones a second segment, with points of its own (each point's
    observations there become a new point, kept where seen three times or more, as the
    tracker keeps them). Returns, per point of the new map, its index in the old one."""
    n = sparse.point_id.size
    later = sparse.obs_kf >= first
    ids = np.where(later, sparse.obs_point + n, sparse.obs_point)
    unique, counts = np.unique(ids, return_counts=True)
    kept = unique[counts >= 3]
    seen = np.isin(ids, kept)
    sparse.kf_segment = (np.arange(sparse.kf_t.size) >= first).astype(np.int32)
    sparse.fr_segment = sparse.kf_segment.copy()
    sparse.obs_kf, sparse.obs_uv = sparse.obs_kf[seen], sparse.obs_uv[seen]
    sparse.obs_point = ids[seen]
    source = kept % n
    sparse.point_id = kept
    sparse.point_xyz = sparse.point_xyz[source]
    sparse.point_segment = (kept >= n).astype(np.int32)
    return source
