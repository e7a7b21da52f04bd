"""A rolling shutter reads rows one after the other while the drone moves: along the
track that scales the image, and every stereo depth comes out off by about
f V readout / (H - 1). Given the camera's readout time, the SLAM method moves its tracked
points and keyframe images to a global shutter's view (a flight through it:
test_slam_parts.py)."""

import cv2
import numpy as np

from worker.pipeline.slam.rolling_shutter import (
    FrameMotion,
    global_shutter_image,
    row_delay,
    to_global_shutter,
)

K = np.array([[400.0, 0.0, 319.5], [0.0, 400.0, 179.5], [0.0, 0.0, 1.0]])
HEIGHT = 360
READOUT = 0.03


def _pose(t: float, velocity: np.ndarray, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R_cw, t_cw at time t of a camera looking down its z axis from the origin, its
    centre moving at `velocity` (world) and turning at `omega` (rad/s, camera frame)."""
    r = cv2.Rodrigues(omega * t)[0]
    centre = velocity * t
    return r, -r @ centre


def _rolling_projection(points: np.ndarray, velocity: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Where a rolling shutter (frame stamped at t = 0, mid readout) sees the points: the
    row each is read in and the pose at that row's time agree (fixed point)."""
    uv = np.zeros((len(points), 2))
    delay = np.zeros(len(points))
    for _ in range(20):
        for i, (x, d) in enumerate(zip(points, delay, strict=True)):
            r, t = _pose(d, velocity, omega)
            p = K @ (r @ x + t)
            uv[i] = p[:2] / p[2]
        delay = row_delay(uv[:, 1], HEIGHT, READOUT)
    return uv


def test_points_seen_through_a_rolling_shutter_go_back_to_a_global_shutters_view():
    rng = np.random.default_rng(3)
    depth = rng.uniform(45.0, 55.0, 300)
    pixels = rng.uniform([0, 0], [639, 359], (300, 2))
    points = (
        np.column_stack(
            [(pixels[:, 0] - K[0, 2]) / K[0, 0], (pixels[:, 1] - K[1, 2]) / K[1, 1], np.ones(300)]
        )
        * depth[:, None]
    )
    velocity = np.array([3.0, 12.0, 0.5])  # m/s, mostly along the image's columns
    omega = np.array([0.05, -0.03, 0.2])
    seen = _rolling_projection(points, velocity, omega)
    # The motion as the SLAM measures it: two poses a tenth of a second apart, the
    # scene's median depth.
    r0, t0 = _pose(-0.05, velocity, omega)
    r1, t1 = _pose(0.05, velocity, omega)
    motion = FrameMotion.between(r0, t0, r1, t1, 0.1, float(np.median(depth)))
    corrected = to_global_shutter(seen, K, HEIGHT, READOUT, motion)
    before = np.linalg.norm(seen - pixels, axis=1)
    after = np.linalg.norm(corrected - pixels, axis=1)
    assert np.percentile(before, 90) > 1.5  # rows far from the centre moved pixels
    assert np.percentile(after, 90) < 0.12  # the depth's spread (10 %) is what is left
    assert after.max() < 0.25
    # No readout: the points are left as they are.
    np.testing.assert_array_equal(to_global_shutter(seen, K, HEIGHT, 0.0, motion), seen)


def test_a_global_shutter_image_puts_texture_where_the_corrected_points_are():
    """The image moved to a global shutter's view and the points moved the same way
    agree: a bright dot seen through the rolling shutter lands where its corrected
    position says."""
    motion = FrameMotion(omega=np.array([0.0, 0.0, 0.3]), v_over_z=np.array([0.0, 1.0, 0.0]))
    image = np.zeros((HEIGHT, 640), np.uint8)
    seen = np.array([[100.0, 40.0], [500.0, 320.0], [320.0, 180.0]])
    for u, v in seen:
        cv2.circle(image, (int(u), int(v)), 3, 255, -1)
    moved = global_shutter_image(image, K, READOUT, motion)
    expected = to_global_shutter(seen, K, HEIGHT, READOUT, motion)
    assert np.abs(expected - seen).max() > 3.0
    for u, v in expected:
        window = moved[int(v) - 6 : int(v) + 7, int(u) - 6 : int(u) + 7].astype(float)
        rows, cols = np.mgrid[-6:7, -6:7]
        centre = (np.sum(cols * window) / window.sum(), np.sum(rows * window) / window.sum())
        assert np.hypot(u - int(u) - centre[0], v - int(v) - centre[1]) < 0.6


def test_a_maps_readout_and_keyframe_motion_are_saved_and_read_back(tmp_path):
    """The ties read keyframe images again after the SLAM: the map file keeps what
    moves them to a global shutter's view, and a keyframe without a known motion (or a
    map without a readout) gives none."""
    from tests.reconstruction.test_speed_paths import _map_with_dense_runs
    from worker.pipeline.slam.result import SparseMap

    m = _map_with_dense_runs()
    assert m.keyframe_motion(0) is None  # no readout: a global shutter
    m.readout_s = READOUT
    m.kf_motion = np.zeros((len(m.kf_t), 6))
    m.kf_motion[1] = [0.01, 0.0, 0.2, 0.0, 0.5, 0.0]
    m.save(tmp_path / "map.npz")
    back = SparseMap.load(tmp_path / "map.npz")
    assert back.readout_s == READOUT
    assert back.keyframe_motion(0) is None  # zeros: none known
    motion = back.keyframe_motion(1)
    np.testing.assert_array_equal(motion.omega, [0.01, 0.0, 0.2])
    np.testing.assert_array_equal(motion.v_over_z, [0.0, 0.5, 0.0])
