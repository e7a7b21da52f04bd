"""Trees and shrubs as surface objects of the DSM.

A `Trees` set holds one row per plant (struct of arrays). Crowns are rasterised onto the
DSM grid as analytic shapes: conifers as slightly convex cones, broadleaves as
ellipsoid caps, shrubs as low ellipsoids, fallen trees as elongated half-ellipsoids
lying on the ground. The DSM is the maximum of the ground surface and every crown.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from worker.simulator.georef import Grid
from worker.simulator.texture import BROADLEAF, CONIFER, LOG, MODEL_TREE, SHRUB

KIND_NAMES = {
    CONIFER: "conifer",
    BROADLEAF: "broadleaf",
    SHRUB: "shrub",
    LOG: "fallen tree",
    MODEL_TREE: "model tree",
}


@dataclass
class Trees:
    """Plants of a scene. Positions are local metres; `z_base` is the ground height at
    the trunk when the plant was placed (or where a fallen tree came to rest)."""

    x: np.ndarray
    y: np.ndarray
    z_base: np.ndarray
    height: np.ndarray
    crown_radius: np.ndarray
    crown_depth: np.ndarray
    kind: np.ndarray
    azimuth: np.ndarray
    tone: np.ndarray
    ident: np.ndarray

    @classmethod
    def empty(cls) -> Trees:
        f = np.zeros(0)
        return cls(
            f,
            f,
            f,
            f,
            f,
            f,
            np.zeros(0, np.int8),
            f,
            np.zeros(0, np.float32),
            np.zeros(0, np.int64),
        )

    def __len__(self) -> int:
        return int(self.x.size)

    def copy(self) -> Trees:
        return Trees(**{f.name: getattr(self, f.name).copy() for f in fields(self)})

    def select(self, mask: np.ndarray) -> Trees:
        return Trees(**{f.name: getattr(self, f.name)[mask] for f in fields(self)})

    @staticmethod
    def concat(parts: list[Trees]) -> Trees:
        parts = [p for p in parts if len(p)]
        if not parts:
            return Trees.empty()
        return Trees(
            **{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(Trees)}
        )

    def counts(self) -> dict[str, int]:
        return {
            name: int((self.kind == k).sum())
            for k, name in KIND_NAMES.items()
            if (self.kind == k).any()
        }


def make_trees(
    x,
    y,
    ground_z,
    height,
    crown_radius,
    crown_depth,
    kind,
    rng: np.random.Generator,
    first_ident: int = 0,
    azimuth=None,
) -> Trees:
    """A tree set with random tones (colour variation) and sequential identities."""
    n = np.asarray(x).size
    return Trees(
        x=np.asarray(x, np.float64),
        y=np.asarray(y, np.float64),
        z_base=np.asarray(ground_z, np.float64),
        height=np.asarray(height, np.float64),
        crown_radius=np.asarray(crown_radius, np.float64),
        crown_depth=np.asarray(crown_depth, np.float64),
        kind=np.broadcast_to(np.asarray(kind, np.int8), (n,)).copy(),
        azimuth=np.zeros(n) if azimuth is None else np.asarray(azimuth, np.float64),
        tone=rng.normal(0.0, 0.09, n).astype(np.float32),
        ident=np.arange(first_ident, first_ident + n, dtype=np.int64),
    )


def jittered_positions(
    rng: np.random.Generator,
    x0: float,
    y0: float,
    x1: float,
    y1: float,
    spacing: float,
    jitter: float = 0.35,
) -> tuple[np.ndarray, np.ndarray]:
    """Plantation-like positions: a square lattice with random offsets."""
    xs = np.arange(x0 + spacing / 2, x1, spacing)
    ys = np.arange(y0 + spacing / 2, y1, spacing)
    gx, gy = np.meshgrid(xs, ys)
    gx = gx.ravel() + rng.uniform(-jitter, jitter, gx.size) * spacing
    gy = gy.ravel() + rng.uniform(-jitter, jitter, gy.size) * spacing
    return gx, gy


@dataclass
class Canopy:
    """Rasterised crowns: absolute top height (-inf where no crown), index of the
    plant on top (-1 where none) and normalised distance from its centre."""

    top: np.ndarray
    index: np.ndarray
    radial: np.ndarray


def rasterize(trees: Trees, grid: Grid) -> Canopy:
    """Rasterise every crown onto `grid` (cell centres)."""
    top = np.full(grid.shape, -np.inf, np.float64)
    index = np.full(grid.shape, -1, np.int32)
    radial = np.zeros(grid.shape, np.float32)
    res = grid.res
    for i in range(len(trees)):
        k = int(trees.kind[i])
        cx, cy = trees.x[i], trees.y[i]
        r = trees.crown_radius[i]
        if k == LOG:
            half_len = trees.height[i] / 2.0
            ext = max(half_len, r)
        else:
            ext = r
        rows, cols = grid.window(cx - ext, cy - ext, cx + ext, cy + ext)
        if rows.stop <= rows.start or cols.stop <= cols.start:
            continue
        xs = grid.x_left + (np.arange(cols.start, cols.stop) + 0.5) * res - cx
        ys = grid.y_top - (np.arange(rows.start, rows.stop) + 0.5) * res - cy
        dx = xs[None, :]
        dy = ys[:, None]
        zb = trees.z_base[i]
        h = trees.height[i]
        depth = trees.crown_depth[i]
        if k == LOG:
            az = np.radians(trees.azimuth[i])
            along = dx * np.sin(az) + dy * np.cos(az)
            across = dx * np.cos(az) - dy * np.sin(az)
            q = (along / half_len) ** 2 + (across / r) ** 2
            inside = q < 1.0
            z = zb + depth * np.sqrt(np.clip(1.0 - q, 0, None))
            rad = np.sqrt(np.clip(q, 0, 1))
        else:
            rho = np.sqrt(dx * dx + dy * dy) / r
            inside = rho < 1.0
            if k in (CONIFER, MODEL_TREE):
                z = zb + h - depth * rho**0.85
            elif k == BROADLEAF:
                z = zb + h - depth / 2.0 + depth / 2.0 * np.sqrt(np.clip(1 - rho * rho, 0, None))
            else:  # shrub
                z = zb + h * np.sqrt(np.clip(1 - rho * rho, 0, None))
            rad = rho
        tile = top[rows, cols]
        upd = inside & (z > tile)
        if not upd.any():
            continue
        tile[upd] = z[upd]
        index[rows, cols][upd] = i
        radial[rows, cols][upd] = rad[upd]
    return Canopy(top=top, index=index, radial=radial)


def grow(
    trees: Trees, rng: np.random.Generator, height_m: dict[int, float], crown_m: dict[int, float]
) -> Trees:
    """Vegetation growth between surveys: each kind grows by about the given height and
    crown radius increments (standing plants only; fallen trees do not grow)."""
    out = trees.copy()
    for k, dh in height_m.items():
        sel = out.kind == k
        n = int(sel.sum())
        if n == 0:
            continue
        gh = np.clip(rng.normal(dh, 0.3 * dh, n), 0, None)
        out.height[sel] += gh
        if k != SHRUB:
            out.crown_depth[sel] += 0.6 * gh
        dr = crown_m.get(k, 0.0)
        out.crown_radius[sel] += np.clip(rng.normal(dr, 0.3 * dr, n), 0, None)
    return out
