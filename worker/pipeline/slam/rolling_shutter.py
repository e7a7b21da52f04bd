"""Rolling shutter: image points and keyframe images moved to where a global shutter
would have put them.

A video camera reads its rows one after the other over the readout time; a frame's
time stamp is the middle of its readout, so row v is read
delta(v) = (v / (H - 1) - 1/2) * readout_s after it. Over that time the camera moves:
its centre at V (camera frame) and its attitude at Omega, so a point at X (camera
frame, depth Z) is seen displaced by delta * (Omega x X - V). Projected, a pixel moves by

    d = delta * ( f * P(Omega x (xn, yn, 1)) - f / Z * P(V) ),   P(a) = (a_x - xn a_z, a_y - yn a_z)

(xn, yn the normalised image point), to first order: over a readout of tens of
milliseconds a drone turns and moves little. Only V / Z enters, so the map's arbitrary
scale does not matter; Z is each map point's own depth where the SLAM knows it, else the
scene's median depth in the frame (the relief's share of the depth is then the
correction's relative error). Along the flight (rows along the track) the motion scales
the image along the track, so a stereo pair's depths are all off by about
f V readout / (H - 1): 14 cm at 4 m/s with a 30-ms readout and a 74-degree lens, of the
same sign on every line where the drone turns at the line's end, of opposite sign on a
line flown backwards.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class FrameMotion:
    """The camera's motion while a frame is read: angular velocity (rad/s) and the
    centre's velocity over the scene's depth (1/s), both in the camera frame."""

    omega: np.ndarray
    v_over_z: np.ndarray

    @classmethod
    def between(
        cls,
        r0: np.ndarray,
        t0: np.ndarray,
        r1: np.ndarray,
        t1: np.ndarray,
        seconds: float,
        depth: float,
    ) -> FrameMotion:
        """The motion from pose 0 (R_cw, t_cw) to pose 1 over `seconds`, the scene at
        `depth` in front of the camera (the map's units, as the poses')."""
        rotation, _ = cv2.Rodrigues(r1 @ r0.T)
        centre0, centre1 = -r0.T @ t0, -r1.T @ t1
        velocity = r1 @ (centre1 - centre0) / seconds
        return cls(omega=rotation.ravel() / seconds, v_over_z=velocity / depth)


def row_delay(rows: np.ndarray, height: int, readout_s: float) -> np.ndarray:
    """Seconds after the frame's time stamp at which each row was read."""
    return (np.asarray(rows, dtype=np.float64) / max(height - 1, 1) - 0.5) * readout_s


def _displacement(
    uv: np.ndarray,
    k: np.ndarray,
    delay: np.ndarray,
    motion: FrameMotion,
    depth_scale: np.ndarray | float = 1.0,
) -> np.ndarray:
    """Pixels by which the rolling shutter moved points that a global shutter would
    have seen at `uv` (first order, so also from where it saw them); `depth_scale`: the
    scene's depth over each point's (1: at the scene's depth)."""
    xn = (uv[:, 0] - k[0, 2]) / k[0, 0]
    yn = (uv[:, 1] - k[1, 2]) / k[1, 1]
    wx, wy, wz = motion.omega
    # Omega x (xn, yn, 1)
    ax = wy - wz * yn
    ay = wz * xn - wx
    az = wx * yn - wy * xn
    vx, vy, vz = (
        (motion.v_over_z[:, None] * depth_scale)
        if np.ndim(depth_scale)
        else (motion.v_over_z * depth_scale)
    )
    dx = k[0, 0] * ((ax - xn * az) - (vx - xn * vz))
    dy = k[1, 1] * ((ay - yn * az) - (vy - yn * vz))
    return np.column_stack([dx, dy]) * delay[:, None]


def to_global_shutter(
    uv: np.ndarray,
    k: np.ndarray,
    height: int,
    readout_s: float,
    motion: FrameMotion,
    depth_scale: np.ndarray | float = 1.0,
) -> np.ndarray:
    """Points (N, 2) seen through the rolling shutter, where a global shutter at the
    frame's time stamp would have seen them. `depth_scale` (N,): the scene's depth over
    each point's, where known (the translation moves near points more)."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    if readout_s <= 0 or not len(uv):
        return uv.copy()
    delay = row_delay(uv[:, 1], height, readout_s)
    return uv - _displacement(uv, k, delay, motion, depth_scale)


# The displacement is a smooth function of the pixel (a low-degree polynomial): it is
# computed on cells this many pixels wide and interpolated (0.02 px off at 640 x 360,
# a tenth of the time).
IMAGE_CELL_PX = 8


def global_shutter_image(
    image: np.ndarray, k: np.ndarray, readout_s: float, motion: FrameMotion
) -> np.ndarray:
    """The image a global shutter would have taken at the frame's time stamp: each
    output pixel is read from where the rolling shutter saw it (two fixed-point steps:
    the displacement depends on the row it was read in)."""
    if readout_s <= 0:
        return image
    h, w = image.shape[:2]
    cell = IMAGE_CELL_PX
    gh, gw = -(-h // cell), -(-w // cell)
    # Cell centres as cv2.resize places them, so that its linear interpolation gives
    # every pixel its own displacement.
    vv, uu = np.meshgrid(
        (np.arange(gh) + 0.5) * h / gh - 0.5, (np.arange(gw) + 0.5) * w / gw - 0.5, indexing="ij"
    )
    gs = np.column_stack([uu.ravel(), vv.ravel()])
    seen = gs.copy()
    for _ in range(2):
        seen = gs + _displacement(seen, k, row_delay(seen[:, 1], h, readout_s), motion)
    moved = (seen - gs).astype(np.float32)
    dx = cv2.resize(moved[:, 0].reshape(gh, gw), (w, h), interpolation=cv2.INTER_LINEAR)
    dy = cv2.resize(moved[:, 1].reshape(gh, gw), (w, h), interpolation=cv2.INTER_LINEAR)
    cols = np.arange(w, dtype=np.float32)[None, :]
    rows = np.arange(h, dtype=np.float32)[:, None]
    return cv2.remap(image, cols + dx, rows + dy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
