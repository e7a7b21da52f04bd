"""A true orthophoto on the survey's DSM: every ground cell coloured from the views that
see it best.

A plain orthomosaic drapes whole images over the ground and leans every building and tree
away from the nadir; a *true* orthophoto colours each DSM cell from the cameras that
actually see that cell, so what stands up stays where it stands. Per cell:

1. **Which views see it.** Each chosen view gets a depth buffer: the DSM cells around its
   footprint projected into it, the nearest depth kept per buffer pixel. A cell farther
   than what its buffer pixel holds (by more than a tolerance that grows with distance
   and with the buffer pixel's size on the ground) is hidden behind something in that
   view and takes no colour from it.
2. **Which of those see it best.** A score per cell and view: nearest to nadir (the
   viewing ray's elevation), nearest to the image centre (least lens falloff and
   distortion), closest (finest ground sampling) and sharpest (the frame's own
   sharpness against the survey's median). The colours of the views within a small score
   margin of the best are blended with weights that fall off exponentially, so a seam is
   a short ramp rather than a step; an image border ramps to zero weight the same way.
3. **Exposure balanced.** Automatic exposure changes brightness between frames. On a
   coarse grid of ground points seen by several views, the median log-ratio of each pair
   of overlapping views gives an equation g_i - g_j = log I_j - log I_i per colour; their
   least-squares solution (gains pulled towards 1) scales each view before it is used.

Views: the keyframes of the map, thinned so that no two kept cameras are closer than a
fraction of a footprint (a 20 min flight has thousands of keyframes, and nearby ones add
nothing but time). Their colour images come from the frames stage's colour copy of the
frames it stored (at twice the processing size: the orthophoto is finer than the DSM
where the imagery allows; only the chosen frames converted), or from the survey's own
video in work folders made before that copy, or from its photos. Images and depth buffers are
kept in memory-mapped files in a scratch folder, and the orthophoto is made tile by tile,
so memory stays bounded whatever the survey's size.

The result is an RGBA Cloud-Optimized GeoTIFF on the DSM's grid (its cells an integer
fraction of the DSM's, at most half), alpha 0 where no view saw the ground or the DSM has no height.
"""

from __future__ import annotations

import math
import shutil
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import rasterio
from rasterio.enums import ColorInterp
from rasterio.transform import Affine
from rasterio.windows import Window

from worker.pipeline.cog import RasterRole, write_cog
from worker.pipeline.errors import InputError
from worker.pipeline.frames import FrameScan, iter_prepared_frames
from worker.pipeline.ingest.video import VideoReader
from worker.pipeline.progress import ProgressFn, no_progress
from worker.pipeline.slam.result import SparseMap

SCRATCH_DIR = "orthophoto.scratch"  # removed when the stage ends (and when it starts again)


@dataclass
class OrthophotoOptions:
    enabled: bool = True
    # Orthophoto cells per DSM cell side, at most; the scale used is the finest the
    # imagery supports (cells no smaller than 1.2 times the images' ground sampling). Finer
    # than half a DSM cell shows detail where the DSM cannot place it: on forested
    # hillslopes (30 s, 1280 px, seeds 1-3) cells of a third of a DSM cell put features
    # 0.30-0.66 m off (median per seed), cells of half a DSM cell 0.19-0.43 m.
    max_scale: int = 2
    # Colour images at this multiple of the processing size (video), at most the original.
    colour_scale: float = 2.0
    # Kept cameras at least this fraction of the footprint's width apart.
    view_spacing: float = 0.25
    tile_size: int = 512
    # Views within about this score of the best are blended (see the module doc).
    blend_margin: float = 0.04
    # A border ramp this fraction of the image's width, over which a view's weight falls
    # to zero: seams never sit on an image edge.
    edge_ramp: float = 0.06
    exposure: bool = True
    # Gains are pulled towards 1 with this weight against the pair equations.
    gain_prior: float = 0.05
    # Depth buffers at 1/buffer_step of the colour image's resolution.
    buffer_step: int = 4


@dataclass
class OrthophotoResult:
    path: str | None
    width: int
    height: int
    resolution_m: float
    scale: int  # orthophoto cells per DSM cell side
    views: int
    keyframes: int
    coverage: float  # share of the DSM's valid cells that got a colour
    exposure_gain_range: tuple[float, float]
    seconds: float
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "path": self.path,
            "width": self.width,
            "height": self.height,
            "resolution_m": self.resolution_m,
            "scale": self.scale,
            "views": self.views,
            "keyframes": self.keyframes,
            "coverage": self.coverage,
            "exposure_gain_range": list(self.exposure_gain_range),
            "seconds": self.seconds,
            "warnings": self.warnings,
        }


@dataclass
class ViewImages:
    """Where the colour of the chosen keyframes comes from: an image per keyframe index,
    as `load(indices, size)` yields (index, BGR image of `size`)."""

    size: tuple[int, int]  # width, height of the images it yields
    load: Callable[[list[int]], Iterator[tuple[int, np.ndarray]]]
    sharpness: dict[int, float] = field(default_factory=dict)


@dataclass
class _Camera:
    k: np.ndarray  # 3 x 3 for the colour images
    size: tuple[int, int]
    distortion: np.ndarray  # OpenCV k1, k2, p1, p2, k3 (zeros: pinhole)

    def project(
        self, r: np.ndarray, t: np.ndarray, xyz: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel u, v and depth of world points (N, 3) in a camera x = R X + t."""
        # R X^T, not X R^T: numpy multiplies an (N, 3) array by a transposed 3 x 3 view
        # about ten times slower (0.2 s for the million cells of one depth buffer; the
        # orthophoto stage spent more time here than anywhere else).
        cam = r.astype(xyz.dtype) @ xyz.T
        cam += t.astype(xyz.dtype)[:, None]
        z = cam[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x = cam[0] / z
            y = cam[1] / z
        if np.any(self.distortion):
            k1, k2, p1, p2, k3 = self.distortion[:5]
            r2 = x * x + y * y
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            x, y = (
                x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y,
            )
        k = self.k
        return k[0, 0] * x + k[0, 2], k[1, 1] * y + k[1, 2], z


def scaled_k(k: np.ndarray, size: tuple[int, int], new_size: tuple[int, int]) -> np.ndarray:
    """Intrinsics for images resized from `size` to `new_size` (pixel centres at
    integers: x' = (x + 0.5) s - 0.5)."""
    sx, sy = new_size[0] / size[0], new_size[1] / size[1]
    out = k.astype(np.float64).copy()
    out[0, 0] *= sx
    out[1, 1] *= sy
    out[0, 2] = (k[0, 2] + 0.5) * sx - 0.5
    out[1, 2] = (k[1, 2] + 0.5) * sy - 0.5
    return out


def select_views(sparse: SparseMap, spacing_m: float) -> np.ndarray:
    """Keyframe indices, thinned greedily in time order: a keyframe is kept when no kept
    camera is within `spacing_m` of it."""
    centres = sparse.kf_centres()
    if spacing_m <= 0 or len(centres) < 2:
        return np.arange(len(centres))
    # Cells of the spacing: a kept camera can only be near one in its own or a
    # neighbouring cell, so the test stays cheap for thousands of keyframes.
    kept: list[int] = []
    grid: dict[tuple[int, int], list[int]] = {}
    for i, c in enumerate(centres):
        cell = (int(c[0] // spacing_m), int(c[1] // spacing_m))
        near = (
            j
            for dx in (-1, 0, 1)
            for dy in (-1, 0, 1)
            for j in grid.get((cell[0] + dx, cell[1] + dy), ())
        )
        if all(np.linalg.norm(centres[j] - c) >= spacing_m for j in near):
            kept.append(i)
            grid.setdefault(cell, []).append(i)
    return np.array(kept, dtype=np.int64)


def _median_height(sparse: SparseMap) -> float:
    if sparse.point_xyz.size:
        return float(np.median(sparse.point_xyz[:, 2]))
    return float(np.median(sparse.kf_centres()[:, 2])) - 50.0


def _footprint_bounds(
    camera: _Camera, r: np.ndarray, t: np.ndarray, z_range: tuple[float, float]
) -> tuple[float, float, float, float] | None:
    """x0, y0, x1, y1 of where the image's corners (and centre) meet the planes at the
    lowest and highest ground heights; None when a corner ray does not meet the ground
    (a view at the horizon: its footprint is unbounded)."""
    w, h = camera.size
    pixels = np.array([[0, 0], [w, 0], [0, h], [w, h], [w / 2, h / 2]], float)
    rays_cam = np.column_stack(
        [
            (pixels[:, 0] - camera.k[0, 2]) / camera.k[0, 0],
            (pixels[:, 1] - camera.k[1, 2]) / camera.k[1, 1],
            np.ones(len(pixels)),
        ]
    )
    rays = rays_cam @ r  # R^T applied to each row: the rays in the world
    centre = -r.T @ t
    points = []
    for z in z_range:
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (z - centre[2]) / rays[:, 2]
        if not np.all(np.isfinite(s)) or np.any(s <= 0):
            return None
        points.append(centre[:2] + s[:, None] * rays[:, :2])
    p = np.vstack(points)
    return float(p[:, 0].min()), float(p[:, 1].min()), float(p[:, 0].max()), float(p[:, 1].max())


class _DsmReader:
    """Windows of the DSM (NaN where it has no height), by world bounds."""

    def __init__(self, path: Path) -> None:
        self.src = rasterio.open(path)
        self.transform: Affine = self.src.transform
        self.res = float(self.src.res[0])
        self.nodata = self.src.nodata

    def close(self) -> None:
        self.src.close()

    def window(self, bounds: tuple[float, float, float, float], step: int = 1) -> tuple:
        """Cell centres' x, y, z (z NaN where missing) inside `bounds`, every `step`-th
        cell; empty arrays when the bounds miss the DSM."""
        x0, y0, x1, y1 = bounds
        inv = ~self.transform
        c0, r0 = inv * (x0, y1)
        c1, r1 = inv * (x1, y0)
        col0, row0 = max(0, math.floor(c0)), max(0, math.floor(r0))
        col1 = min(self.src.width, math.ceil(c1))
        row1 = min(self.src.height, math.ceil(r1))
        if col1 <= col0 or row1 <= row0:
            empty = np.empty(0)
            return empty, empty, empty
        win = Window(col0, row0, col1 - col0, row1 - row0)
        out_shape = (max(1, win.height // step), max(1, win.width // step))
        z = self.src.read(1, window=win, out_shape=out_shape).astype(np.float64)
        if self.nodata is not None:
            z[z == self.nodata] = np.nan
        sy, sx = win.height / out_shape[0], win.width / out_shape[1]
        cols = col0 + (np.arange(out_shape[1]) + 0.5) * sx
        rows = row0 + (np.arange(out_shape[0]) + 0.5) * sy
        a = self.transform
        xs = a.c + cols * a.a
        ys = a.f + rows * a.e
        xx, yy = np.meshgrid(xs, ys)
        return xx.ravel(), yy.ravel(), z.ravel()


def _depth_buffer(
    camera: _Camera,
    r: np.ndarray,
    t: np.ndarray,
    dsm: _DsmReader,
    bounds: tuple[float, float, float, float],
    step: int,
) -> np.ndarray:
    """The nearest depth per buffer pixel (inf where no DSM cell lands)."""
    w, h = camera.size
    bw, bh = -(-w // step), -(-h // step)
    depth = np.full(bh * bw, np.inf, np.float32)
    x, y, z = dsm.window(bounds)
    ok = np.isfinite(z)
    if not ok.any():
        return depth.reshape(bh, bw)
    xyz = np.column_stack([x[ok], y[ok], z[ok]])
    u, v, d = camera.project(r, t, xyz)
    inside = (d > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    idx = (v[inside] // step).astype(np.int64) * bw + (u[inside] // step).astype(np.int64)
    np.minimum.at(depth, idx, d[inside].astype(np.float32))
    depth = depth.reshape(bh, bw)
    # A buffer pixel no cell landed in (steep ground seen at a grazing angle) takes its
    # neighbours' nearest depth, so a hidden cell behind it does not show through.
    holes = ~np.isfinite(depth)
    if holes.any():
        finite = np.where(holes, np.float32(3e38), depth)
        near = cv2.erode(finite, np.ones((3, 3), np.uint8))
        depth = np.where(holes & (near < 3e38), near, depth)
    return depth


def colour_view_size(
    video_size: tuple[int, int], processing_size: tuple[int, int], colour_scale: float
) -> tuple[int, int]:
    """The size of the views' colour images: `colour_scale` times the processing size,
    no larger than the video, both sides even (H.264's 4:2:0)."""
    w0, h0 = processing_size
    width = int(min(video_size[0], round(w0 * colour_scale))) // 2 * 2
    return width, int(round(width * h0 / w0 / 2) * 2)


def _frame_views(
    frames: Callable[[Callable[[float], bool]], Iterator[Any]],
    size: tuple[int, int],
    sparse: SparseMap,
    scan: FrameScan,
    fps: float,
) -> ViewImages:
    """The keyframes' images from a stream of video frames (`frames(wanted)` yields
    the frames whose time `wanted` accepts, each with `.t` and a BGR `.image`), matched
    by time; their sharpness from the frames stage's `scan`."""
    times = sparse.kf_t
    tol = 0.25 / fps
    sharp = {}
    if scan.t.size:
        nearest = np.clip(np.searchsorted(scan.t, times), 0, scan.t.size - 1)
        sharp = {i: float(scan.sharpness[n]) for i, n in enumerate(nearest.tolist())}

    def load(indices: list[int]) -> Iterator[tuple[int, np.ndarray]]:
        wanted = np.sort(times[indices])
        index_of = {float(times[i]): i for i in indices}
        keys = np.array(sorted(index_of))

        def is_wanted(t: float) -> bool:
            j = int(np.searchsorted(wanted, t))
            return any(0 <= k < wanted.size and abs(wanted[k] - t) <= tol for k in (j - 1, j))

        for frame in frames(is_wanted):
            j = int(np.argmin(np.abs(keys - frame.t)))
            yield index_of[float(keys[j])], frame.image

    return ViewImages(size=size, load=load, sharpness=sharp)


def video_view_images(
    video: Path, sparse: SparseMap, scan: FrameScan, colour_scale: float
) -> ViewImages:
    """The keyframes' colour images decoded from the survey's video (only the frames at
    keyframe times are converted), at `colour_scale` times the processing size but no
    larger than the video."""
    info = VideoReader(video).info
    size = colour_view_size((info.width, info.height), sparse.size, colour_scale)

    def frames(wanted: Callable[[float], bool]) -> Iterator[Any]:
        return VideoReader(video).frames(size=size, gray=False, wanted=wanted)

    return _frame_views(frames, size, sparse, scan, info.fps or 30.0)


def stored_view_images(
    frames_dir: Path, size: tuple[int, int], sparse: SparseMap, scan: FrameScan, fps: float
) -> ViewImages:
    """The keyframes' colour images from the frames stage's colour copy of the frames
    it stored (frames.py, `colour.mkv`, of `size`): the survey's video is not decoded
    again, nor needed any more."""

    def frames(wanted: Callable[[float], bool]) -> Iterator[Any]:
        return iter_prepared_frames(frames_dir, colour=True, wanted=wanted)

    return _frame_views(frames, size, sparse, scan, fps)


def still_view_images(paths: list[str], times: list[float], sparse: SparseMap) -> ViewImages:
    """The keyframes' colour images from the image files the map was made of (matched by
    time), at the size the map's intrinsics are for."""
    by_time = {float(t): p for t, p in zip(times, paths, strict=True)}
    keys = np.array(sorted(by_time))
    size = sparse.size

    def path_of(i: int) -> str:
        j = int(np.argmin(np.abs(keys - sparse.kf_t[i])))
        return by_time[float(keys[j])]

    def load(indices: list[int]) -> Iterator[tuple[int, np.ndarray]]:
        for i in indices:
            image = cv2.imread(path_of(i), cv2.IMREAD_COLOR)
            if image is None:
                continue
            if (image.shape[1], image.shape[0]) != size:
                image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
            yield i, image

    return ViewImages(size=size, load=load)


def _exposure_gains(
    camera: _Camera,
    sparse: SparseMap,
    views: np.ndarray,
    images: np.ndarray,
    buffers: np.ndarray,
    dsm: _DsmReader,
    options: OrthophotoOptions,
) -> np.ndarray:
    """Per view and colour, the gain that matches it to its overlapping views (see the
    module doc); ones when there is nothing to match."""
    n = len(views)
    gains = np.ones((n, 3))
    if n < 2:
        return gains
    src = dsm.src
    step = max(1, int(max(src.width, src.height) // 200))
    x, y, z = dsm.window(
        (src.bounds.left, src.bounds.bottom, src.bounds.right, src.bounds.top), step
    )
    ok = np.isfinite(z)
    xyz = np.column_stack([x[ok], y[ok], z[ok]])
    if len(xyz) < 20:
        return gains
    w, h = camera.size
    seen_idx: list[np.ndarray] = []
    seen_log: list[np.ndarray] = []
    for v, kf in enumerate(views.tolist()):
        u, vv, d = camera.project(sparse.kf_r[kf], sparse.kf_tr[kf], xyz)
        margin = 0.1 * w
        inside = (d > 0) & (u >= margin) & (u < w - margin) & (vv >= margin) & (vv < h - margin)
        idx = np.flatnonzero(inside)
        bu = (u[idx] // options.buffer_step).astype(int)
        bv = (vv[idx] // options.buffer_step).astype(int)
        visible = d[idx] <= buffers[v][bv, bu] * 1.02 + 3 * dsm.res
        idx, bu, bv = idx[visible], bu[visible], bv[visible]
        # Colours of a blurred image: a few pixels of misregistration do not matter.
        small = cv2.resize(
            np.asarray(images[v]), (w // 8, h // 8), interpolation=cv2.INTER_AREA
        ).astype(np.float64)
        colour = small[
            np.clip((vv[idx] / 8).astype(int), 0, h // 8 - 1),
            np.clip((u[idx] / 8).astype(int), 0, w // 8 - 1),
        ]
        good = np.all(colour > 8, axis=1) & np.all(colour < 247, axis=1)
        seen_idx.append(idx[good])
        seen_log.append(np.log(colour[good]))
    rows: list[tuple[int, int, np.ndarray, float]] = []
    for i in range(n):
        for j in range(i + 1, n):
            shared, a, b = np.intersect1d(seen_idx[i], seen_idx[j], return_indices=True)
            if shared.size < 20:
                continue
            diff = np.median(seen_log[i][a] - seen_log[j][b], axis=0)
            rows.append((i, j, diff, math.sqrt(shared.size)))
    if not rows:
        return gains
    # Normal equations of sum w (g_i - g_j + d_ij)^2 + prior sum g_i^2, per colour.
    normal = np.eye(n) * options.gain_prior * max(1.0, np.mean([r[3] for r in rows]))
    rhs = np.zeros((n, 3))
    for i, j, diff, weight in rows:
        normal[i, i] += weight
        normal[j, j] += weight
        normal[i, j] -= weight
        normal[j, i] -= weight
        rhs[i] -= weight * diff
        rhs[j] += weight * diff
    log_gains = np.linalg.solve(normal, rhs)
    return np.exp(np.clip(log_gains, -math.log(2.0), math.log(2.0)))


def write_orthophoto(
    work_dir: Path,
    sparse: SparseMap,
    dsm_path: Path,
    source: ViewImages,
    out_path: Path,
    options: OrthophotoOptions | None = None,
    distortion: np.ndarray | None = None,
    progress: ProgressFn = no_progress,
) -> OrthophotoResult:
    """Make the true orthophoto of `dsm_path` from the map's keyframes (see the module
    doc) and write it as an RGBA COG at `out_path`."""
    start = time.perf_counter()
    options = options or OrthophotoOptions()
    work_dir = Path(work_dir)
    scratch = work_dir / SCRATCH_DIR
    shutil.rmtree(scratch, ignore_errors=True)  # what a killed run left
    scratch.mkdir(parents=True)
    try:
        return _write(work_dir, sparse, dsm_path, source, out_path, options, distortion,
                      progress, scratch, start)  # fmt: skip
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _write(
    work_dir: Path,
    sparse: SparseMap,
    dsm_path: Path,
    source: ViewImages,
    out_path: Path,
    options: OrthophotoOptions,
    distortion: np.ndarray | None,
    progress: ProgressFn,
    scratch: Path,
    start: float,
) -> OrthophotoResult:
    if sparse.kf_t.size == 0:
        raise InputError("the map has no keyframe to colour the orthophoto from")
    camera = _Camera(
        scaled_k(sparse.k, sparse.size, source.size),
        source.size,
        np.zeros(5) if distortion is None else np.asarray(distortion, float)[:5],
    )
    w, h = camera.size
    warnings: list[str] = []
    dsm = _DsmReader(dsm_path)
    try:
        ground = _median_height(sparse)
        heights = sparse.kf_centres()[:, 2] - ground
        altitude = float(np.median(np.abs(heights))) if heights.size else 50.0
        footprint_m = altitude * w / camera.k[0, 0]
        views = select_views(sparse, options.view_spacing * footprint_m)
        # The DSM's own height range bounds the footprints: its 1st to 99th percentile,
        # since a few outlying cells (a spike above the cameras: 82 m under a flight at
        # 32 m, issue 18's flight seed 8) would put every view at the horizon.
        stats = dsm.src.read(1, out_shape=(64, 64), masked=True).compressed()
        z_range = (ground, ground)
        if stats.size:
            low, high = np.percentile(stats, [1.0, 99.0])
            z_range = (float(low), float(high))
        bounds_of: dict[int, tuple[float, float, float, float]] = {}
        for kf in views.tolist():
            b = _footprint_bounds(camera, sparse.kf_r[kf], sparse.kf_tr[kf], z_range)
            if b is not None:
                bounds_of[kf] = b
        dropped = len(views) - len(bounds_of)
        if dropped:
            warnings.append(f"{dropped} views look at the horizon and were left out")
        views = np.array([kf for kf in views.tolist() if kf in bounds_of], dtype=np.int64)
        if views.size == 0:
            raise InputError("no camera of the survey looks at the ground")
        n = len(views)
        images = np.lib.format.open_memmap(
            scratch / "images.npy", mode="w+", dtype=np.uint8, shape=(n, h, w, 3)
        )
        have = np.zeros(n, bool)
        position = {kf: v for v, kf in enumerate(views.tolist())}
        sharp = np.ones(n)
        for kf, image in source.load(views.tolist()):
            v = position[kf]
            images[v] = image
            have[v] = True
            sharp[v] = source.sharpness.get(kf) or _sharpness(image)
            progress(0.4 * have.sum() / n)
        if not have.any():
            raise InputError("none of the survey's frames could be read for the orthophoto")
        if not have.all():
            warnings.append(f"{int((~have).sum())} of {n} frames could not be read; left out")
        views, images_kept = views[have], np.flatnonzero(have)
        n = len(views)
        step = options.buffer_step
        buffers = np.lib.format.open_memmap(
            scratch / "depth.npy",
            mode="w+",
            dtype=np.float32,
            shape=(n, -(-h // step), -(-w // step)),
        )
        for v, kf in enumerate(views.tolist()):
            buffers[v] = _depth_buffer(
                camera, sparse.kf_r[kf], sparse.kf_tr[kf], dsm, bounds_of[kf], step
            )
        progress(0.5)
        view_images = _Reindexed(images, images_kept)
        gains = (
            _exposure_gains(camera, sparse, views, view_images, buffers, dsm, options)
            if options.exposure
            else np.ones((n, 3))
        )
        sharp = sharp[images_kept]
        sharp_term = np.clip(0.1 * np.log(np.maximum(sharp, 1e-6) / np.median(sharp)), -0.3, 0.1)
        # The finest cells the imagery supports, an integer fraction of the DSM's.
        gsd = altitude / camera.k[0, 0]
        scale = int(np.clip(math.floor(dsm.res / (1.2 * gsd)), 1, options.max_scale))
        result = _render(
            camera, sparse, views, view_images, buffers, gains, sharp_term,
            [bounds_of[kf] for kf in views.tolist()], dsm, scale, altitude, out_path,
            scratch, options, progress,
        )  # fmt: skip
    finally:
        dsm.close()
    width, height, coverage = result
    return OrthophotoResult(
        path=str(out_path),
        width=width,
        height=height,
        resolution_m=round(dsm.res / scale, 6),
        scale=scale,
        views=n,
        keyframes=int(sparse.kf_t.size),
        coverage=round(coverage, 4),
        exposure_gain_range=(round(float(gains.min()), 3), round(float(gains.max()), 3)),
        seconds=round(time.perf_counter() - start, 3),
        warnings=warnings,
    )


class _Reindexed:
    """The rows `rows` of an array, indexed 0..len(rows)-1."""

    def __init__(self, array: np.ndarray, rows: np.ndarray) -> None:
        self.array, self.rows = array, rows

    def __getitem__(self, i: int) -> np.ndarray:
        return self.array[self.rows[i]]

    def __len__(self) -> int:
        return len(self.rows)


def _sharpness(image: np.ndarray) -> float:
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)[::2, ::2]
    return float(cv2.Laplacian(grey, cv2.CV_32F, ksize=3).var())


def _render(
    camera: _Camera,
    sparse: SparseMap,
    views: np.ndarray,
    images: _Reindexed,
    buffers: np.ndarray,
    gains: np.ndarray,
    sharp_term: np.ndarray,
    bounds: list[tuple[float, float, float, float]],
    dsm: _DsmReader,
    scale: int,
    altitude: float,
    out_path: Path,
    scratch: Path,
    options: OrthophotoOptions,
    progress: ProgressFn,
) -> tuple[int, int, float]:
    """Colour the orthophoto tile by tile into a GeoTIFF, then make it a COG; its width,
    height and the share of the DSM's valid cells it coloured."""
    src = dsm.src
    res = dsm.res / scale
    width, height = src.width * scale, src.height * scale
    transform = src.transform * Affine.scale(1 / scale)
    w, h = camera.size
    centres = np.array([-sparse.kf_r[kf].T @ sparse.kf_tr[kf] for kf in views.tolist()])
    box = np.array(bounds)
    tile = options.tile_size
    tau = options.blend_margin / 3.0
    ramp = max(1.0, options.edge_ramp * w)
    step = options.buffer_step
    valid_cells = coloured = 0
    profile = {
        "driver": "GTiff",
        "width": width,
        "height": height,
        "count": 4,
        "dtype": "uint8",
        "crs": src.crs,
        "transform": transform,
        "tiled": True,
        "blockxsize": 256,
        "blockysize": 256,
        "compress": "deflate",
        "photometric": "RGB",
    }
    plain_path = scratch / "orthophoto.tif"
    tiles = [(row, col) for row in range(0, height, tile) for col in range(0, width, tile)]
    with rasterio.open(plain_path, "w", **profile) as dst:
        dst.colorinterp = [ColorInterp.red, ColorInterp.green, ColorInterp.blue, ColorInterp.alpha]
        for done, (row, col) in enumerate(tiles):
            th, tw = min(tile, height - row), min(tile, width - col)
            x = transform.c + (col + np.arange(tw) + 0.5) * res
            y = transform.f - (row + np.arange(th) + 0.5) * res
            z = _heights(src, dsm.nodata, row, col, th, tw, scale)
            xx, yy = np.meshgrid(x, y)
            ok = np.isfinite(z)
            valid_cells += int(ok.sum())
            rgba = np.zeros((4, th, tw), np.uint8)
            if ok.any():
                x0, x1, y0, y1 = x[0], x[-1], y[-1], y[0]
                near = np.flatnonzero(
                    (box[:, 0] <= x1) & (box[:, 2] >= x0) & (box[:, 1] <= y1) & (box[:, 3] >= y0)
                )
                # Coordinates from the tile's corner in single precision (UTM values
                # lose centimetres in float32; offsets from a corner do not).
                origin = np.array([x0, y1, float(np.nanmedian(z))])
                xyz = np.column_stack([xx[ok] - x0, yy[ok] - y1, z[ok] - origin[2]]).astype(
                    np.float32
                )
                cell_index = np.full((th, tw), -1, np.int64)
                cell_index[ok] = np.arange(len(xyz))
                accum = np.zeros((len(xyz), 3), np.float32)
                total = np.zeros(len(xyz), np.float32)
                for v in near.tolist():
                    kf = int(views[v])
                    # Only the cells inside the view's footprint are projected.
                    c0, c1 = np.searchsorted(x, [box[v, 0], box[v, 2]])
                    r0, r1 = np.searchsorted(-y, [-box[v, 3], -box[v, 1]])
                    sub = cell_index[r0:r1, c0:c1]
                    idx = sub[sub >= 0]
                    if idx.size == 0:
                        continue
                    r = sparse.kf_r[kf]
                    t = r @ origin + sparse.kf_tr[kf]
                    u, vv, d = camera.project(r, t, xyz[idx])
                    inside = (d > 0) & (u >= 0) & (u <= w - 1) & (vv >= 0) & (vv <= h - 1)
                    if not inside.any():
                        continue
                    idx, u, vv, d = idx[inside], u[inside], vv[inside], d[inside]
                    buf = buffers[v][(vv // step).astype(int), (u // step).astype(int)]
                    pixel_m = d * (step / camera.k[0, 0])
                    visible = d <= buf + 0.01 * d + 2.0 * pixel_m + 2.0 * dsm.res
                    if not visible.any():
                        continue
                    idx, u, vv, d = idx[visible], u[visible], vv[visible], d[visible]
                    ray = (centres[v] - origin).astype(np.float32) - xyz[idx]
                    nadir = ray[:, 2] / np.sqrt(np.einsum("ij,ij->i", ray, ray))
                    radial = ((u - camera.k[0, 2]) * (2 / w)) ** 2 + (
                        (vv - camera.k[1, 2]) * (2 / h)
                    ) ** 2
                    score = (
                        nadir
                        - 0.08 * radial
                        - 0.1 * np.log(np.maximum(d, 1e-3) / altitude)
                        + sharp_term[v]
                    )
                    edge = np.minimum(np.minimum(u, w - 1 - u), np.minimum(vv, h - 1 - vv))
                    # Weights relative to a fixed top score (1: nadir, centre) keep the
                    # sums in range; the blend then favours the best view by exp(Δ/τ).
                    weight = np.exp((score - 1.0) / tau) * np.clip(edge / ramp, 0.0, 1.0)
                    colour = _sample(np.asarray(images[v]), u, vv)
                    accum[idx] += weight[:, None] * colour * gains[v].astype(np.float32)
                    total[idx] += weight
                got = total > 0
                colour = np.zeros((len(xyz), 3))
                colour[got] = accum[got] / total[got, None]
                bgr = np.clip(np.rint(colour), 0, 255).astype(np.uint8)
                flat = np.flatnonzero(ok.ravel())
                for band, channel in enumerate((2, 1, 0)):  # BGR to RGB
                    plane = rgba[band].reshape(-1)
                    plane[flat] = bgr[:, channel]
                alpha = rgba[3].reshape(-1)
                alpha[flat[got]] = 255
                coloured += int(got.sum())
            dst.write(rgba, window=Window(col, row, tw, th))
            progress(0.5 + 0.45 * (done + 1) / len(tiles))
    write_cog(plain_path, out_path, RasterRole.image)
    return width, height, coloured / valid_cells if valid_cells else 0.0


def _sample(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear colours (N, 3) at pixel positions u, v (OpenCV's maps are at most 32767
    on a side: the points go in rows of 1024)."""
    n = u.size
    rows = -(-n // 1024)
    map_x = np.zeros(rows * 1024, np.float32)
    map_y = np.zeros(rows * 1024, np.float32)
    map_x[:n], map_y[:n] = u, v
    out = cv2.remap(
        image,
        map_x.reshape(rows, 1024),
        map_y.reshape(rows, 1024),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    return out.reshape(-1, 3)[:n].astype(np.float32)


def _heights(
    src: rasterio.io.DatasetReader,
    nodata: float | None,
    row: int,
    col: int,
    th: int,
    tw: int,
    scale: int,
) -> np.ndarray:
    """The DSM's heights at the centres of a tile of orthophoto cells (bilinear between
    DSM cells; NaN where the DSM has none)."""
    r0, c0 = row // scale, col // scale
    r1 = min(src.height, -(-(row + th) // scale) + 1)
    c1 = min(src.width, -(-(col + tw) // scale) + 1)
    r0m, c0m = max(0, r0 - 1), max(0, c0 - 1)
    block = src.read(1, window=Window(c0m, r0m, c1 - c0m, r1 - r0m)).astype(np.float32)
    if nodata is not None:
        block[block == nodata] = np.nan
    if scale == 1:
        return block[row - r0m : row - r0m + th, col - c0m : col - c0m + tw].astype(np.float64)
    # Orthophoto cell centre (i + 0.5) / scale in DSM cells; DSM centres at j + 0.5.
    cols = ((col + np.arange(tw) + 0.5) / scale - 0.5 - c0m).astype(np.float32)
    rows = ((row + np.arange(th) + 0.5) / scale - 0.5 - r0m).astype(np.float32)
    map_x, map_y = np.meshgrid(cols, rows)
    out = cv2.remap(block, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.astype(np.float64)
