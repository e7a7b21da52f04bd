"""Seeded terrain at the two scales of the issue, and the scene state that evolves.

- `paper_mounds_scene`: the paper's experiment field, a ~20 m x 20 m sandy area with
  two sand mounds (A and B) about 1.5 m high, surrounded by short grass, with small
  model trees on and around the mounds and three checkpoint targets; 2 cm cells.
- `hillslope_scene`: a real-scale forested slope of a few hundred metres above a valley
  with a stream and a gravel road; gullies cut the slope; conifer plantation,
  broadleaves and shrubs are surface objects; 20 cm cells.

The `Scene` holds the bare-earth DEM (`ground`), a low-vegetation layer (`surface`,
grass height, part of the DSM but not of the DEM), materials and plants. The DSM is
max(ground + surface, crowns).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from worker.simulator.georef import Grid
from worker.simulator.texture import (
    BROADLEAF,
    CONIFER,
    MODEL_TREE,
    SHRUB,
    Material,
    fbm,
)
from worker.simulator.vegetation import Canopy, Trees, jittered_positions, make_trees, rasterize


@dataclass
class Scene:
    """The state of a simulated site at one step."""

    grid: Grid
    ground: np.ndarray
    surface: np.ndarray
    material: np.ndarray
    trees: Trees
    sand_like: np.ndarray
    floor: np.ndarray | None = None
    disturbed: np.ndarray | None = None
    features: dict = field(default_factory=dict)

    def copy(self) -> Scene:
        return Scene(
            grid=self.grid,
            ground=self.ground.copy(),
            surface=self.surface.copy(),
            material=self.material.copy(),
            trees=self.trees.copy(),
            sand_like=self.sand_like,
            floor=self.floor,
            disturbed=None if self.disturbed is None else self.disturbed.copy(),
            features=self.features,
        )

    def compose(self) -> tuple[np.ndarray, Canopy]:
        """The DSM (float32) and the rasterised crowns."""
        canopy = rasterize(self.trees, self.grid)
        low = self.ground + self.surface
        dsm = np.where(canopy.top > low, canopy.top, low).astype(np.float32)
        # Crowns hidden under a raised ground are not visible.
        canopy.index[canopy.top <= low] = -1
        return dsm, canopy

    def dem(self) -> np.ndarray:
        return self.ground.astype(np.float32)

    def height_at(self, x, y) -> np.ndarray:
        """Ground height (nearest cell) at local points."""
        col, row = self.grid.col_row(np.asarray(x), np.asarray(y))
        r = np.clip(np.rint(row).astype(int), 0, self.grid.height - 1)
        c = np.clip(np.rint(col).astype(int), 0, self.grid.width - 1)
        return self.ground[r, c]


def _smoothstep(t):
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3 - 2 * t)


# --------------------------------------------------------------------------------------
# paper-mounds


@dataclass(frozen=True)
class Mound:
    name: str
    center: tuple[float, float]
    height: float
    radii: tuple[float, float]
    rotation_deg: float
    collapse_azimuth_deg: float

    def radius_towards(self, azimuth_deg: float) -> float:
        """Distance from the centre to the foot of the mound in a direction."""
        a = np.radians(azimuth_deg - self.rotation_deg)
        ra, rb = self.radii
        # Ellipse semi-axis ra along the rotated east axis, rb along the rotated north.
        return float(1.0 / np.sqrt((np.sin(a) / ra) ** 2 + (np.cos(a) / rb) ** 2))

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "center_local": list(self.center),
            "height_m": self.height,
            "radii_m": list(self.radii),
            "rotation_deg": self.rotation_deg,
            "collapse_azimuth_deg": self.collapse_azimuth_deg,
        }


PAPER_MOUNDS = (
    Mound("A", (-3.6, 3.4), 1.50, (3.8, 3.3), 20.0, 250.0),
    Mound("B", (4.0, -2.2), 1.45, (3.5, 3.7), -15.0, 135.0),
)
PAPER_CHECKPOINTS = (("CP1", -8.0, -7.5), ("CP2", 8.2, 7.0), ("CP3", 0.5, 8.6))
PAPER_FIELD_HALF = 10.0


def paper_mounds_scene(
    rng: np.random.Generator, res: float = 0.02, size_m: float = 40.0, base_z: float = 25.0
) -> Scene:
    """The paper's field at one-tenth scale (see module docstring)."""
    grid = Grid.centered(size_m, size_m, res)
    x, y = grid.mesh()
    shape = grid.shape
    cells = 1.0 / res
    floor = (
        base_z
        + 0.004 * x
        - 0.002 * y
        + 0.02 * fbm(shape, rng, [6 * cells, 2 * cells], [0.7, 0.3])
        + 0.003 * fbm(shape, rng, [0.3 * cells, 0.08 * cells], [0.6, 0.4])
    )
    inside = (np.abs(x) <= PAPER_FIELD_HALF) & (np.abs(y) <= PAPER_FIELD_HALF)
    # The sand field sits a few centimetres above the surrounding lawn.
    edge = np.maximum(np.abs(x), np.abs(y)) - PAPER_FIELD_HALF
    floor = floor + 0.05 * (1.0 - _smoothstep(edge / 0.3))
    ground = floor.copy()
    lump = fbm(shape, rng, [0.5 * cells, 0.15 * cells], [0.7, 0.3])
    for m in PAPER_MOUNDS:
        rot = np.radians(m.rotation_deg)
        dx, dy = x - m.center[0], y - m.center[1]
        a = dx * np.cos(rot) - dy * np.sin(rot)
        b = dx * np.sin(rot) + dy * np.cos(rot)
        rho2 = (a / m.radii[0]) ** 2 + (b / m.radii[1]) ** 2
        prof = np.clip(1.0 - rho2, 0, None) ** 1.5
        ground = ground + m.height * prof + 0.012 * lump * (prof > 0) * np.sqrt(prof)

    material = np.full(shape, Material.GRASS, np.uint8)
    material[inside] = Material.SAND
    path = (np.abs(y + 12.5) < 0.6) & (np.abs(x) < 18)
    material[path] = Material.GRAVEL
    surface = np.zeros(shape, np.float32)
    grass = material == Material.GRASS
    surface[grass] = (0.04 + 0.015 * fbm(shape, rng, [0.4 * cells, 0.1 * cells]))[grass]
    surface = np.clip(surface, 0, None)
    for _name, cx, cy in PAPER_CHECKPOINTS:
        _paint_target(material, grid, cx, cy, 0.6)

    # Small model trees (branches planted in the sand) on the mounds, shrubs on the lawn.
    parts = []
    for m in PAPER_MOUNDS:
        n = 7
        ang = rng.uniform(0, 2 * np.pi, n)
        rad = np.sqrt(rng.uniform(0.05, 0.7, n))
        rot = np.radians(m.rotation_deg)
        a = rad * np.cos(ang) * m.radii[0]
        b = rad * np.sin(ang) * m.radii[1]
        tx = m.center[0] + a * np.cos(rot) + b * np.sin(rot)
        ty = m.center[1] - a * np.sin(rot) + b * np.cos(rot)
        h = rng.uniform(0.25, 0.6, n)
        parts.append((tx, ty, h, rng.uniform(0.07, 0.14, n), 0.75 * h, MODEL_TREE))
    n = 26
    ang = rng.uniform(0, 2 * np.pi, n)
    rr = rng.uniform(PAPER_FIELD_HALF + 1.0, size_m / 2 - 1.0, n)
    sx, sy = rr * np.cos(ang), rr * np.sin(ang)
    sx = np.clip(sx, -size_m / 2 + 1, size_m / 2 - 1)
    sy = np.clip(sy, -size_m / 2 + 1, size_m / 2 - 1)
    keep = np.abs(sy + 12.5) > 1.2
    sx, sy = sx[keep], sy[keep]
    h = rng.uniform(0.3, 0.9, sx.size)
    parts.append((sx, sy, h, rng.uniform(0.25, 0.55, sx.size), h, SHRUB))
    trees = _assemble(parts, ground, grid, rng)
    scene = Scene(
        grid=grid,
        ground=ground,
        surface=surface,
        material=material,
        trees=trees,
        sand_like=inside,
        floor=floor,
        features={
            "mounds": [m.to_dict() for m in PAPER_MOUNDS],
            "field": {"half_size_m": PAPER_FIELD_HALF, "material": "sand"},
        },
    )
    cps = []
    for name, cx, cy in PAPER_CHECKPOINTS:
        cps.append({"name": name, "x": cx, "y": cy, "z": float(scene.height_at(cx, cy))})
    scene.features["checkpoints"] = cps
    return scene


def _paint_target(material: np.ndarray, grid: Grid, cx: float, cy: float, size: float) -> None:
    """A 2 x 2 black-and-white checkerboard target centred on (cx, cy)."""
    rows, cols = grid.window(cx - size / 2, cy - size / 2, cx + size / 2, cy + size / 2)
    sub = grid.sub(rows, cols)
    xs, ys = sub.mesh()
    inside = (np.abs(xs - cx) < size / 2) & (np.abs(ys - cy) < size / 2)
    white = ((xs - cx) > 0) == ((ys - cy) > 0)
    tile = material[rows, cols]
    tile[inside & white] = Material.TARGET_WHITE
    tile[inside & ~white] = Material.TARGET_BLACK


def _assemble(parts, ground, grid: Grid, rng) -> Trees:
    sets = []
    ident = 0
    for tx, ty, h, r, depth, kind in parts:
        col, row = grid.col_row(tx, ty)
        ri = np.clip(np.rint(row).astype(int), 0, grid.height - 1)
        ci = np.clip(np.rint(col).astype(int), 0, grid.width - 1)
        t = make_trees(tx, ty, ground[ri, ci], h, r, depth, kind, rng, first_ident=ident)
        ident += len(t)
        sets.append(t)
    return Trees.concat(sets)


# --------------------------------------------------------------------------------------
# hillslope


def stream_y(x):
    """Northing of the valley stream (local metres) as a function of easting."""
    return -105.0 + 8.0 * np.sin(np.asarray(x) / 60.0)


HILL_GULLIES = (-130.0, -40.0, 95.0)
HILL_CLEARING = (-150.0, 45.0, 24.0)


def _slope_profile(s: np.ndarray) -> np.ndarray:
    """Height above the stream as a function of the distance s north of it."""
    grid_s = np.arange(-80.0, 340.0, 0.1)
    slope = np.where(
        grid_s >= 0,
        0.03
        + (np.tan(np.radians(32.0)) - 0.03)
        * _smoothstep((grid_s - 35.0) / 50.0)
        * (1.0 - 0.55 * _smoothstep((grid_s - 190.0) / 70.0)),
        -(0.03 + 0.32 * _smoothstep((-grid_s - 14.0) / 20.0)),
    )
    prof = np.cumsum(slope) * 0.1
    prof -= np.interp(0.0, grid_s, prof)
    return np.interp(s, grid_s, prof)


def hillslope_scene(
    rng: np.random.Generator,
    res: float = 0.2,
    width_m: float = 400.0,
    height_m: float = 300.0,
    base_z: float = 700.0,
) -> Scene:
    """A real-scale forested hillslope above a valley (see module docstring)."""
    grid = Grid.centered(width_m, height_m, res)
    x, y = grid.mesh()
    shape = grid.shape
    cells = 1.0 / res
    s = y - stream_y(x)
    z = base_z - 0.015 * x + _slope_profile(s)
    z -= 1.6 * np.exp(-((s / 2.8) ** 2))  # stream channel
    gully_depth = np.zeros(shape)
    gully_dist = np.full(shape, np.inf)
    for i, gx in enumerate(HILL_GULLIES):
        xc = gx + 7.0 * np.sin(y / 33.0 + 1.7 * i)
        dx = np.abs(x - xc)
        depth = 7.0 * _smoothstep((s - 40.0) / 45.0) * (1.0 - 0.5 * _smoothstep((s - 230.0) / 40.0))
        prof = np.clip(1.0 - dx / 16.0, 0, None) ** 1.6
        gully_depth = np.maximum(gully_depth, depth * prof)
        gully_dist = np.minimum(gully_dist, dx)
    z -= gully_depth
    rough = fbm(
        shape, rng, [40 * cells, 12 * cells, 3 * cells, 0.6 * cells], [1.4, 0.5, 0.12, 0.03]
    )
    forest_zone = (s > 30) | (s < -12)
    z += rough * np.where(forest_zone, 1.0, 0.35)
    # Gravel road along the valley, cut into the floodplain.
    road = np.abs(s - 22.0) < 2.5
    z = np.where(road, z - 0.9 * rough * 0.35 + 0.05, z)
    ground = z

    material = np.full(shape, Material.FOREST_FLOOR, np.uint8)
    meadow = ((s > 4) & (s < 34)) | ((s < -4) & (s > -14))
    cx, cy, cr = HILL_CLEARING
    clearing = np.hypot(x - cx, y - cy) < cr * (1 + 0.15 * fbm(shape, rng, [6 * cells]))
    material[meadow | clearing] = Material.GRASS
    material[(np.abs(s) < 4.0)] = Material.GRAVEL
    material[np.abs(s) < 2.0] = Material.WATER
    material[road] = Material.GRAVEL
    rocky = (gully_depth > 3.5) & (fbm(shape, rng, [2 * cells, 0.5 * cells]) > 0.2)
    material[rocky] = Material.ROCK
    surface = np.zeros(shape, np.float32)
    grass = material == Material.GRASS
    surface[grass] = np.clip(0.25 + 0.08 * fbm(shape, rng, [3 * cells, 0.6 * cells]), 0.05, None)[
        grass
    ]

    # Vegetation.
    parts = []
    px, py = jittered_positions(rng, grid.x_left, grid.y_bottom, grid.x_right, grid.y_top, 5.6)
    ps = py - stream_y(px)
    ok = (ps > 38) & (rng.random(px.size) < 0.86)
    ok &= np.hypot(px - cx, py - cy) > cr + 3
    gd = np.min(
        [
            np.abs(px - (gx + 7.0 * np.sin(py / 33.0 + 1.7 * i)))
            for i, gx in enumerate(HILL_GULLIES)
        ],
        axis=0,
    )
    ok &= gd > 5.0
    px, py, ps = px[ok], py[ok], ps[ok]
    h = rng.uniform(15.0, 23.0, px.size) - 0.012 * np.clip(ps - 60, 0, None)
    parts.append((px, py, h, rng.uniform(1.9, 2.8, px.size), 0.55 * h, CONIFER))
    bx, by = jittered_positions(rng, grid.x_left, grid.y_bottom, grid.x_right, grid.y_top, 9.0)
    bs = by - stream_y(bx)
    gdb = np.min(
        [
            np.abs(bx - (gx + 7.0 * np.sin(by / 33.0 + 1.7 * i)))
            for i, gx in enumerate(HILL_GULLIES)
        ],
        axis=0,
    )
    okb = (((bs > 30) & (bs < 42)) | (bs < -16) | ((gdb < 6.0) & (bs > 40))) & (
        rng.random(bx.size) < 0.7
    )
    bx, by = bx[okb], by[okb]
    h = rng.uniform(9.0, 15.0, bx.size)
    parts.append((bx, by, h, rng.uniform(3.0, 4.5, bx.size), 0.6 * h, BROADLEAF))
    n = 160
    sx = rng.uniform(grid.x_left + 2, grid.x_right - 2, n)
    ss = rng.uniform(8.0, 33.0, n)
    sy = stream_y(sx) + ss
    ok_s = np.abs(ss - 22.0) > 4.0
    ang = rng.uniform(0, 2 * np.pi, 40)
    rr = cr * np.sqrt(rng.uniform(0, 1, 40))
    sx = np.concatenate([sx[ok_s], cx + rr * np.cos(ang)])
    sy = np.concatenate([sy[ok_s], cy + rr * np.sin(ang)])
    h = rng.uniform(1.0, 2.6, sx.size)
    parts.append((sx, sy, h, rng.uniform(0.8, 1.7, sx.size), h, SHRUB))
    trees = _assemble(parts, ground, grid, rng)
    return Scene(
        grid=grid,
        ground=ground,
        surface=surface,
        material=material,
        trees=trees,
        sand_like=np.zeros(shape, bool),
        floor=None,
        features={
            "valley": {"stream": "y = -105 + 8 sin(x / 60) (local metres), flowing east"},
            "gullies_x_local": list(HILL_GULLIES),
            "clearing": {"center_local": [cx, cy], "radius_m": cr},
        },
    )
