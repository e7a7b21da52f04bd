"""Rolling shutter: image rows exposed one after the other while the camera moves.

A video camera reads its sensor row by row, top to bottom, over the readout time
(`readout_s`, some 10-35 ms for consumer drone cameras): each row sees the scene from
the pose the camera had when that row was read. A frame's time stamp is the middle of
its readout, so the centre row sees the scene from the pose the trajectory gives for
that time, the top row from the pose `readout_s / 2` earlier, the bottom row from the
pose `readout_s / 2` later.

The renderer draws the frame once, from the mid-readout pose, over a field of view
grown by a margin (`margin_px`), with its depth per pixel; `warp_rows` then makes each
output row from that view: every output pixel's ray, from the pose of its row, is
followed to the surface the centre view's depth map describes (a few fixed-point steps:
the depth in the centre view where the ray point projects), and the colour is taken
where that surface point lies in the centre view. Exact for the visible surface; where
the row's pose sees behind an edge that the centre view hides (a tree crown's side,
a few pixels at most over a readout), the nearer surface's colour is stretched.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from worker.simulator.camera import CameraModel

# Fixed-point steps along each ray: over a readout the pose changes little, so the first
# depth guess is already close; three steps leave a residual well under a pixel on the
# simulated terrain.
RAY_STEPS = 3


def readout_times(t: np.ndarray, readout_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Times of the first and the last row of frames stamped `t` (mid-readout)."""
    half = 0.5 * float(readout_s)
    return np.asarray(t) - half, np.asarray(t) + half


def padded_camera(camera: CameraModel, margin_px: int) -> CameraModel:
    """`camera` with its image grown by `margin_px` on every side (same focal length)."""
    return replace(
        camera,
        name=f"{camera.name}+{margin_px}",
        width=camera.width + 2 * margin_px,
        height=camera.height + 2 * margin_px,
        cx=camera.cx + margin_px,
        cy=camera.cy + margin_px,
    )


def margin_for(
    camera: CameraModel,
    first: tuple[np.ndarray, np.ndarray],
    last: tuple[np.ndarray, np.ndarray],
    height_above_ground_m: np.ndarray,
) -> int:
    """Pixels by which a row's view may move from the centre view over the frames
    whose first-row and last-row poses (positions (n, 3), world-from-camera rotations
    (n, 3, 3)) are given, at their heights above the ground: half the translation over
    the height, and half the rotation, in pixels at the image's corner, plus 2."""
    (p0, r0), (p1, r1) = first, last
    moved = np.linalg.norm(np.asarray(p1) - np.asarray(p0), axis=1)
    height = np.maximum(np.asarray(height_above_ground_m, float), 1.0)
    turn = Rotation.from_matrix(np.einsum("nji,njk->nik", r0, r1)).magnitude()
    corner = camera.fx + 0.5 * np.hypot(camera.width, camera.height)
    shift = 0.5 * (camera.fx * moved / height + corner * turn)
    return int(np.ceil(float(shift.max(initial=0.0)))) + 2


def row_poses(
    first: tuple[np.ndarray, np.ndarray], last: tuple[np.ndarray, np.ndarray], rows: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per image row: the camera position (rows, 3), linear between the first and the
    last row's, and the world-from-camera rotation (rows, 3, 3), spherical-linear."""
    f = np.linspace(0.0, 1.0, rows) if rows > 1 else np.zeros(1)
    p0, p1 = np.asarray(first[0], float), np.asarray(last[0], float)
    positions = p0[None, :] + f[:, None] * (p1 - p0)[None, :]
    slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([first[1], last[1]])))
    return positions, slerp(f).as_matrix()


def warp_rows(
    image: np.ndarray,
    depth: np.ndarray,
    view: CameraModel,
    centre: tuple[np.ndarray, np.ndarray],
    rows: tuple[np.ndarray, np.ndarray],
    out: CameraModel,
    fill: tuple[float, float, float],
) -> np.ndarray:
    """The rolling-shutter image (out.height, out.width, channels) from the centre view:
    `image` and `depth` (along the optical axis, inf where the view sees sky) drawn with
    camera `view` from `centre` = (position, world-from-camera rotation); `rows` the
    pose of every output row (`row_poses`). `out` is the output camera (the view's
    camera without its margin; no lens distortion). Sky is `fill`."""
    h, w = out.height, out.width
    positions, rotations = rows
    c0, r0 = np.asarray(centre[0], float), np.asarray(centre[1], float)
    # In the centre camera's frame, the point at depth z along output pixel (u, v)'s ray
    # is a + z b, with a = R0^T (c_v - c0) per row and b = R0^T R_v (x_u, y_v, 1): as
    # the ray's x depends on the column alone and its y on the row alone, each component
    # of b is an outer sum, computed on (h, w) float32 arrays.
    a = (positions - c0) @ r0  # (h, 3)
    turn = np.einsum("ji,rjk->rik", r0, rotations)  # (h, 3, 3): R0^T R_v
    x = ((np.arange(w) - out.cx) / out.fx).astype(np.float32)
    y = ((np.arange(h) - out.cy) / out.fy).astype(np.float32)
    b = [
        (turn[:, i, 0, None] * x[None, :] + (turn[:, i, 1] * y + turn[:, i, 2])[:, None]).astype(
            np.float32
        )
        for i in range(3)
    ]
    ax, ay, az = (a[:, i, None].astype(np.float32) for i in range(3))
    big = np.float32(1e9)
    depth_finite = np.where(np.isfinite(depth), depth, big).astype(np.float32)
    bz = np.maximum(b[2], np.float32(1e-6))

    def where_seen(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel (col, row) in the centre view of the ray points at depth z."""
        yz = np.maximum(az + z * b[2], np.float32(1e-6))
        col = (ax + z * b[0]) / yz * np.float32(view.fx) + np.float32(view.cx)
        row = (ay + z * b[1]) / yz * np.float32(view.fy) + np.float32(view.cy)
        return col, row

    def depth_at(col: np.ndarray, row: np.ndarray) -> np.ndarray:
        return cv2.remap(depth_finite, col, row, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)

    # First guess: the centre view's depth at the same pixel (shifted by the margin).
    col = np.broadcast_to(np.arange(w, dtype=np.float32) + np.float32(view.cx - out.cx), (h, w))
    row = np.broadcast_to(
        (np.arange(h, dtype=np.float32) + np.float32(view.cy - out.cy))[:, None], (h, w)
    )
    z = depth_at(np.ascontiguousarray(col), np.ascontiguousarray(row))
    for _ in range(RAY_STEPS):
        d = depth_at(*where_seen(z))
        # The ray point whose depth in the centre view is the surface's there.
        z = (d - az) / bz
    col, row = where_seen(z)
    warped = cv2.remap(
        np.ascontiguousarray(image, dtype=np.float32),
        col,
        row,
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    warped[depth_at(col, row) >= big] = fill
    return warped
