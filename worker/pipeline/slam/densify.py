"""Dense points from a keyframe pair: rectify, OpenCV semi-global matching, depth.

Along-track flight puts the baseline along the image's vertical axis, so both images are
first turned by 90 degrees when the baseline is more vertical than horizontal; after
`stereoRectify`, if the second camera sits to the left, both rectified images are
mirrored so that SGBM always sees the left image first. The disparity search range
comes from the depths of the sparse map points the first keyframe sees. Depth is the
closed form Z = f B / d (the notes: 2 ms where `triangulatePoints` took 0.8 s).

Points are returned in the first keyframe's camera frame, so that a later change of the
keyframe poses (pose-prior bundle adjustment) can move them along.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from worker.pipeline.binned import binned_mean, nmad
from worker.pipeline.slam.geometry import rotation_z90


@dataclass
class DensifyOptions:
    enabled: bool = True
    every: int = 1  # densify every n-th keyframe (2 halves the cost where they overlap)
    min_baseline_ratio: float = 0.04  # baseline / median depth of the pair
    target_baseline_ratio: float = 0.1
    max_baseline_ratio: float = 0.3
    # A second, wider pair per keyframe (SLAM): its heights, whose noise falls as the
    # baseline grows, replace the first pair's in the DSM cells where the two agree; the
    # first pair keeps every other cell (see `wide_pair_points`). None: one pair.
    wide_baseline_ratio: float | None = 0.2
    max_wide_baseline_ratio: float = 0.45
    block_size: int = 5
    stride: int = 2  # keep every n-th pixel in both directions
    uniqueness: int = 10
    speckle_window: int = 100
    speckle_range: int = 2
    depth_margin: float = 1.3  # search depths within [zmin / m, zmax * m] of the map
    max_disparities: int = 256
    # stereoRectify's alpha: 0 keeps only pixels valid in both rectified images (video
    # keyframes, turned little between them, lose almost nothing); up to 1 keeps every
    # source pixel, which photos turned by tens of degrees (a turn) need.
    rectify_alpha: float = 0.0


def _rotated_k(k: np.ndarray, height: int) -> np.ndarray:
    """Intrinsics after turning the image 90 degrees clockwise."""
    return np.array(
        [[k[1, 1], 0.0, height - 1 - k[1, 2]], [0.0, k[0, 0], k[0, 2]], [0.0, 0.0, 1.0]]
    )


def densify_pair(
    img_a: np.ndarray,
    img_b: np.ndarray,
    k: np.ndarray,
    pose_a: tuple[np.ndarray, np.ndarray],
    pose_b: tuple[np.ndarray, np.ndarray],
    depth_range: tuple[float, float],
    options: DensifyOptions | None = None,
) -> np.ndarray:
    """Dense points (N, 3) float32 in keyframe a's camera frame (empty if it fails)."""
    options = options or DensifyOptions()
    r_a, t_a = pose_a
    r_b, t_b = pose_b
    r_ba = r_b @ r_a.T
    t_ba = t_b - r_ba @ t_a
    baseline_a = -r_ba.T @ t_ba  # centre of b in a's frame
    h, w = img_a.shape[:2]
    turn = np.eye(3)
    k_used = k
    if abs(baseline_a[1]) > abs(baseline_a[0]):
        img_a = cv2.rotate(img_a, cv2.ROTATE_90_CLOCKWISE)
        img_b = cv2.rotate(img_b, cv2.ROTATE_90_CLOCKWISE)
        turn = rotation_z90(1)
        k_used = _rotated_k(k, h)
        h, w = w, h
        r_ba = turn @ r_ba @ turn.T
        t_ba = turn @ t_ba
    dist = np.zeros(5)
    r1, r2, p1, p2, _q, _, _ = cv2.stereoRectify(
        k_used,
        dist,
        k_used,
        dist,
        (w, h),
        r_ba,
        t_ba.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=options.rectify_alpha,
    )
    map1 = cv2.initUndistortRectifyMap(k_used, dist, r1, p1, (w, h), cv2.CV_32FC1)
    map2 = cv2.initUndistortRectifyMap(k_used, dist, r2, p2, (w, h), cv2.CV_32FC1)
    rect_a = cv2.remap(img_a, *map1, cv2.INTER_LINEAR)
    rect_b = cv2.remap(img_b, *map2, cv2.INTER_LINEAR)
    f = float(p1[0, 0])
    baseline = abs(float(p2[0, 3]) / f)
    mirrored = p2[0, 3] > 0
    if mirrored:
        rect_a, rect_b = rect_a[:, ::-1].copy(), rect_b[:, ::-1].copy()
    zmin, zmax = depth_range
    zmin, zmax = zmin / options.depth_margin, zmax * options.depth_margin
    d_lo = f * baseline / zmax
    d_hi = f * baseline / max(zmin, 1e-6)
    if not (np.isfinite(d_lo) and np.isfinite(d_hi)) or d_hi <= 0:
        return np.empty((0, 3), np.float32)
    min_disp = max(0, int(np.floor(d_lo)))
    num = int(np.ceil((d_hi - min_disp + 1) / 16.0)) * 16
    num = int(np.clip(num, 16, options.max_disparities))
    # SGBM needs room for its search inside the image.
    num = min(num, (w // 2 - min_disp) // 16 * 16)
    if num < 16:
        return np.empty((0, 3), np.float32)
    bs = options.block_size
    sgbm = cv2.StereoSGBM_create(
        minDisparity=min_disp,
        numDisparities=num,
        blockSize=bs,
        P1=8 * bs * bs,
        P2=32 * bs * bs,
        disp12MaxDiff=1,
        uniquenessRatio=options.uniqueness,
        speckleWindowSize=options.speckle_window,
        speckleRange=options.speckle_range,
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )
    disparity = sgbm.compute(rect_a, rect_b).astype(np.float32) / 16.0
    s = max(1, options.stride)
    disp = disparity[::s, ::s]
    vv, uu = np.mgrid[0:h:s, 0:w:s]
    valid = (disp > min_disp + 0.5) & (rect_a[::s, ::s] > 0 if rect_a.ndim == 2 else True)
    if not valid.any():
        return np.empty((0, 3), np.float32)
    d = disp[valid].astype(np.float64)
    u = uu[valid].astype(np.float64)
    v = vv[valid].astype(np.float64)
    if mirrored:
        u = (w - 1) - u
    z = f * baseline / d
    x = (u - p1[0, 2]) * z / f
    y = (v - p1[1, 2]) * z / p1[1, 1]
    pts_rect = np.column_stack([x, y, z])
    pts = pts_rect @ r1  # R1^T @ X: back to the (turned) camera frame of a
    pts = pts @ turn  # undo the turn: X_a = turn^T X_turned
    keep = (pts[:, 2] > zmin) & (pts[:, 2] < zmax)
    return pts[keep].astype(np.float32)


def wide_pair_points(
    points: np.ndarray, wide: np.ndarray, cell_m: float, k: float = 3.0
) -> np.ndarray:
    """Mask of the dense points a DSM of `cell_m` cells keeps: in every cell where the
    wide pairs' points (`wide`: SparseMap.dense_wide_pair) agree with the narrower
    pairs', only the wide pairs' points (a height's noise falls as the baseline grows);
    everywhere else only the narrower pairs' points.

    The wide pairs refine the narrow ones and never stand alone: on forested hillslopes
    their mismatches (occlusions grow with the baseline) were tens of metres off in the
    cells only they measured, and in cells where the two disagree the narrow pair was
    the closer to the truth two times in three. Agreement: the difference of the two
    means within `k` robust deviations (NMAD over every cell both measured) of its
    median, so the bound follows the survey's own noise (centimetres over bare ground,
    metres over a forest)."""
    if not wide.any() or wide.all():
        return np.ones(len(points), dtype=bool)
    # Cells on the DSM's own grid (whole multiples of the cell from the origin, as
    # dsm_export snaps it): on a grid shifted from it, a DSM cell would be judged by its
    # neighbour's points.
    col = np.floor(points[:, 0] / cell_m).astype(np.int64)
    row = np.floor(points[:, 1] / cell_m).astype(np.int64)
    col -= col.min()
    row -= row.min()
    rows = int(row.max()) + 1
    cell = col * rows + row
    del col, row
    n_cells = int(cell.max()) + 1
    if n_cells > 4 * cell.size:
        # Points strewn far apart (before the footprint filter): number the occupied
        # cells rather than allocate every cell of their extent.
        _, cell = np.unique(cell, return_inverse=True)
        cell = cell.ravel()
        n_cells = int(cell.max()) + 1
    z = points[:, 2]
    count_wide, mean_wide = binned_mean(z[wide], cell[wide], n_cells)
    count_narrow, mean_narrow = binned_mean(z[~wide], cell[~wide], n_cells)
    both = (count_wide > 0) & (count_narrow > 0)
    use_wide = np.zeros(n_cells, dtype=bool)
    if both.any():
        diff = mean_wide[both] - mean_narrow[both]
        use_wide[both] = np.abs(diff - np.median(diff)) <= k * nmad(diff)
    chosen = use_wide[cell]
    return np.where(wide, chosen, ~chosen)
