"""Where each camera of a map looks on the ground, and how many cameras see each cell.

A camera's footprint is its image border cast onto a ground plane. Where the camera
sees (`views`, the overlap figures) the plane is fitted to the sparse points it observes,
tilted with the slope: on a hillside a horizontal plane puts the uphill edge of the
footprint too far out and the downhill edge too near, and the overlap area it gives is
then larger than what the photos share (measured: a hillslope photo set's coverage read
0.62 with level planes). The plane is raised to the upper part of the heights the camera
sees (`VIEW_SURFACE_QUANTILE`): the image border meets tree crowns and mound tops before
the ground between them. How far it can see at most (`reach`, the DSM's extent) uses a
horizontal plane at a low quantile of those heights, since lower ground lies farther out
along the edge rays. Heights are kept within the range of the whole map's points so that
a camera of a bad segment, whose points may be anywhere, still gets a footprint near the
others; that range (`height_range`) is robust to a few per cent of points triangulated
kilometres away, as SfM leaves them; a camera without enough observed points uses the
heights of the whole map and a level plane. Rays that meet the plane far away or not at
all (an oblique camera's upper rows) are cut at `max_range_factor` times the camera's
height above the plane, so a camera looking at the horizon has a bounded footprint.

The per-cell view count is rasterised camera by camera into one int16 raster, each
footprint only over its own window: memory is one raster whatever the number of
cameras.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import rasterio.features
import shapely
from rasterio.transform import Affine
from rasterio.windows import Window
from rasterio.windows import transform as window_transform
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry

from worker.pipeline.slam.result import SparseMap

# Samples along each image edge: enough to follow a footprint cut at the range limit.
EDGE_SAMPLES = 8
# A camera needs this many observed points for its own ground height.
MIN_OBSERVED_POINTS = 20
# Below this height above its ground (metres) a camera's footprint is meaningless.
MIN_CAMERA_HEIGHT_M = 0.5
# A camera's view for the overlap figures: its image border meets the first surface it
# crosses, the upper part of what the camera sees (tree crowns, mound tops) rather than
# its middle, so the view is cast on its fitted plane raised to this quantile of the
# heights above it. Chosen by how well the two-view overlap matches the truth's (the
# truth DSM seen from the cameras moved onto the truth, simulated photo sets): on the
# forested hillslope (6 sets) intersection over union 0.93 (median plane: 0.91), area
# 2.3-3.9 % above the truth's instead of 7.6-9.1 %; on the mounds (3 sets) 0.992-0.994
# (median plane 0.995-0.996), area 0.4-0.7 % below. Of 0.75, 0.8, 0.9 and 0.95, tried
# on the first set of each scene, 0.9 had the best mean of the two; 0.98 did worse on the
# hillslope.
VIEW_SURFACE_QUANTILE = 0.9
# Points beyond these heights are outliers for every camera's ground: the map's
# quartiles grown by this many inter-quartile ranges (Tukey's far-out fences), and by at
# least the cameras' median height above the map's median point times this share: a
# flat field's quartiles are centimetres apart, and a few trees on it (under a quarter
# of the points) stand well beyond them, but not above the cameras that look down on them.
HEIGHT_FENCE_IQR = 3.0
HEIGHT_FENCE_MIN_SHARE = 1.0


@dataclass(frozen=True)
class HeightRange:
    """Where the ground the cameras see can be: `fences`, outside which a point is an
    outlier (left out of every camera's ground), and `clip`, the range a camera's ground
    height is kept within (the map's quantiles, within the fences)."""

    fences: tuple[float, float]
    clip: tuple[float, float]

    def inside(self, z: np.ndarray) -> np.ndarray:
        return np.isfinite(z) & (z >= self.fences[0]) & (z <= self.fences[1])


def height_range(
    sparse: SparseMap, clip_quantiles: tuple[float, float] = (0.02, 0.98)
) -> HeightRange | None:
    """The map's `HeightRange` (None without heights). The quantiles alone held where
    few points are wrong (a slam map's stray matches); SfM keeps points triangulated
    along nearly parallel rays, kilometres away, and where they are more than a few per
    cent they carry the quantiles with them, and make up most of what some cameras see
    (a 12-s sfm survey over the mounds: 9.5 % of its points, its 2 % and 98 % quantiles
    at -1441 m and +942 m around ground at 34 m; a camera's low ground 1.5 km below it,
    its footprint 6 x 11 km, and the DSM 2.9 x 2.8 km instead of some 30 x 45 m)."""
    z = sparse.point_xyz[:, 2] if sparse.point_xyz.size else np.empty(0)
    z = z[np.isfinite(z)]
    if z.size == 0:
        return None
    q1, median, q3 = np.quantile(z, (0.25, 0.5, 0.75))
    centres_z = sparse.kf_centres()[:, 2] if sparse.kf_t.size else np.empty(0)
    centres_z = centres_z[np.isfinite(centres_z)]
    above = float(np.median(centres_z) - median) if centres_z.size else 0.0
    fence = max(HEIGHT_FENCE_IQR * float(q3 - q1), HEIGHT_FENCE_MIN_SHARE * abs(above))
    fences = (float(q1) - fence, float(q3) + fence)
    lo, hi = np.quantile(z, clip_quantiles)
    return HeightRange(fences=fences, clip=(max(float(lo), fences[0]), min(float(hi), fences[1])))


def ground_heights(
    sparse: SparseMap, quantile: float = 0.5, clip_quantiles: tuple[float, float] = (0.02, 0.98)
) -> np.ndarray:
    """Per keyframe: the `quantile` of the heights of the sparse points it observes
    within the map's fences, kept within its clip range (`height_range`); the whole
    map's `quantile` where a keyframe observes too few points. NaN without points."""
    n = sparse.kf_t.size
    heights = height_range(sparse, clip_quantiles)
    if heights is None:
        return np.full(n, np.nan)
    z_all = sparse.point_xyz[:, 2]
    overall = float(np.quantile(z_all[heights.inside(z_all)], quantile))
    out = np.full(n, overall)
    if sparse.obs_kf.size:
        index = np.searchsorted(sparse.point_id, sparse.obs_point)
        index = np.clip(index, 0, max(sparse.point_id.size - 1, 0))
        known = sparse.point_id[index] == sparse.obs_point
        kf = sparse.obs_kf[known]
        z = sparse.point_xyz[index[known], 2]
        order = np.argsort(kf, kind="stable")
        kf, z = kf[order], z[order]
        starts = np.searchsorted(kf, np.arange(n + 1))
        for i in range(n):
            zi = z[starts[i] : starts[i + 1]]
            zi = zi[heights.inside(zi)]
            if zi.size >= MIN_OBSERVED_POINTS:
                out[i] = np.quantile(zi, quantile)
    return np.clip(out, *heights.clip)


def _border_pixels(width: int, height: int) -> np.ndarray:
    """Points along the image border, clockwise from the top-left corner, (M, 2)."""
    s = np.linspace(0.0, 1.0, EDGE_SAMPLES, endpoint=False)
    w, h = float(width), float(height)
    top = np.column_stack([s * w, np.zeros_like(s)])
    right = np.column_stack([np.full_like(s, w), s * h])
    bottom = np.column_stack([w - s * w, np.full_like(s, h)])
    left = np.column_stack([np.zeros_like(s), h - s * h])
    return np.concatenate([top, right, bottom, left])


def camera_footprint(
    k: np.ndarray,
    size: tuple[int, int],
    r_cw: np.ndarray,
    t_cw: np.ndarray,
    ground_z: float,
    max_range_factor: float = 4.0,
    slope: tuple[float, float] = (0.0, 0.0),
) -> Polygon | None:
    """The ground polygon one camera (intrinsics `k`, image `size` = width, height,
    world-to-camera `r_cw`, `t_cw`) sees on the plane through z = `ground_z` below the
    camera rising by `slope` (dz/dx, dz/dy); None when the camera is not above the plane
    or sees no ground."""
    centre = -r_cw.T @ t_cw
    height = float(centre[2] - ground_z)
    if not np.isfinite(height) or height < MIN_CAMERA_HEIGHT_M:
        return None
    uv = _border_pixels(*size)
    rays_cam = np.linalg.solve(k, np.column_stack([uv, np.ones(len(uv))]).T)
    rays = (r_cw.T @ rays_cam).T  # world directions
    reach = max_range_factor * height
    # How fast each ray closes on the plane (negative: towards it).
    closing = rays[:, 2] - slope[0] * rays[:, 0] - slope[1] * rays[:, 1]
    down = closing < 0
    # Distance along each ray to the plane; rays that never meet it go to the range limit.
    t = np.zeros(len(rays))
    t[down] = -height / closing[down]
    ground = centre[None, :] + t[:, None] * rays
    horizontal = np.hypot(rays[:, 0], rays[:, 1])
    far = ~down | (np.hypot(ground[:, 0] - centre[0], ground[:, 1] - centre[1]) > reach)
    if far.all():
        return None
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(horizontal > 0, reach / horizontal, 0.0)
    ground[far, :2] = centre[None, :2] + scale[far, None] * rays[far, :2]
    polygon = shapely.make_valid(Polygon(ground[:, :2]))
    if polygon.is_empty or polygon.area <= 0:
        return None
    if not isinstance(polygon, Polygon):
        polygon = shapely.convex_hull(polygon)
    return polygon


def ground_planes(
    sparse: SparseMap,
    clip_quantiles: tuple[float, float] = (0.02, 0.98),
    max_slope: float = 2.0,
    surface_quantile: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Per keyframe: the ground plane through the sparse points it observes, as (height
    below the camera (K,), slope dz/dx, dz/dy (K, 2)), fitted by least squares and once
    more without the points beyond 3 robust sigmas (trees, a wrong match), then, with
    `surface_quantile`, raised to that quantile of the points' heights above it. Heights
    are kept within the `clip_quantiles` of the map's points, slopes within `max_slope`;
    a keyframe observing too few points gets the map's median height and a level plane.
    Points beyond the map's fences are left out, as outliers (`height_range`)."""
    heights = ground_heights(sparse, 0.5, clip_quantiles)
    slopes = np.zeros((sparse.kf_t.size, 2))
    if not sparse.obs_kf.size or not np.isfinite(heights).any():
        return heights, slopes
    heights_range = height_range(sparse, clip_quantiles)
    if heights_range is None:
        return heights, slopes
    lo, hi = heights_range.clip
    centres = sparse.kf_centres()
    index = np.clip(np.searchsorted(sparse.point_id, sparse.obs_point), 0, sparse.point_id.size - 1)
    known = sparse.point_id[index] == sparse.obs_point
    kf, xyz = sparse.obs_kf[known], sparse.point_xyz[index[known]]
    order = np.argsort(kf, kind="stable")
    kf, xyz = kf[order], xyz[order]
    starts = np.searchsorted(kf, np.arange(sparse.kf_t.size + 1))
    for i in range(sparse.kf_t.size):
        pts = xyz[starts[i] : starts[i + 1]]
        pts = pts[np.isfinite(pts).all(axis=1) & heights_range.inside(pts[:, 2])]
        if len(pts) < MIN_OBSERVED_POINTS:
            continue
        a = np.column_stack([np.ones(len(pts)), pts[:, :2] - centres[i, :2]])
        keep = np.ones(len(pts), bool)
        for _ in range(2):
            coef = np.linalg.lstsq(a[keep], pts[keep, 2], rcond=None)[0]
            residual = pts[:, 2] - a @ coef
            mad = 1.4826 * np.median(np.abs(residual[keep] - np.median(residual[keep])))
            keep = np.abs(residual) <= max(3.0 * mad, 1e-6)
            if keep.sum() < MIN_OBSERVED_POINTS:
                break
        lift = 0.0 if surface_quantile is None else float(np.quantile(residual, surface_quantile))
        heights[i] = float(np.clip(coef[0] + lift, lo, hi))
        slopes[i] = np.clip(coef[1:], -max_slope, max_slope)
    return heights, slopes


def camera_footprints(
    sparse: SparseMap,
    ground_quantile: float | None = None,
    max_range_factor: float = 4.0,
    surface_quantile: float | None = None,
) -> list[Polygon | None]:
    """Per keyframe of `sparse` (in a metric, z-up frame): its footprint on the ground
    plane fitted to what it sees (raised to `surface_quantile` of the heights above it,
    when given), or with `ground_quantile` on the level ground at that quantile of the
    heights it sees (see the module doc); None where it has none."""
    if ground_quantile is None:
        heights, slopes = ground_planes(sparse, surface_quantile=surface_quantile)
    else:
        heights = ground_heights(sparse, ground_quantile)
        slopes = np.zeros((sparse.kf_t.size, 2))
    return [
        camera_footprint(
            sparse.k,
            sparse.size,
            sparse.kf_r[i],
            sparse.kf_tr[i],
            heights[i],
            max_range_factor,
            (float(slopes[i, 0]), float(slopes[i, 1])),
        )
        if np.isfinite(heights[i])
        else None
        for i in range(sparse.kf_t.size)
    ]


def _window(geometry: BaseGeometry, transform: Affine, shape: tuple[int, int]) -> Window | None:
    """The raster window that holds `geometry`, cut to the raster; None if outside."""
    rows, cols = shape
    left, bottom, right, top = geometry.bounds
    col_lo, row_lo = ~transform * (left, top)
    col_hi, row_hi = ~transform * (right, bottom)
    col0 = max(int(np.floor(min(col_lo, col_hi))), 0)
    row0 = max(int(np.floor(min(row_lo, row_hi))), 0)
    col1 = min(int(np.ceil(max(col_lo, col_hi))) + 1, cols)
    row1 = min(int(np.ceil(max(row_lo, row_hi))) + 1, rows)
    if col1 <= col0 or row1 <= row0:
        return None
    return Window(col0, row0, col1 - col0, row1 - row0)


def rasterise(
    geometry: BaseGeometry, transform: Affine, shape: tuple[int, int]
) -> tuple[Window, np.ndarray] | None:
    """Cells whose centre lies in `geometry`, over the window that holds it: (window,
    uint8 mask of the window's shape, 1 inside); None when it misses the raster."""
    window = _window(geometry, transform, shape)
    if window is None:
        return None
    local = window_transform(window, transform)
    mask = rasterio.features.rasterize(
        [(geometry, 1)],
        out_shape=(int(window.height), int(window.width)),
        transform=local,
        fill=0,
        dtype="uint8",
    )
    return window, mask


def view_count(
    footprints: Sequence[BaseGeometry | None], transform: Affine, shape: tuple[int, int]
) -> np.ndarray:
    """Per cell of the raster (`transform`, `shape` = rows, cols): how many footprints
    hold its centre (int16: a survey has far fewer than 32767 cameras over one cell)."""
    count = np.zeros(shape, dtype=np.int16)
    for polygon in footprints:
        if polygon is None or polygon.is_empty:
            continue
        cut = rasterise(polygon, transform, shape)
        if cut is None:
            continue
        window, mask = cut
        rows = slice(int(window.row_off), int(window.row_off + window.height))
        cols = slice(int(window.col_off), int(window.col_off + window.width))
        count[rows, cols] += mask
    return count


def footprint_union(
    footprints: Sequence[BaseGeometry | None], margin_m: float = 0.0
) -> BaseGeometry:
    """The union of the footprints, grown by `margin_m` (empty if there are none)."""
    parts = [p for p in footprints if p is not None and not p.is_empty]
    if not parts:
        return Polygon()
    union = shapely.union_all(parts)
    return union.buffer(margin_m) if margin_m > 0 else union


def snapped_bounds(
    geometry: BaseGeometry, resolution_m: float
) -> tuple[float, float, float, float]:
    """The bounds of `geometry` grown to whole multiples of the resolution (the DSM
    grid's snapping, see dsm_export)."""
    left, bottom, right, top = geometry.bounds
    res = float(resolution_m)
    return (
        float(np.floor(left / res) * res),
        float(np.floor(bottom / res) * res),
        float((np.floor(right / res) + 1) * res),
        float((np.floor(top / res) + 1) * res),
    )


def grid_of(
    bounds: tuple[float, float, float, float], resolution_m: float
) -> tuple[Affine, tuple[int, int]]:
    """The north-up raster (transform, (rows, cols)) of snapped `bounds`."""
    left, bottom, right, top = bounds
    res = float(resolution_m)
    shape = (round((top - bottom) / res), round((right - left) / res))
    return Affine(res, 0.0, left, 0.0, -res, top), shape


def points_inside(points: np.ndarray, region: BaseGeometry, resolution_m: float) -> np.ndarray:
    """Which points (N, >= 2) fall into a cell of `resolution_m` whose centre is in
    `region`: one raster lookup per point instead of a polygon test (millions of points)."""
    inside = np.zeros(len(points), dtype=bool)
    if region.is_empty or len(points) == 0:
        return inside
    transform, shape = grid_of(snapped_bounds(region, resolution_m), resolution_m)
    cut = rasterise(region, transform, shape)
    if cut is None:
        return inside
    window, mask = cut
    local = window_transform(window, transform)
    col = np.floor((points[:, 0] - local.c) / local.a)
    row = np.floor((points[:, 1] - local.f) / local.e)
    ok = (
        np.isfinite(col)
        & np.isfinite(row)
        & (col >= 0)
        & (col < mask.shape[1])
        & (row >= 0)
        & (row < mask.shape[0])
    )
    inside[ok] = mask[row[ok].astype(np.int64), col[ok].astype(np.int64)] > 0
    return inside


@dataclass
class SurveyFootprints:
    """What the cameras of a survey see: `viewpoints`, what is seen from each place a
    camera stood (the union of the footprints, on the surface their image borders meet
    (`VIEW_SURFACE_QUANTILE`), of the keyframes taken there, see `viewpoint_groups`), and
    `reach`, the union of the footprints on the ground each sees (its fitted plane, and
    its low ground), grown by `margin_m`: where a point the cameras measured can lie."""

    viewpoints: list[BaseGeometry]
    reach: BaseGeometry
    margin_m: float


def viewpoint_groups(
    centres: np.ndarray, depths: np.ndarray, min_baseline_ratio: float
) -> np.ndarray:
    """Per keyframe (in order), the viewpoint it belongs to: a keyframe closer than
    `min_baseline_ratio` times its depth to the first keyframe of the current viewpoint
    joins it, any other starts the next. Ground seen from one viewpoint only has no
    stereo, however many keyframes see it: a video holds many keyframes where the
    aircraft hovers, turns on the spot at a line's end or climbs straight up, and their
    footprints overlap without a baseline between them. Keyframes without a depth start
    their own viewpoint."""
    groups = np.zeros(len(centres), dtype=np.int64)
    anchor = 0
    for i in range(1, len(centres)):
        reach = min_baseline_ratio * depths[anchor]
        if np.isfinite(reach) and np.linalg.norm(centres[i] - centres[anchor]) < reach:
            groups[i] = groups[anchor]
        else:
            anchor = i
            groups[i] = groups[i - 1] + 1
    return groups


def survey_footprints(
    sparse: SparseMap,
    resolution_m: float,
    margin_fraction: float = 0.05,
    margin_cells: int = 5,
    low_ground_quantile: float = 0.05,
    min_baseline_ratio: float = 0.04,
) -> SurveyFootprints | None:
    """The footprints of `sparse`'s keyframes (see `SurveyFootprints`); the margin is the
    larger of `margin_fraction` of the median footprint's size (square root of its area:
    pose and ground-height errors scale with it) and `margin_cells` DSM cells; keyframes
    closer than `min_baseline_ratio` times their height above the ground they see share
    a viewpoint (the shortest baseline dense matching takes). None when no keyframe has
    a footprint."""
    # Where points may lie is bounded by the ground each camera sees, not by the surface
    # its border meets first: the footprints on the fitted planes, and on the low ground.
    fitted = camera_footprints(sparse)
    sizes = [np.sqrt(p.area) for p in fitted if p is not None]
    if not sizes:
        return None
    margin = max(margin_fraction * float(np.median(sizes)), margin_cells * resolution_m)
    far = camera_footprints(sparse, ground_quantile=low_ground_quantile)
    reach = footprint_union([*far, *fitted], margin)
    views = camera_footprints(sparse, surface_quantile=VIEW_SURFACE_QUANTILE)
    centres = sparse.kf_centres()
    depths = centres[:, 2] - ground_heights(sparse)
    groups = viewpoint_groups(centres, np.where(depths > 0, depths, np.nan), min_baseline_ratio)
    viewpoints = [
        footprint_union([views[i] for i in np.flatnonzero(groups == g)])
        for g in range(int(groups.max()) + 1 if len(groups) else 0)
    ]
    return SurveyFootprints(viewpoints=viewpoints, reach=reach, margin_m=margin)


def overlap_figures(
    views: Sequence[BaseGeometry | None], measured: np.ndarray, transform: Affine
) -> tuple[float, float | None]:
    """(area in m² seen by two or more of `views` (a survey's viewpoints), the fraction
    of it that `measured` (a north-up raster, `transform`) holds; None when no cell is
    seen twice). Counted on a grid of the raster's cells grown to hold every footprint:
    overlap outside the raster (where no point was kept) counts as not measured."""
    union = footprint_union(views)
    if union.is_empty:
        return 0.0, None
    res = float(transform.a)
    left, bottom, right, top = union.bounds
    # Whole cells of the raster's grid, extended to the footprints' bounds.
    col0 = int(np.floor((left - transform.c) / res))
    col1 = int(np.ceil((right - transform.c) / res))
    row0 = int(np.floor((transform.f - top) / res))
    row1 = int(np.ceil((transform.f - bottom) / res))
    col0, row0 = min(col0, 0), min(row0, 0)
    col1, row1 = max(col1, measured.shape[1]), max(row1, measured.shape[0])
    grid = transform * Affine.translation(col0, row0)
    count = view_count(views, grid, (row1 - row0, col1 - col0))
    overlap = count >= 2
    del count
    cells = int(overlap.sum())
    if cells == 0:
        return 0.0, None
    inside = overlap[-row0 : -row0 + measured.shape[0], -col0 : -col0 + measured.shape[1]]
    return float(cells * res * res), float((inside & measured).sum() / cells)
