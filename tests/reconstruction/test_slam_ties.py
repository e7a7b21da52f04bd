"""Tie points between flight lines: a line flown the other way sees the ground turned by
180 degrees; the points one line observes are found in the other's keyframes where the
true cameras see them, though the map's poses are off by a few pixels."""

import cv2
import numpy as np

from tests.reconstruction.test_slam_parts import texture
from worker.pipeline.slam.result import SparseMap
from worker.pipeline.slam.ties import TieOptions, _ground_homography, tie_flight_lines

K = np.array([[300.0, 0.0, 159.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]])
SIZE = (320, 240)
ALTITUDE = 10.0
GROUND_M_PER_PX = 0.01  # of the texture


def pose_over(x: float, y: float, heading_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """R_cw, t_cw of a camera looking straight down from (x, y, ALTITUDE) onto z = 0."""
    h = np.radians(heading_deg)
    # Camera x to the right of the heading, y backwards, z down.
    right = np.array([np.cos(h), -np.sin(h), 0.0])
    forward = np.array([np.sin(h), np.cos(h), 0.0])
    r_wc = np.column_stack([right, -forward, [0.0, 0.0, -1.0]])
    r_cw = r_wc.T
    return r_cw, -r_cw @ np.array([x, y, ALTITUDE])


def render(ground: np.ndarray, pose: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The camera's image of the textured ground plane z = 0."""
    r, t = pose
    plane_to_image = K @ np.column_stack([r[:, 0], r[:, 1], t])
    texture_to_plane = np.diag([GROUND_M_PER_PX, -GROUND_M_PER_PX, 1.0])
    texture_to_plane[1, 2] = ground.shape[0] * GROUND_M_PER_PX  # texture row 0 is north
    return cv2.warpPerspective(ground, plane_to_image @ texture_to_plane, SIZE)


def project(pose, xyz):
    r, t = pose
    cam = xyz @ r.T + t
    return cam[:, :2] / cam[:, 2:] * [K[0, 0], K[1, 1]] + K[:2, 2]


def test_the_ground_homography_maps_pixels_of_one_camera_onto_the_other():
    a, b = pose_over(1.0, 2.0, 0.0), pose_over(2.5, 1.5, 180.0)
    rng = np.random.default_rng(0)
    ground = np.column_stack([rng.uniform(-1, 4, 20), rng.uniform(-1, 5, 20), np.zeros(20)])
    cam_a = ground @ a[0].T + a[1]
    normal = a[0] @ np.array([0.0, 0.0, 1.0])
    normal = -normal if normal[2] < 0 else normal
    h_ab = _ground_homography(K, a, b, normal, float(normal @ cam_a[0]))
    uv_a, uv_b = project(a, ground), project(b, ground)
    mapped = cv2.perspectiveTransform(uv_a.reshape(-1, 1, 2), h_ab).reshape(-1, 2)
    assert np.abs(mapped - uv_b).max() < 1e-6


def test_points_of_one_line_are_found_in_the_line_flown_back():
    ground = texture((900, 900), seed=4)  # 9 m x 9 m
    # Line 1 flies north at x = 3.5 m; line 2 flies south at x = 4.5 m, 30 s later.
    line1 = [pose_over(3.5, y, 0.0) for y in (3.0, 4.5, 6.0)]
    line2 = [pose_over(4.5, y, 180.0) for y in (6.0, 4.5, 3.0)]
    true_poses = line1 + line2
    images = {i: render(ground, p) for i, p in enumerate(true_poses)}
    # Ground points line 1 tracked, observed in its keyframes only.
    rng = np.random.default_rng(1)
    xyz = np.column_stack([rng.uniform(2.5, 5.5, 400), rng.uniform(2.5, 6.5, 400), np.zeros(400)])
    obs_kf, obs_pt, obs_uv = [], [], []
    for k in range(3):
        uv = project(true_poses[k], xyz)
        seen = (uv[:, 0] > 5) & (uv[:, 0] < SIZE[0] - 5) & (uv[:, 1] > 5) & (uv[:, 1] < SIZE[1] - 5)
        obs_kf.append(np.full(seen.sum(), k))
        obs_pt.append(np.flatnonzero(seen))
        obs_uv.append(uv[seen])
    # The map's poses of line 2 are off: 4 cm and half a degree (several pixels).
    tilt = cv2.Rodrigues(np.radians([0.5, -0.3, 0.4]))[0]
    map_poses = line1 + [(tilt @ r, tilt @ t + [0.04, -0.03, 0.0]) for r, t in line2]
    empty3 = np.empty((0, 3, 3))
    sparse = SparseMap(
        k=K, size=SIZE, kf_id=np.arange(6), kf_segment=np.zeros(6, np.int32),
        kf_t=np.array([0.0, 1.0, 2.0, 30.0, 31.0, 32.0]),
        kf_r=np.array([p[0] for p in map_poses]), kf_tr=np.array([p[1] for p in map_poses]),
        obs_kf=np.concatenate(obs_kf).astype(np.int32), obs_point=np.concatenate(obs_pt),
        obs_uv=np.concatenate(obs_uv).astype(np.float32), point_id=np.arange(400),
        point_xyz=xyz, point_segment=np.zeros(400, np.int32), fr_t=np.empty(0),
        fr_segment=np.empty(0, np.int32), fr_r=empty3, fr_tr=np.empty((0, 3)),
        fr_is_kf=np.empty(0, bool), fr_ref_kf=np.empty(0, np.int32), fr_rel_r=empty3,
        fr_rel_t=np.empty((0, 3)),
    )  # fmt: skip
    before = sparse.obs_kf.size
    report = tie_flight_lines(sparse, images.get, TieOptions(max_points=400))
    added = slice(before, None)
    assert report.observations == sparse.obs_kf.size - before > 300
    assert set(sparse.obs_kf[added].tolist()) <= {3, 4, 5}  # only line 2 gains points
    # Each new observation is where the true camera sees that point.
    for k in (3, 4, 5):
        mine = sparse.obs_kf[added] == k
        truth = project(true_poses[k], xyz[sparse.obs_point[added][mine]])
        error = np.linalg.norm(sparse.obs_uv[added][mine] - truth, axis=1)
        assert np.median(error) < 0.1 and np.percentile(error, 95) < 0.5
    # Nothing is added twice.
    pairs = set(zip(sparse.obs_kf.tolist(), sparse.obs_point.tolist(), strict=True))
    assert len(pairs) == sparse.obs_kf.size
    assert tie_flight_lines(sparse, images.get, TieOptions(max_points=400)).observations == 0
