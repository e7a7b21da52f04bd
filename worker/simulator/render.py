"""Perspective rendering of a textured height field with correct occlusion.

The surface is the DSM, bilinearly interpolated between cell centres; its colour is
an orthoimage (albedo x shading, precomputed once per survey) on the same extent.
Each frame is rendered in three vectorised passes:

1. Splat: the DSM blocks inside the view frustum are sampled (every few cells far
   away, several samples per cell close by, so that neighbours land at most
   `splat_spacing_px` apart) and projected into a depth buffer (`np.minimum.at`).
   Steep sides (crown walls, scarps) are splatted as vertical columns down to the
   lowest neighbour. This tells, for every pixel, roughly how far the first surface is.
2. Intersect: every pixel ray is intersected exactly with the interpolated surface.
   The nearest splat of the pixel's 3x3 neighbourhood gives a bracket; a few secant
   steps kept inside it find the crossing. Rays already under the surface at the
   start of their bracket step backwards; rays passing in front of it (silhouettes)
   or without a splat are marched conservatively on max-maps of the DSM (they never
   step over a surface higher than their path) and then refined the same way.
   Every hit is a point of the surface on the pixel's ray, and the first one along
   it, except where a ray clips less than a cell of a steep object's edge.
3. Shade: the orthoimage is sampled at the hit points from a mip-map pyramid with
   per-pixel level of detail (tent-filtered between levels); vignetting and sensor
   noise are applied.

With `RenderOptions.rolling_shutter_margin_px`, a frame may be given three poses (mid
readout, first row, last row): the passes draw the mid-readout view over a field of
view grown by the margin, and `rolling_shutter.warp_rows` makes each row from it as
seen from its own pose, before vignetting and noise.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from worker.simulator.camera import CameraModel
from worker.simulator.georef import Grid
from worker.simulator.rolling_shutter import padded_camera, row_poses, warp_rows

_REMAP_WIDTH = 2048  # remap refuses images wider or taller than 32767 pixels
SKY_RGB = (205.0, 214.0, 224.0)


def sample_bilinear(img: np.ndarray, cols: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Bilinear samples of `img` at continuous (cols, rows) of any shape (cell centres
    at integers, mirrored outside the image). Returns float32 of shape cols.shape
    (+ channels)."""
    shape = cols.shape
    c = np.ascontiguousarray(cols, dtype=np.float32).ravel()
    r = np.ascontiguousarray(rows, dtype=np.float32).ravel()
    n = c.size
    if n == 0:
        extra = img.shape[2:] if img.ndim == 3 else ()
        return np.zeros(shape + extra, np.float32)
    if len(shape) == 2 and shape[0] < 32767 and shape[1] < 32767:
        out = cv2.remap(
            img,
            c.reshape(shape),
            r.reshape(shape),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REFLECT_101,
        )
        return out.astype(np.float32, copy=False)
    w = min(_REMAP_WIDTH, n)
    h = -(-n // w)
    pad = h * w - n
    if pad:
        c = np.concatenate([c, np.zeros(pad, np.float32)])
        r = np.concatenate([r, np.zeros(pad, np.float32)])
    out = cv2.remap(
        img,
        c.reshape(h, w),
        r.reshape(h, w),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REFLECT_101,
    )
    if img.ndim == 3:
        out = out.reshape(h * w, img.shape[2])[:n]
        return out.reshape((*shape, img.shape[2])).astype(np.float32, copy=False)
    return out.reshape(-1)[:n].reshape(shape).astype(np.float32, copy=False)


def _blocked(a: np.ndarray, hb: int, wb: int, b: int, fill) -> np.ndarray:
    """`a` (h, w) as (hb, wb, b, b) blocks of b x b cells, padded with `fill`."""
    p = np.full((hb * b, wb * b), fill, a.dtype)
    p[: a.shape[0], : a.shape[1]] = a
    return np.ascontiguousarray(p.reshape(hb, b, wb, b).transpose(0, 2, 1, 3))


@dataclass(frozen=True)
class RenderOptions:
    """How frames are rendered."""

    vignetting: float = 0.18
    """Relative darkening in the image corners (cos^4-like falloff scaled to this)."""
    noise_sigma: float = 1.2
    """Standard deviation of additive sensor noise in 8-bit levels (0 disables)."""
    refine_iterations: int = 3
    march_iterations: int = 400
    splat_spacing_px: float = 1.5
    """Largest distance in pixels between neighbouring splatted DSM cells (the 3x3
    neighbourhood of a pixel then always holds a sample)."""
    near_m: float = 0.05
    column_spacing_px: float = 2.0
    side_texture: bool = True
    """Give steep sides (crown walls) a texture varying with height, slightly darker."""
    """Spacing of the samples splatted along steep sides (vertical columns)."""
    rolling_shutter_margin_px: int = 0
    """Rolling-shutter frames: the view is drawn this many pixels wider on every side
    (at least how far a row's pose moves the image over the readout, see
    rolling_shutter.margin_for); 0: global shutter, one pose per frame."""


@dataclass
class RenderStats:
    """Counters accumulated over the frames a renderer has drawn."""

    frames: int = 0
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    pixels: int = 0
    marched_rays: int = 0
    sky_pixels: int = 0
    extra: dict = field(default_factory=dict)

    @property
    def frames_per_second(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    def to_dict(self) -> dict:
        return {
            "frames": self.frames,
            "seconds": round(self.seconds, 3),
            "frames_per_second": round(self.frames_per_second, 2),
            "cpu_ms_per_frame": round(1000 * self.cpu_seconds / max(self.frames, 1), 2),
            "marched_ray_fraction": round(self.marched_rays / max(self.pixels, 1), 5),
            "sky_pixel_fraction": round(self.sky_pixels / max(self.pixels, 1), 5),
        }


@dataclass
class Frame:
    """One rendered view. `depth` is the distance along the optical axis to the surface
    point each pixel shows (inf for sky), `hit` those points in the local frame."""

    image: np.ndarray
    depth: np.ndarray | None = None
    hit: np.ndarray | None = None


class HeightFieldRenderer:
    """Renders views of one DSM + orthoimage pair with one camera."""

    def __init__(
        self,
        dsm: np.ndarray,
        grid: Grid,
        ortho: np.ndarray,
        camera: CameraModel,
        options: RenderOptions | None = None,
        noise_seed: int = 0,
    ) -> None:
        if dsm.shape != grid.shape:
            raise ValueError(f"DSM shape {dsm.shape} does not match grid {grid.shape}")
        if max(dsm.shape) >= 32767 or max(ortho.shape[:2]) >= 32767:
            raise ValueError("rasters wider than 32766 cells cannot be rendered")
        self.options = options or RenderOptions()
        self.grid = grid
        self.camera = camera
        # The camera the passes draw with: the output camera, grown by the margin for
        # rolling-shutter frames.
        margin = self.options.rolling_shutter_margin_px
        self._view = padded_camera(camera, margin) if margin > 0 else camera
        if margin > 0 and camera.has_distortion:
            raise ValueError("rolling-shutter frames are drawn without lens distortion")
        self.dsm = np.ascontiguousarray(dsm, dtype=np.float32)
        self.zmin = float(self.dsm.min())
        self.zmax = float(self.dsm.max())
        # Block extremes to bound the heights inside a view cheaply.
        b = 32
        hb, wb = -(-grid.height // b), -(-grid.width // b)
        padded = np.pad(
            self.dsm, ((0, hb * b - grid.height), (0, wb * b - grid.width)), mode="edge"
        )
        blocks = padded.reshape(hb, b, wb, b)
        self._block = b
        self._bmax = blocks.max(axis=(1, 3))
        self._bmin = blocks.min(axis=(1, 3))
        # Max-map of 4 x 4 cell blocks, dilated by one block, for conservative marching.
        h4, w4 = -(-grid.height // 4), -(-grid.width // 4)
        p4 = np.pad(self.dsm, ((0, h4 * 4 - grid.height), (0, w4 * 4 - grid.width)), mode="edge")
        # (Pairwise maxima of strided slices: a reduction over axes (1, 3) of the 4-D
        # view is several times slower.)
        r4 = np.maximum(np.maximum(p4[0::4], p4[1::4]), np.maximum(p4[2::4], p4[3::4]))
        m4 = np.maximum(np.maximum(r4[:, 0::4], r4[:, 1::4]), np.maximum(r4[:, 2::4], r4[:, 3::4]))
        k3 = np.ones((3, 3), np.uint8)
        rep = cv2.BORDER_REPLICATE
        self._max4 = cv2.dilate(m4, k3, borderType=rep)
        self._min_nb = cv2.erode(self.dsm, k3, borderType=rep)
        # Direction (east, north) towards the lowest of the 8 neighbours: a steep side
        # faces that way, and is only seen from that side.
        pad = np.pad(self.dsm, 1, mode="edge")
        hh, ww = self.dsm.shape
        # The first strictly lowest neighbour in this order wins; its index is kept
        # with masked copies (boolean-index assignment is much slower) and mapped to
        # (east, north) at the end.
        offsets = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc]
        best = pad[:hh, :ww].copy()
        which = np.zeros(self.dsm.shape, np.int8)
        for k, (dr, dc) in enumerate(offsets[1:], start=1):
            nb = pad[1 + dr : 1 + dr + hh, 1 + dc : 1 + dc + ww]
            np.copyto(which, np.int8(k), where=nb < best)
            np.minimum(best, nb, out=best)
        self._face_e = np.array([dc for _, dc in offsets], np.int8)[which]
        self._face_n = np.array([-dr for dr, _ in offsets], np.int8)[which]
        # Steep sides (crown walls, scarps) carry no texture of their own in an
        # orthoimage: they get a procedural texture varying with height, and are darker.
        ex = np.abs(np.diff(self.dsm, axis=1, append=self.dsm[:, -1:]))
        ey = np.abs(np.diff(self.dsm, axis=0, append=self.dsm[-1:, :]))
        slope = np.maximum(ex, ey) / np.float32(grid.res)
        self._steep = np.clip((slope - 2.0) / 3.0, 0.0, 1.0).astype(np.float32)
        self._side_noise = cv2.GaussianBlur(
            np.random.default_rng(12345).random((256, 256)).astype(np.float32), (0, 0), 1.0
        )
        self._side_noise = (self._side_noise - self._side_noise.mean()) / self._side_noise.std()
        self._max1 = cv2.dilate(self.dsm, k3, borderType=rep)
        # Block-major copies of what the splat reads (b x b cells contiguous per block):
        # a visible block is then copied whole instead of gathered cell by cell. Cells
        # past the DSM edge are NaN, so their projections fail the near-plane test.
        self._blk_z = _blocked(self.dsm, hb, wb, b, np.nan)
        self._blk_zl = _blocked(self._min_nb, hb, wb, b, np.nan)
        self._blk_fe = _blocked(self._face_e, hb, wb, b, 0)
        self._blk_fn = _blocked(self._face_n, hb, wb, b, 0)
        # Cell-centre coordinates per block column / row (same arithmetic as per cell).
        self._blk_x = (grid.x_left + (np.arange(wb * b) + 0.5) * grid.res).reshape(wb, b)
        self._blk_y = (grid.y_top - (np.arange(hb * b) + 0.5) * grid.res).reshape(hb, b)
        # Orthoimage pyramid (mip-map); level 0 may be finer than the DSM.
        self.ortho_factor = ortho.shape[1] / grid.width
        if abs(ortho.shape[0] / grid.height - self.ortho_factor) > 1e-9:
            raise ValueError("the orthoimage must cover the DSM extent exactly")
        levels = [np.ascontiguousarray(ortho)]
        while min(levels[-1].shape[:2]) > 16 and len(levels) < 10:
            levels.append(cv2.pyrDown(levels[-1]))
        self._pyramid = levels
        self._ortho_res = grid.res / self.ortho_factor
        # Per-camera constants.
        rays = self._view.pixel_rays().reshape(-1, 3)
        self._ray_x = np.ascontiguousarray(rays[:, 0])
        self._ray_y = np.ascontiguousarray(rays[:, 1])
        h, w = camera.height, camera.width
        u, v = np.meshgrid(np.arange(w), np.arange(h))
        rr = ((u - camera.cx) / (w / 2)) ** 2 + ((v - camera.cy) / (w / 2)) ** 2
        vig = 1.0 - self.options.vignetting * np.clip(rr / 1.3125, 0, 1.5) ** 1.5
        self._vignette = vig.astype(np.float32)[..., None]
        # Vignetting x exposure spelled out per channel: a (h, w, 1) factor broadcast
        # over 3 channels runs numpy's slow short inner loop.
        self._vig_cache: tuple[float, np.ndarray] | None = None
        rng = np.random.default_rng(noise_seed)
        if self.options.noise_sigma > 0:
            self._noise = rng.normal(0, self.options.noise_sigma, (4, h, w, 3)).astype(np.float32)
        else:
            self._noise = None
        self._kernel = np.ones((3, 3), np.uint8)
        self._wide_kernel = np.ones((9, 9), np.uint8)
        self._col_lim = (np.float32(-grid.width + 1), np.float32(2 * grid.width - 2))
        self._row_lim = (np.float32(-grid.height + 1), np.float32(2 * grid.height - 2))
        self.stats = RenderStats()

    # -- geometry helpers -------------------------------------------------------------
    def _world_rays(self, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World directions (east, north, up components, each (n,)) of all pixel rays
        for rotation r (camera z = 1). Separate contiguous arrays: writing strided
        columns of an (n, 3) array cost more than the arithmetic."""
        rf = r.astype(np.float32)
        out = []
        for k in range(3):
            dk = self._ray_x * rf[k, 0]
            dk += self._ray_y * rf[k, 1]
            dk += rf[k, 2]
            out.append(dk)
        return out[0], out[1], out[2]

    def _ray_setup(self, c: np.ndarray, d: tuple[np.ndarray, np.ndarray, np.ndarray]):
        """Ray origins and directions in DSM pixel units (col, row) and metres (z)."""
        g = self.grid
        c_cr = np.array(
            [(c[0] - g.x_left) / g.res - 0.5, (g.y_top - c[1]) / g.res - 0.5, c[2]], np.float32
        )
        inv = np.float32(1.0 / g.res)
        d_cr = (d[0] * inv, d[1] * -inv, d[2])
        return c_cr, d_cr

    def _gap(self, c_cr, d_cr, tau: np.ndarray, shape: tuple | None = None) -> np.ndarray:
        """Height above the surface of the ray points at parameter tau (rays given in
        pixel units by `_ray_setup`). Outside the DSM the surface is mirrored, up to
        one DSM size away, and flat beyond. `shape` reshapes the samples for remap."""
        dc, dr, dz = d_cr
        col = tau * dc
        col += c_cr[0]
        row = tau * dr
        row += c_cr[1]
        np.clip(col, self._col_lim[0], self._col_lim[1], out=col)
        np.clip(row, self._row_lim[0], self._row_lim[1], out=row)
        if shape is not None:
            hgt = sample_bilinear(self.dsm, col.reshape(shape), row.reshape(shape)).ravel()
        else:
            hgt = sample_bilinear(self.dsm, col, row)
        z = tau * dz
        z += c_cr[2]
        z -= hgt
        return z

    def _view_box(self, c: np.ndarray, d: tuple, zlo: float, zhi: float):
        """Row/col slices of the DSM that the frustum can see between heights zlo..zhi."""
        g = self.grid
        h, w = self._view.height, self._view.width
        border = np.concatenate(
            [
                np.arange(0, w, 16),
                (h - 1) * w + np.arange(0, w, 16),
                np.arange(0, h, 16) * w,
                np.arange(0, h, 16) * w + (w - 1),
                [h * w - 1],
            ]
        )
        db = np.stack([d[0][border], d[1][border], d[2][border]], axis=1)
        if np.any(db[:, 2] > -1e-3):
            return slice(0, g.height), slice(0, g.width)
        pts = []
        for z in (zlo, zhi):
            t = (z - c[2]) / db[:, 2]
            t = np.maximum(t, 0.0)
            pts.append(c[:2] + t[:, None] * db[:, :2])
        p = np.concatenate(pts)
        m = 2 * g.res
        return g.window(p[:, 0].min() - m, p[:, 1].min() - m, p[:, 0].max() + m, p[:, 1].max() + m)

    def _box_heights(self, rows: slice, cols: slice) -> tuple[float, float]:
        b = self._block
        br = slice(rows.start // b, -(-rows.stop // b))
        bc = slice(cols.start // b, -(-cols.stop // b))
        bmax = self._bmax[br, bc]
        if bmax.size == 0:
            return self.zmin, self.zmax
        return float(self._bmin[br, bc].min()), float(bmax.max())

    # -- rendering ----------------------------------------------------------------------
    def render(
        self,
        position: np.ndarray,
        r_wc: np.ndarray,
        *,
        frame_index: int = 0,
        exposure: float = 1.0,
        with_geometry: bool = False,
    ) -> Frame:
        """Render the view from `position` (local x, y, z) with rotation `r_wc`; for a
        rolling-shutter frame (with a margin in the options), `position` (3, 3) and
        `r_wc` (3, 3, 3) hold the poses at mid readout, first row and last row, and the
        geometry (`with_geometry`) is that of the mid-readout view."""
        t0 = time.perf_counter()
        c0 = time.process_time()
        opt = self.options
        cam = self._view
        g = self.grid
        h, w = cam.height, cam.width
        c = np.asarray(position, dtype=np.float64)
        r = np.asarray(r_wc, dtype=np.float64)
        readout = None
        if c.ndim == 2:
            if opt.rolling_shutter_margin_px <= 0:
                raise ValueError(
                    "rolling-shutter poses need RenderOptions.rolling_shutter_margin_px"
                )
            readout = ((c[1], r[1]), (c[2], r[2]))
            c, r = c[0], r[0]
        d = self._world_rays(r)  # world directions, scaled to camera z = 1
        c_cr, d_cr = self._ray_setup(c, d)

        # View box and local height range (twice: the second pass uses local extremes).
        rows, cols = self._view_box(c, d, self.zmin, self.zmax)
        zlo, zhi = self._box_heights(rows, cols)
        rows, cols = self._view_box(c, d, zlo, zhi)
        zlo, zhi = self._box_heights(rows, cols)

        # Pass 1: splat the DSM cells in view into a depth buffer.
        down = -d[2]
        zbuf = np.full(h * w, np.inf, np.float32)
        stride = 1
        if rows.stop > rows.start and cols.stop > cols.start:
            stride = self._splat(zbuf, c, r, rows, cols)
        zb = zbuf.reshape(h, w)
        lo = cv2.erode(zb, self._kernel).ravel()

        # Pass 2: exact intersection of every pixel ray with the interpolated surface.
        # The bracket is centred on the nearest splat of the 3x3 neighbourhood: a ray
        # that passes in front of it (silhouette) is marched on from there, so the
        # first crossing is always the one found.
        n = h * w
        have = lo < 1e30  # erode pads with FLT_MAX, not inf
        margin = np.float32((2.0 * stride + 2.0) * g.res) / np.maximum(down, np.float32(0.05))
        a = np.where(have, np.maximum(lo - margin, np.float32(opt.near_m)), np.float32(opt.near_m))
        b = np.where(have, lo + margin, np.float32(opt.near_m))
        fa = self._gap(c_cr, d_cr, a, (h, w))
        fb = self._gap(c_cr, d_cr, b, (h, w))
        good = have & (fa > 0) & (fb <= 0)
        simple = good.copy()  # tight bracket around the nearest splat: secant is enough
        # Near a depth discontinuity a steep wall (crown side) may cross the ray before
        # the nearest splat: march those rays from the nearest depth around them.
        wide = cv2.erode(zb, self._wide_kernel).ravel()
        wall = have & (wide < lo - 2 * margin)
        # Rays under the surface at the start of their bracket show a steep side between
        # splats: step backwards with doubling steps until above it. Rays that pass in
        # front of the bracket, and what is left, are marched.
        fix = np.flatnonzero(have & ~good)
        if fix.size:
            self._expand(c_cr, d_cr, fix, a, b, fa, fb, margin, good)
        # Rays above the surface at both ends pass in front of the nearest splat (a
        # crown next to them): probe densely from there to beyond their own splat.
        both = np.flatnonzero(have & ~good & (fa > 0) & (fb > 0))
        if both.size:
            own = zb.ravel()[both]
            b_far = np.where(np.isfinite(own), np.maximum(own + margin[both], b[both]), b[both])
            self._probe(c_cr, d_cr, both, a, b, b_far, fa, fb, good, k=24)
            left = both[~good[both]]
            b[left] = b_far[~good[both]]
        march_idx = np.flatnonzero(~good)
        if march_idx.size:
            start = np.where(have & (fa > 0) & ~wall, b, np.float32(-1.0))[march_idx]
            # Without a usable start, begin just before the nearest splat around.
            need = np.flatnonzero(start < 0)
            if need.size:
                ui = march_idx[need]
                wd = wide[ui]
                ok = wd < 1e30
                a2 = np.where(ok, np.maximum(wd - 2 * margin[ui], np.float32(opt.near_m)), 1.0)
                f2 = self._gap(c_cr, tuple(x[ui] for x in d_cr), a2)
                start[need] = np.where(ok & (f2 > 0), a2, np.float32(-1.0))
            m_idx, ma, mb, mfa, mfb = self._march(c_cr, d_cr, d, march_idx, start, zhi)
            a[m_idx], b[m_idx], fa[m_idx], fb[m_idx] = ma, mb, mfa, mfb
            good[m_idx] = True
            self.stats.marched_rays += int(march_idx.size)
        a[~good] = b[~good] = np.float32(opt.near_m)
        fa[~good], fb[~good] = 1.0, -1.0
        tau, f_end, moved = self._refine(c_cr, d_cr, a, b, fa, fb, (h, w))
        # The gap at the final tau: known already where the last step left tau as it
        # was (most rays), computed for the others (samples do not depend on layout).
        mv = np.flatnonzero(moved)
        if mv.size:
            f_end[mv] = self._gap(c_cr, tuple(x[mv] for x in d_cr), tau[mv])
        # Where the secant has not converged (steep or folded surface in the bracket),
        # and for the marched rays, use the bracketing method.
        converged = np.abs(f_end) < np.float32(0.05 * g.res)
        careful = np.flatnonzero(good & ~(simple & converged))
        if careful.size:
            tau[careful] = self._illinois(
                c_cr,
                tuple(x[careful] for x in d_cr),
                a[careful],
                b[careful],
                fa[careful],
                fb[careful],
            )
        tau[~good] = np.inf

        # Pass 3: shade from the orthoimage pyramid.
        hitmask = np.isfinite(tau)
        t_hit = np.where(hitmask, tau, 0.0).astype(np.float32)
        f = np.float32(g.res / self._ortho_res)
        col = ((c_cr[0] + 0.5) + t_hit * d_cr[0]) * f - 0.5
        row = ((c_cr[1] + 0.5) + t_hit * d_cr[1]) * f - 0.5
        np.clip(col, -self._pyramid[0].shape[1] + 1, 2 * self._pyramid[0].shape[1] - 2, out=col)
        np.clip(row, -self._pyramid[0].shape[0] + 1, 2 * self._pyramid[0].shape[0] - 2, out=row)
        lod = np.log2(np.maximum(t_hit * np.float32(1.0 / (cam.fx * self._ortho_res)), 1.0))
        lod = np.minimum(lod, len(self._pyramid) - 1).reshape(h, w)
        col = col.reshape(h, w)
        row = row.reshape(h, w)
        l_lo = int(np.floor(lod.min()))
        l_hi = min(int(np.ceil(lod.max())), len(self._pyramid) - 1)
        if l_lo == l_hi:
            rgb = sample_bilinear(self._pyramid[l_lo], *self._level_coords(col, row, l_lo))
        else:
            rgb = np.zeros((h, w, 3), np.float32)
            for lev in range(l_lo, l_hi + 1):
                wgt = np.maximum(0.0, 1.0 - np.abs(lod - lev))
                if not np.any(wgt > 0):
                    continue
                smp = sample_bilinear(self._pyramid[lev], *self._level_coords(col, row, lev))
                rgb += smp * wgt[..., None]
        if self.options.side_texture:
            # Height along the ray at the hit, and position across it, index the noise.
            steep = sample_bilinear(
                self._steep,
                ((c_cr[0]) + t_hit * d_cr[0]).reshape(h, w),
                ((c_cr[1]) + t_hit * d_cr[1]).reshape(h, w),
            )
            # Only the (few) pixels on steep sides: elsewhere the factor is exactly 1.
            sp = np.flatnonzero(steep.ravel() > 0)
            if sp.size:
                st = steep.ravel()[sp]
                zh = np.float32(c[2]) + t_hit[sp] * d_cr[2][sp]
                hx = (col.ravel()[sp] + row.ravel()[sp]).astype(np.float32) * np.float32(
                    self._ortho_res * 2.0
                )
                nz = sample_bilinear(
                    self._side_noise, np.mod(hx, 255.0), np.mod(zh * np.float32(3.0), 255.0)
                )
                f = 1.0 - 0.3 * st + 0.3 * st * np.clip(nz, -2.0, 2.0)
                flat = rgb.reshape(n, 3)
                flat[sp] *= f[:, None]
        sky = ~hitmask.reshape(h, w)
        if sky.any():
            rgb[sky] = SKY_RGB
            self.stats.sky_pixels += int(sky.sum())
        out = self.camera
        m = opt.rolling_shutter_margin_px
        if readout is not None:
            rows = row_poses(*readout, out.height)
            rgb = warp_rows(rgb, tau.reshape(h, w), cam, (c, r), rows, out, SKY_RGB)
        elif m > 0:
            rgb = np.ascontiguousarray(rgb[m : m + out.height, m : m + out.width])
        rgb *= self._vignette_for(exposure)
        if self._noise is not None:
            rgb += self._noise[frame_index % len(self._noise)]
        rgb += 0.5
        np.clip(rgb, 0, 255, out=rgb)
        image = rgb.astype(np.uint8)

        self.stats.frames += 1
        self.stats.pixels += n
        self.stats.seconds += time.perf_counter() - t0
        self.stats.cpu_seconds += time.process_time() - c0
        if not with_geometry:
            return Frame(image=image)
        t64 = t_hit.astype(np.float64)
        dd = np.stack(d, axis=1).astype(np.float64)
        hit = (c[None, :] + t64[:, None] * dd).reshape(h, w, 3)
        hit[sky] = np.nan
        inner = (slice(m, m + out.height), slice(m, m + out.width))
        return Frame(image=image, depth=tau.reshape(h, w)[inner], hit=hit[inner])

    def _vignette_for(self, exposure: float) -> np.ndarray:
        """Vignetting x exposure as an (h, w, 3) factor, kept for the survey's exposure."""
        if self._vig_cache is None or self._vig_cache[0] != exposure:
            f = self._vignette * np.float32(exposure)
            self._vig_cache = (exposure, np.ascontiguousarray(np.repeat(f, 3, axis=2)))
        return self._vig_cache[1]

    @staticmethod
    def _level_coords(col: np.ndarray, row: np.ndarray, level: int):
        if level == 0:
            return col, row
        s = np.float32(1.0 / 2**level)
        return (col + 0.5) * s - 0.5, (row + 0.5) * s - 0.5

    def _splat(self, zbuf, c, r, rows: slice, cols: slice) -> int:
        """Project DSM samples into the depth buffer. The DSM is split into blocks; each
        block visible in the frustum is sampled every `stride` cells, or `upsample`
        times per cell (bilinear), so that neighbouring samples land at most
        `splat_spacing_px` apart where the block is closest. Returns the largest stride."""
        opt = self.options
        cam = self._view
        g = self.grid
        h, w = cam.height, cam.width
        b = self._block
        bi = np.arange(rows.start // b, -(-rows.stop // b))
        bj = np.arange(cols.start // b, -(-cols.stop // b))
        gi, gj = np.meshgrid(bi, bj, indexing="ij")
        gi, gj = gi.ravel(), gj.ravel()
        zlo = self._bmin[gi, gj].astype(np.float64)
        zhi = self._bmax[gi, gj].astype(np.float64)
        # Camera coordinates of the 8 corners of every block's bounding box.
        x0 = g.x_left + gj * b * g.res - c[0]
        x1 = np.minimum(x0 + b * g.res, g.x_right - c[0])
        y0 = g.y_top - gi * b * g.res - c[1]
        y1 = np.maximum(y0 - b * g.res, g.y_bottom - c[1])
        cx = np.stack([x0, x1, x0, x1, x0, x1, x0, x1], axis=1)
        cy = np.stack([y0, y0, y1, y1, y0, y0, y1, y1], axis=1)
        cz = np.stack([zlo, zlo, zlo, zlo, zhi, zhi, zhi, zhi], axis=1) - c[2]
        pc = [r[0, k] * cx + r[1, k] * cy + r[2, k] * cz for k in range(3)]
        zc = pc[2]
        front = zc > opt.near_m
        visible = front.any(axis=1)
        # Cull blocks whose corners all lie beyond one side of the image.
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.where(front, cam.fx * pc[0] / zc + cam.cx, np.nan)
            v = np.where(front, cam.fy * pc[1] / zc + cam.cy, np.nan)
        all_front = front.all(axis=1)
        slack = 0.15 * w  # distortion and bilinear bulges
        off = (
            (np.nanmax(u, axis=1) < -slack)
            | (np.nanmin(u, axis=1) > w + slack)
            | (np.nanmax(v, axis=1) < -slack)
            | (np.nanmin(v, axis=1) > h + slack)
        )
        visible &= ~(all_front & off)
        zmin_c = np.where(front, zc, np.inf).min(axis=1)
        near_depth = np.where(all_front, zmin_c, opt.near_m)
        px_per_cell = cam.fx * g.res / np.maximum(near_depth, opt.near_m)
        stride = np.where(
            px_per_cell <= opt.splat_spacing_px,
            np.clip(np.floor(opt.splat_spacing_px / px_per_cell), 1, b),
            1,
        ).astype(int)
        up = np.where(
            px_per_cell > opt.splat_spacing_px,
            np.clip(np.ceil(px_per_cell / opt.splat_spacing_px), 1, 4),
            1,
        ).astype(int)
        xs_all, ys_all, zs_all, zl_all, fe_all, fn_all = [], [], [], [], [], []
        cz32 = np.float32(c[2])
        for s_val, u_val in sorted(set(zip(stride[visible], up[visible], strict=True))):
            sel = visible & (stride == s_val) & (up == u_val)
            bi_s, bj_s = gi[sel], gj[sel]
            if u_val == 1:
                # Every s-th cell of whole blocks, read from the block-major copies
                # (cells past the DSM edge are NaN and fail the near-plane test below).
                nb = bi_s.size
                m = -(-b // s_val)
                shape3 = (nb, m, m)
                zs_all.append((self._blk_z[bi_s, bj_s][:, ::s_val, ::s_val] - cz32).ravel())
                zl_all.append((self._blk_zl[bi_s, bj_s][:, ::s_val, ::s_val] - cz32).ravel())
                fe_all.append(self._blk_fe[bi_s, bj_s][:, ::s_val, ::s_val].ravel())
                fn_all.append(self._blk_fn[bi_s, bj_s][:, ::s_val, ::s_val].ravel())
                xb = (self._blk_x[bj_s][:, ::s_val] - c[0]).astype(np.float32)
                yb = (self._blk_y[bi_s][:, ::s_val] - c[1]).astype(np.float32)
                xs_all.append(np.broadcast_to(xb[:, None, :], shape3).ravel())
                ys_all.append(np.broadcast_to(yb[:, :, None], shape3).ravel())
                continue
            offs = (np.arange(b * u_val) + 0.5) / u_val - 0.5
            rr = (bi_s * b)[:, None, None] + offs[None, :, None]
            cc = (bj_s * b)[:, None, None] + offs[None, None, :]
            rr, cc = np.broadcast_arrays(rr, cc)
            rr, cc = rr.ravel(), cc.ravel()
            ok = (rr > -0.5) & (rr < g.height - 0.5) & (cc > -0.5) & (cc < g.width - 0.5)
            rr, cc = rr[ok], cc[ok]
            zs = sample_bilinear(self.dsm, cc, rr)
            zl = sample_bilinear(self._min_nb, cc, rr)
            ri_ = np.clip(np.rint(rr), 0, g.height - 1).astype(np.intp)
            ci_ = np.clip(np.rint(cc), 0, g.width - 1).astype(np.intp)
            fe_all.append(self._face_e[ri_, ci_])
            fn_all.append(self._face_n[ri_, ci_])
            xs_all.append((g.x_left + (cc + 0.5) * g.res - c[0]).astype(np.float32))
            ys_all.append((g.y_top - (rr + 0.5) * g.res - c[1]).astype(np.float32))
            zs_all.append(zs.astype(np.float32) - cz32)
            zl_all.append(zl.astype(np.float32) - cz32)
        if not xs_all:
            return 1
        xs = np.concatenate(xs_all)
        ys = np.concatenate(ys_all)
        dz = np.concatenate(zs_all)
        rf = r.astype(np.float32)
        zc = rf[0, 2] * xs + rf[1, 2] * ys + rf[2, 2] * dz
        # Samples behind the near plane (or past the DSM edge: NaN) are not dropped
        # here but masked at the end: filtering seven arrays cost more than projecting
        # the few extra points.
        ok = zc > opt.near_m
        with np.errstate(all="ignore"):
            xc = rf[0, 0] * xs + rf[1, 0] * ys + rf[2, 0] * dz
            yc = rf[0, 1] * xs + rf[1, 1] * ys + rf[2, 1] * dz
            u, v = self._to_pixels(xc, yc, zc)
            # Steep sides (crown walls, scarps) fall between samples: splat each sample
            # as the vertical column below it, down to its lowest neighbour, at about
            # one sample per pixel of the column's projected length. The column lies
            # inside the solid, so its depths never hide a surface that is in front.
            drop = dz - np.concatenate(zl_all)
            # (xs, ys are sample minus camera: the side is seen if the camera lies on
            # the side of the lowest neighbour.)
            cand = np.flatnonzero((drop > 2.0 * g.res) & ok)
            fe = np.concatenate(fe_all)[cand]
            fn = np.concatenate(fn_all)[cand]
            steep = cand[(fe * xs[cand] + fn * ys[cand]) < 0]
            iu = np.floor(u + 0.5).astype(np.int32)
            iv = np.floor(v + 0.5).astype(np.int32)
        inside = ok & (iu >= 0) & (iu < w) & (iv >= 0) & (iv < h)
        pix = iv[inside] * w + iu[inside]
        depth = zc[inside]
        if steep.size:
            xb = xc[steep] - rf[2, 0] * drop[steep]
            yb = yc[steep] - rf[2, 1] * drop[steep]
            zb = zc[steep] - rf[2, 2] * drop[steep]
            okb = zb > opt.near_m
            steep, xb, yb, zb = steep[okb], xb[okb], yb[okb], zb[okb]
            ub, vb = self._to_pixels(xb, yb, zb)
            length = np.hypot(u[steep] - ub, v[steep] - vb)
            n = np.clip(np.floor(length / opt.column_spacing_px), 0, 64).astype(np.int64)
            total = int(n.sum())
            if total > 0:
                rep = np.repeat(np.arange(steep.size), n)
                start = np.cumsum(n) - n
                k = np.arange(total) - np.repeat(start, n)
                frac = ((k + 1) / np.repeat(n, n)).astype(np.float32)
                s_idx = steep[rep]
                xcol = xc[s_idx] + (xb[rep] - xc[s_idx]) * frac
                ycol = yc[s_idx] + (yb[rep] - yc[s_idx]) * frac
                zcol = zc[s_idx] + (zb[rep] - zc[s_idx]) * frac
                ucol, vcol = self._to_pixels(xcol, ycol, zcol)
                iuc = np.floor(ucol + 0.5).astype(np.int32)
                ivc = np.floor(vcol + 0.5).astype(np.int32)
                inc = (iuc >= 0) & (iuc < w) & (ivc >= 0) & (ivc < h)
                pix = np.concatenate([pix, ivc[inc] * w + iuc[inc]])
                depth = np.concatenate([depth, zcol[inc]])
                self.stats.extra["last_column_points"] = total
        np.minimum.at(zbuf, pix, depth)
        self.stats.extra["last_splat_points"] = int(np.count_nonzero(ok))
        return int(stride[visible].max()) if visible.any() else 1

    def _probe(self, c_cr, d_cr, idx, a, b, b_end, fa, fb, good, k: int = 24) -> None:
        """Look for the first crossing at k points in (a, b_end] of rays `idx` whose
        bracket start is above the surface; close their brackets on it (in place)."""
        ai = a[idx]
        frac = (np.arange(1, k + 1, dtype=np.float32) / k)[None, :]
        tt = ai[:, None] + (b_end - ai)[:, None] * frac
        ff = self._gap(c_cr, tuple(np.repeat(x[idx], k) for x in d_cr), tt.ravel()).reshape(
            idx.size, k
        )
        below = ff <= 0
        hit = below.any(axis=1)
        if not hit.any():
            return
        first = np.argmax(below, axis=1)
        rows = np.arange(idx.size)
        prev_t = np.where(first > 0, tt[rows, first - 1], ai)
        prev_f = np.where(first > 0, ff[rows, first - 1], fa[idx])
        sel = idx[hit]
        a[sel] = prev_t[hit]
        fa[sel] = prev_f[hit]
        b[sel] = tt[rows, first][hit]
        fb[sel] = ff[rows, first][hit]
        good[sel] = True

    def _expand(self, c_cr, d_cr, idx, a, b, fa, fb, margin, good, steps: int = 6) -> None:
        """Grow failed brackets in place (see `render`), marking those that now hold a
        crossing as good."""
        near = np.float32(self.options.near_m)
        di = tuple(x[idx] for x in d_cr)
        ai, bi, fai, fbi = a[idx], b[idx], fa[idx], fb[idx]
        step = margin[idx].copy()
        back = fai <= 0
        fwd = np.zeros_like(back)
        for _ in range(steps):
            todo = back | fwd
            if not todo.any():
                break
            t_new = np.where(back, np.maximum(ai - step, near), bi + step)
            sel = np.flatnonzero(todo)
            f_new = self._gap(c_cr, tuple(x[sel] for x in di), t_new[sel])
            fn = np.zeros_like(fai)
            fn[sel] = f_new
            # Backwards: new point above the surface closes [t_new, a].
            hit_b = back & (fn > 0)
            bi = np.where(hit_b, ai, bi)
            fbi = np.where(hit_b, fai, fbi)
            ai = np.where(back, t_new, ai)
            fai = np.where(back, fn, fai)
            stuck = back & ~hit_b & (t_new <= near)
            back = back & ~hit_b & ~stuck
            # Forwards: new point under the surface closes [b, t_new].
            hit_f = fwd & (fn <= 0)
            ai = np.where(fwd, bi, ai)
            fai = np.where(fwd, fbi, fai)
            bi = np.where(fwd, t_new, bi)
            fbi = np.where(fwd, fn, fbi)
            fwd = fwd & ~hit_f
            step = step * 2
        ok = (fai > 0) & (fbi <= 0)
        a[idx], b[idx], fa[idx], fb[idx] = ai, bi, fai, fbi
        good[idx[ok]] = True

    def _to_pixels(self, xc, yc, zc):
        cam = self._view
        inv = 1.0 / zc
        xn = xc * inv
        yn = yc * inv
        if cam.has_distortion:
            xn, yn = cam.distort_normalized(xn, yn)
        return cam.fx * xn + np.float32(cam.cx), cam.fy * yn + np.float32(cam.cy)

    def _march(self, c_cr, d_cr, d, idx, start, zhi):
        """March rays `idx` from `start` (where start < 0: from above the highest terrain
        in view, `zhi`, or in the whole DSM) to their first crossing of the surface;
        returns the brackets of the rays that have one.

        Conservative stepping on two max-maps (4 x 4 cell blocks dilated by one block,
        and cells dilated by one cell): a ray above the local maximum descends to it in
        one step, never moving sideways more than the map's reach; below both it drops
        by its height above the surface, moving at most half a cell sideways, and checks
        for a crossing. The last few rays (grazing along steep crown sides) test many
        such steps per iteration. Only features thinner than half a cell are missed."""
        opt = self.options
        g = self.grid
        near = np.float32(opt.near_m)
        dc, dr, dz = (x[idx] for x in d_cr)
        down = -dz
        hcell = np.sqrt(dc * dc + dr * dr)  # cells per unit of tau
        zc = np.float32(c_cr[2])

        def top_at(z):
            t = np.where(down > 1e-6, (zc - z - 1e-3) / np.maximum(down, 1e-6), near)
            return np.maximum(t, near).astype(np.float32)

        tau = np.where(start >= 0, start, top_at(zhi)).astype(np.float32)
        f = self._gap(c_cr, (dc, dr, dz), tau)
        retry = f <= 0
        if retry.any():
            tau[retry] = top_at(self.zmax)[retry]
            f[retry] = self._gap(c_cr, (dc[retry], dr[retry], dz[retry]), tau[retry])
        act = np.flatnonzero(f > 0)  # rays starting under the surface show nothing
        t_act, f_act = tau[act], f[act]
        mx = self._max4
        outside_max = np.float32(self.zmax)
        inv_down = np.where(down > 1e-6, 1.0 / np.maximum(down, 1e-6), np.inf).astype(np.float32)
        cap4 = np.where(hcell > 1e-9, 2.999 / np.maximum(hcell, 1e-9), np.inf).astype(np.float32)
        cap1 = np.where(hcell > 1e-9, 0.499 / np.maximum(hcell, 1e-9), np.inf).astype(np.float32)
        tiny = np.float32(1e-3) * np.float32(g.res)
        tail, chunk = 2048, 64
        half_cell = np.float32(0.5 * g.res)
        far = np.float32(
            (abs(zc - self.zmin) + 10.0) * 50.0 + 3.0 * np.hypot(g.width, g.height) * g.res
        )
        outs: list[tuple] = []
        for _ in range(opt.march_iterations):
            if act.size == 0:
                break
            col = c_cr[0] + t_act * dc[act]
            row = c_cr[1] + t_act * dr[act]
            ci = np.floor(col + 0.5).astype(np.int64)
            ri = np.floor(row + 0.5).astype(np.int64)
            inside = (ri >= 0) & (ri < g.height) & (ci >= 0) & (ci < g.width)
            m4 = np.full(act.size, outside_max, np.float32)
            m1 = np.full(act.size, outside_max, np.float32)
            rin, cin = ri[inside], ci[inside]
            m4[inside] = mx[rin >> 2, cin >> 2]
            m1[inside] = self._max1[rin, cin]
            zr = zc + t_act * dz[act]
            idn = inv_down[act]
            # Safe steps: descend to a max-map level without leaving its reach; near
            # the surface, drop by the height above it, at most half a cell sideways.
            safe4 = np.where(zr > m4, np.minimum((zr - m4) * idn, cap4[act]), 0)
            safe1 = np.where(zr > m1, np.minimum((zr - m1) * idn, cap1[act]), 0)
            fine = np.minimum(np.float32(1.05) * f_act * idn, cap1[act])
            step = np.maximum(np.maximum(safe4, safe1), np.maximum(fine, tiny)).astype(np.float32)
            if act.size <= tail:
                # Few rays left (grazing along steep sides): test many fine steps at once.
                k = np.arange(1, chunk + 1, dtype=np.float32)
                dt = np.minimum(cap1[act], half_cell * idn).astype(np.float32)
                tt = t_act[:, None] + dt[:, None] * k[None, :]
                ff = self._gap(
                    c_cr,
                    tuple(np.repeat(x[act], chunk) for x in (dc, dr, dz)),
                    tt.ravel(),
                ).reshape(act.size, chunk)
                below = ff <= 0
                first = np.argmax(below, axis=1)
                hit = below[np.arange(act.size), first]
                ta = np.where(first > 0, tt[np.arange(act.size), first - 1], t_act)
                fa_ = np.where(first > 0, ff[np.arange(act.size), first - 1], f_act)
                tb = tt[np.arange(act.size), first]
                fb_ = ff[np.arange(act.size), first]
                if hit.any():
                    outs.append((act[hit], ta[hit], tb[hit], fa_[hit], fb_[hit]))
                t_last, f_last = tt[:, -1], ff[:, -1]
                keep = ~hit & (t_last < far)
                act, t_act, f_act = act[keep], t_last[keep], f_last[keep]
                continue
            t_new = t_act + step
            f_new = self._gap(c_cr, (dc[act], dr[act], dz[act]), t_new)
            crossed = f_new <= 0
            if crossed.any():
                outs.append(
                    (act[crossed], t_act[crossed], t_new[crossed], f_act[crossed], f_new[crossed])
                )
            keep = ~crossed & (t_new < far) & ~((down[act] <= 0) & (zr > self.zmax))
            act, t_act, f_act = act[keep], t_new[keep], f_new[keep]
        if not outs:
            e = np.zeros(0, np.float32)
            return np.zeros(0, np.int64), e, e, e, e
        sel, a, b, fa, fb = (np.concatenate(x) for x in zip(*outs, strict=True))
        return idx[sel], a, b, fa, fb

    def _illinois(self, c_cr, d_cr, a, b, fa, fb, iterations: int = 8):
        """Regula falsi with the Illinois modification: slower than `_refine` but it
        keeps a true bracket, so on wide brackets (marched rays, steep sides) it stays
        on the crossing the march found."""
        a, b, fa, fb = a.copy(), b.copy(), fa.copy(), fb.copy()
        prev_above = np.zeros(a.shape, bool)
        prev_below = np.zeros(a.shape, bool)
        half = np.float32(0.5)
        for _ in range(iterations):
            cm = self._secant(a, b, fa, fb)
            fc = self._gap(c_cr, d_cr, cm)
            above = fc > 0
            below = ~above
            np.multiply(fb, half, out=fb, where=above & prev_above)
            np.multiply(fa, half, out=fa, where=below & prev_below)
            np.copyto(a, cm, where=above)
            np.copyto(fa, fc, where=above)
            np.copyto(b, cm, where=below)
            np.copyto(fb, fc, where=below)
            prev_above, prev_below = above, below
        return self._secant(a, b, fa, fb)

    def _refine(self, c_cr, d_cr, a, b, fa, fb, shape=None):
        """The crossing inside brackets with fa > 0 >= fb: secant iterations on the last
        two points, kept inside the bracket (converges in 2-3 steps on the bilinear
        surface; the bracket makes it safe). Returns tau, the gap at the tau before the
        last step, and where that step moved tau (elsewhere the gap is the one at tau).
        """
        t_prev, f_prev = b, fb
        t = self._secant(a, b, fa, fb)
        f = np.full_like(t, np.nan)
        moved = np.ones(t.shape, bool)
        for _ in range(self.options.refine_iterations):
            f = self._gap(c_cr, d_cr, t, shape)
            denom = f - f_prev
            # Masked ufuncs (divide(where=...), clip with array bounds) are several
            # times slower than plain ones: divide everywhere, then zero the steps
            # with a vanishing denominator; clip as max then min (what clip does).
            with np.errstate(divide="ignore", invalid="ignore"):
                step = f * (t - t_prev)
                step /= denom
            step[np.abs(denom) <= 1e-9] = 0.0
            t_new = t - step
            np.maximum(t_new, a, out=t_new)
            np.minimum(t_new, b, out=t_new)
            moved = t_new != t
            t_prev, f_prev, t = t, f, t_new
        return t, f, moved

    @staticmethod
    def _secant(a, b, fa, fb):
        denom = fa - fb
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(denom > 0, fa / denom, np.float32(0.5))
        np.clip(t, 0.0, 1.0, out=t)
        return a + (b - a) * t
