"""Dense points from a keyframe pair: rectify, OpenCV semi-global matching, depth.

Rectification turns both views to a common orientation whose x axis runs from the first
camera to the second (so the second is always on the right, whatever the flight
direction) and whose optical axis is the two views' mean axis with its part along the
baseline removed. The rectified views keep the cameras' focal length and show the whole
of the first image, on a canvas that reaches left by the widest disparity searched (so
that its left edge too finds its match); OpenCV's `stereoRectify` instead crops both to a
rectangle valid in both (alpha 0) or shrinks them to fit one frame (alpha 1). That cost
the turns most of their overlap, and a camera climbing or descending as it flies (the
paper's 3-D path climbs at up to 47° at one-tenth scale) nearly all of it: its baseline is
tilted from the image plane by the climb's angle, the rectified views by as much, and
alpha 0 kept a sliver (0.02-0.09 of such keyframes' footprints measured), alpha 1 an empty
frame. The disparity search range comes from the depths, along the rectified axis, of the
sparse map points the first keyframe sees (on a 45° climb they spread from a fifth of
the keyframe's own depths to more). Depth is the closed form Z = f B / d (the notes:
2 ms where `triangulatePoints` took 0.8 s).

Points are returned in the first keyframe's camera frame, so that a later change of the
keyframe poses (pose-prior bundle adjustment) can move them along.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from worker.pipeline.binned import binned_mean, nmad


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
    # The rectified canvas (square pixels of the camera's horizontal focal length) spans
    # at most this many times the image's larger side in either direction (a steeply
    # tilted view stretches its far edge without bound), and the first image covers at
    # most this many times its own pixels on it (drawn smaller if need be).
    max_canvas_factor: float = 2.0
    max_canvas_pixels: float = 1.0


def _closest_ratio(ratios: dict[int, float], target: float, low: float, high: float) -> int | None:
    """The keyframe whose baseline ratio is closest to `target` (in log) within
    [low, high], or None."""
    inside = {i: r for i, r in ratios.items() if low <= r <= high}
    if not inside:
        return None
    return min(inside, key=lambda i: abs(np.log(inside[i] / target)))


def stereo_partners(ratios: dict[int, float], options: DensifyOptions) -> list[int]:
    """A keyframe's partners among candidates (index: baseline over the keyframe's
    median depth): the one nearest the target ratio, then, where `wide_baseline_ratio`
    is set, a clearly wider one; empty when none is within the ratios taken."""
    o = options
    first = _closest_ratio(
        ratios, o.target_baseline_ratio, o.min_baseline_ratio, o.max_baseline_ratio
    )
    if first is None:
        return []
    partners = [first]
    if o.wide_baseline_ratio is not None:
        # Only a pair clearly wider than the first is worth its matching.
        wide = _closest_ratio(
            ratios, o.wide_baseline_ratio, 1.5 * ratios[first], o.max_wide_baseline_ratio
        )
        if wide is not None:
            partners.append(wide)
    return partners


@dataclass
class _Rectification:
    """Both views turned to the common orientation `r_a` (a's camera frame to the
    rectified one) and drawn with intrinsics `k` on one canvas; `mask_a`/`mask_b`: the
    canvas pixels each image fills."""

    image_a: np.ndarray
    image_b: np.ndarray
    mask_a: np.ndarray
    mask_b: np.ndarray
    r_a: np.ndarray
    k: np.ndarray
    baseline: float


def _rectifying_rotation(r_ba: np.ndarray, centre_b: np.ndarray) -> np.ndarray | None:
    """Rows: x along the baseline (a to b), z the views' mean optical axis made
    perpendicular to it, y completing the frame; in a's camera frame. None when the
    baseline runs along the optical axis (nothing to rectify)."""
    x = centre_b / np.linalg.norm(centre_b)
    axis = np.array([0.0, 0.0, 1.0]) + r_ba[2]  # a's axis plus b's, in a's frame
    z = axis - (axis @ x) * x
    norm = np.linalg.norm(z)
    if norm < 0.1 * np.linalg.norm(axis):
        return None
    z /= norm
    return np.stack([x, np.cross(z, x), z])


def _warped_border(k: np.ndarray, r: np.ndarray, size: tuple[int, int]) -> np.ndarray | None:
    """Where an image's border lands under the pure rotation `r` (focal length kept,
    principal point at 0): (N, 2) in order around it, None if part of it turns behind
    the camera."""
    w, h = size
    t = np.linspace(0.0, 1.0, 33)
    back = t[::-1]
    # Around the image in order: top, right, bottom, left.
    u = np.concatenate([t * (w - 1), np.full_like(t, w - 1), back * (w - 1), np.zeros_like(t)])
    v = np.concatenate([np.zeros_like(t), t * (h - 1), np.full_like(t, h - 1), back * (h - 1)])
    rays = np.linalg.solve(k, np.stack([u, v, np.ones_like(u)])).T @ r.T
    if (rays[:, 2] <= 1e-3).any():
        return None
    return k[0, 0] * rays[:, :2] / rays[:, 2:]


def _rectify(
    img_a: np.ndarray,
    img_b: np.ndarray,
    k: np.ndarray,
    r_ba: np.ndarray,
    centre_b: np.ndarray,
    rect_depths: tuple[float, float],
    rotation: np.ndarray,
    options: DensifyOptions,
) -> tuple[_Rectification, float, float] | None:
    """The rectified pair and its disparity range (lowest, highest), or None."""
    h, w = img_a.shape[:2]
    f = float(k[0, 0])
    baseline = float(np.linalg.norm(centre_b))
    d_lo = f * baseline / rect_depths[1]
    d_hi = f * baseline / max(rect_depths[0], 1e-6)
    r_b = rotation @ r_ba.T  # b's camera frame to the rectified one
    border_a = _warped_border(k, rotation, (w, h))
    border_b = _warped_border(k, r_b, (w, h))
    if border_a is None or border_b is None or not np.isfinite(d_hi):
        return None
    # Columns: all of a, and room on the left for its left edge's match in b; rows: those
    # both images reach. Both bounded around a's centre.
    reach = options.max_canvas_factor * max(w, h)
    ray = rotation @ np.linalg.solve(k, np.array([k[0, 2], k[1, 2], 1.0]))
    cx, cy = f * ray[0] / ray[2], f * ray[1] / ray[2]
    left = max(border_a[:, 0].min() - d_hi, cx - reach / 2)
    right = min(border_a[:, 0].max(), cx + reach / 2)
    top = max(border_a[:, 1].min(), border_b[:, 1].min(), cy - reach / 2)
    bottom = min(border_a[:, 1].max(), border_b[:, 1].max(), cy + reach / 2)
    if right - left < 32 or bottom - top < 32:
        return None
    # A tilted view stretches the image (its far side several times): drawn smaller, its
    # matching costs the cube of the scale (pixels and disparities) and its points stay
    # about as many as the image's. The area a's image covers on the canvas (not the
    # canvas's: a view turned in its plane leaves empty corners that cost little).
    x, y = border_a[:, 0], border_a[:, 1]
    drawn = min(0.5 * abs(x @ np.roll(y, 1) - y @ np.roll(x, 1)), (right - left) * (bottom - top))
    scale = min(1.0, np.sqrt(options.max_canvas_pixels * w * h / drawn))
    f_rect = f * scale
    width = int(np.ceil((right - left) * scale)) + 1
    height = int(np.ceil((bottom - top) * scale)) + 1
    k_rect = np.array([[f_rect, 0.0, -left * scale], [0.0, f_rect, -top * scale], [0, 0, 1.0]])
    dist = np.zeros(5)
    ones = np.full((h, w), 255, np.uint8)
    out = []
    for image, r in ((img_a, rotation), (img_b, r_b)):
        maps = cv2.initUndistortRectifyMap(k, dist, r, k_rect, (width, height), cv2.CV_32FC1)
        out.append(cv2.remap(image, *maps, cv2.INTER_LINEAR))
        out.append(cv2.remap(ones, *maps, cv2.INTER_NEAREST) > 0)
    rect = _Rectification(out[0], out[2], out[1], out[3], rotation, k_rect, baseline)
    return rect, d_lo * scale, d_hi * scale


def densify_pair(
    img_a: np.ndarray,
    img_b: np.ndarray,
    k: np.ndarray,
    pose_a: tuple[np.ndarray, np.ndarray],
    pose_b: tuple[np.ndarray, np.ndarray],
    seen_points: np.ndarray,
    options: DensifyOptions | None = None,
    sample_phase: int = 0,
) -> np.ndarray:
    """Dense points (N, 3) float32 in keyframe a's camera frame (empty if it fails).

    `seen_points`: map points (N, 3) in a's camera frame, those a sees; their depths
    bound the search and the points returned.

    `sample_phase` shifts the every-`stride`-th pixel sampling (rows first, then
    columns): pairs along one flight line share their rectified rows' ground positions
    across the line, so with one phase for all their points fall on the same lines
    across it, and a DSM cell finer than the points' spacing stays empty between them
    whatever the overlap. Successive keyframes given successive phases fill it."""
    options = options or DensifyOptions()
    empty = np.empty((0, 3), np.float32)
    seen_points = np.asarray(seen_points, dtype=np.float64).reshape(-1, 3)
    seen_points = seen_points[seen_points[:, 2] > 0]
    if len(seen_points) < 3:
        return empty
    zmin, zmax = np.percentile(seen_points[:, 2], [2, 98])
    zmin, zmax = zmin / options.depth_margin, zmax * options.depth_margin
    r_a, t_a = pose_a
    r_b, t_b = pose_b
    r_ba = r_b @ r_a.T
    t_ba = t_b - r_ba @ t_a
    centre_b = -r_ba.T @ t_ba  # b's centre in a's frame
    rotation = _rectifying_rotation(r_ba, centre_b)
    if rotation is None:
        return empty
    # The points' depths along the rectified view's axis (see the module's docstring).
    rect_z = (seen_points @ rotation.T)[:, 2]
    rect_z = rect_z[rect_z > 0]
    if rect_z.size < 3:
        return empty
    rect_lo, rect_hi = np.percentile(rect_z, [2, 98])
    depths = (rect_lo / options.depth_margin, rect_hi * options.depth_margin)
    rectified = _rectify(img_a, img_b, k, r_ba, centre_b, depths, rotation, options)
    if rectified is None:
        return empty
    rect, d_lo, d_hi = rectified
    min_disp = max(0, int(np.floor(d_lo)))
    num = int(np.ceil((d_hi - min_disp + 1) / 16.0)) * 16
    num = int(np.clip(num, 16, options.max_disparities))
    width = rect.image_a.shape[1]
    # SGBM needs room for its search inside the image.
    num = min(num, (width // 2 - min_disp) // 16 * 16)
    if num < 16:
        return empty
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
    disparity = sgbm.compute(rect.image_a, rect.image_b).astype(np.float32) / 16.0
    # Only where both images' blocks lie wholly inside them (their edges on the canvas's
    # black would match anything).
    kernel = np.ones((bs, bs), np.uint8)
    inside_a = cv2.erode(rect.mask_a.view(np.uint8), kernel) > 0
    inside_b = cv2.erode(rect.mask_b.view(np.uint8), kernel) > 0
    s = max(1, options.stride)
    r0, c0 = sample_phase % s, (sample_phase // s) % s
    disp = disparity[r0::s, c0::s]
    vv, uu = np.mgrid[r0 : disparity.shape[0] : s, c0:width:s]
    valid = (disp > min_disp + 0.5) & inside_a[r0::s, c0::s]
    if not valid.any():
        return empty
    d = disp[valid].astype(np.float64)
    u = uu[valid].astype(np.float64)
    v = vv[valid].astype(np.float64)
    # The whole search must lie inside b: where b does not see a pixel's ground, SGBM
    # still picks the best of what it searched, a smaller disparity than the true one
    # (on forested hillslopes, points tens of metres below the ground).
    row = v.astype(np.int64)
    ok = np.ones(len(u), dtype=bool)
    for shift in (min_disp, min_disp + num - 1):
        column = u.astype(np.int64) - shift
        ok &= (column >= 0) & inside_b[row, np.clip(column, 0, width - 1)]
    d, u, v = d[ok], u[ok], v[ok]
    f = float(rect.k[0, 0])
    z = f * rect.baseline / d
    x = (u - rect.k[0, 2]) * z / f
    y = (v - rect.k[1, 2]) * z / f
    pts = np.column_stack([x, y, z]) @ rect.r_a  # R^T X: back to a's camera frame
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
