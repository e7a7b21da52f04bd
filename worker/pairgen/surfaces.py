"""Surface models: what stands on the ground (grass, trees, buildings) in each survey.

A model draws both surveys' scenes at once, the post scene holding the changes that are
not landslides (growth, felling, planting, mowing, building and demolition).
`apply_slides` then moves or removes what stood on the slides, and `render` turns a
scene into a DSM on a given ground.

Trees and roofs are rendered as absolute heights (a crown's top is its trunk's ground
plus the tree's height) and the DSM takes the highest of ground, crowns and roofs: a
crown overhanging a slide stays where it is when the ground under it drops, as it
would. Grass is added to the ground (it rides on whatever the ground does).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import ndimage

from worker.pairgen.fields import gaussian_field, slope_deg, smooth
from worker.pairgen.slides import CARRYING, Slide

SurfaceModel = Callable[..., "SurfacePlan"]


@dataclass(frozen=True)
class Trees:
    row: np.ndarray  # trunk position, pixels (float)
    col: np.ndarray
    height: np.ndarray  # m
    radius: np.ndarray  # crown radius, m
    crown: np.ndarray  # crown depth / height
    cone: np.ndarray  # bool: conical (conifer) rather than paraboloid crown

    @staticmethod
    def empty() -> Trees:
        z = np.zeros(0)
        return Trees(z, z, z, z, z, np.zeros(0, dtype=bool))

    def __len__(self) -> int:
        return int(self.row.size)

    def take(self, keep: np.ndarray) -> Trees:
        return Trees(*(getattr(self, f)[keep] for f in _TREE_FIELDS))

    def concat(self, other: Trees) -> Trees:
        return Trees(*(np.concatenate([getattr(self, f), getattr(other, f)]) for f in _TREE_FIELDS))


_TREE_FIELDS = ("row", "col", "height", "radius", "crown", "cone")


@dataclass(frozen=True)
class Building:
    row: float  # centre, pixels
    col: float
    half_length_m: float
    half_width_m: float
    angle: float  # radians, of the long side from the column axis
    height_m: float
    ridge_m: float  # gable rise above the eaves; 0 for a flat roof


@dataclass(frozen=True)
class Scene:
    """One survey's surface: grass height above ground, trees, buildings."""

    grass: np.ndarray | None = None
    trees: Trees = field(default_factory=Trees.empty)
    buildings: tuple[Building, ...] = ()


@dataclass(frozen=True)
class SurfacePlan:
    pre: Scene
    post: Scene  # with the non-landslide changes only
    description: dict[str, Any] = field(default_factory=dict)


# ---------------------------------------------------------------- rendering


def _bilinear_many(a: np.ndarray, r: np.ndarray, c: np.ndarray) -> np.ndarray:
    return ndimage.map_coordinates(a, [r, c], order=1, mode="nearest")


def _building_window(
    b: Building, shape: tuple[int, int], pixel_size: float, pad_px: int = 0
) -> tuple[tuple[slice, slice], np.ndarray, np.ndarray] | None:
    """The building's pixel window (grown by `pad_px`) and, on it, the inside mask and
    the across-ridge offset (0 on the ridge, 1 at the eaves)."""
    reach = np.hypot(b.half_length_m, b.half_width_m) / pixel_size + 1 + pad_px
    r0, r1 = max(int(b.row - reach), 0), min(int(b.row + reach) + 2, shape[0])
    c0, c1 = max(int(b.col - reach), 0), min(int(b.col + reach) + 2, shape[1])
    if r0 >= r1 or c0 >= c1:
        return None
    dr = (np.arange(r0, r1)[:, None] - b.row) * pixel_size
    dc = (np.arange(c0, c1)[None, :] - b.col) * pixel_size
    along = dc * np.cos(b.angle) - dr * np.sin(b.angle)
    across = dc * np.sin(b.angle) + dr * np.cos(b.angle)
    inside = (np.abs(along) <= b.half_length_m) & (np.abs(across) <= b.half_width_m)
    return (slice(r0, r1), slice(c0, c1)), inside, np.abs(across) / b.half_width_m


def building_masks(
    buildings: tuple[Building, ...], shape: tuple[int, int], pixel_size: float
) -> np.ndarray:
    mask = np.zeros(shape, dtype=bool)
    for b in buildings:
        win = _building_window(b, shape, pixel_size)
        if win is not None:
            mask[win[0]] |= win[1]
    return mask


def render(scene: Scene, ground: np.ndarray, pixel_size: float) -> np.ndarray:
    """The DSM of `scene` standing on `ground` (float64)."""
    dsm = ground + scene.grass if scene.grass is not None else ground.copy()
    for b in scene.buildings:
        win = _building_window(b, ground.shape, pixel_size)
        if win is None or not win[1].any():
            continue
        window, inside, across = win
        # Roofs are level: the eaves stand on the footprint's median ground.
        base = float(np.median(ground[window][inside]))
        roof = base + b.height_m - b.ridge_m * across
        dsm[window] = np.where(inside, np.maximum(dsm[window], roof), dsm[window])
    trees = scene.trees
    if len(trees):
        tops = _bilinear_many(ground, trees.row, trees.col) + trees.height
        for i in range(len(trees)):
            _stamp_crown(dsm, trees, i, float(tops[i]), pixel_size)
    return dsm


def _stamp_crown(dsm: np.ndarray, trees: Trees, i: int, top: float, pixel_size: float) -> None:
    radius_px = trees.radius[i] / pixel_size
    r, c = trees.row[i], trees.col[i]
    r0, r1 = (
        max(int(np.floor(r - radius_px)), 0),
        min(int(np.ceil(r + radius_px)) + 1, dsm.shape[0]),
    )
    c0, c1 = (
        max(int(np.floor(c - radius_px)), 0),
        min(int(np.ceil(c + radius_px)) + 1, dsm.shape[1]),
    )
    if r0 >= r1 or c0 >= c1:
        return
    d = np.hypot(np.arange(r0, r1)[:, None] - r, np.arange(c0, c1)[None, :] - c) / radius_px
    depth = trees.crown[i] * trees.height[i]
    crown = top - depth * (d if trees.cone[i] else d * d)
    window = dsm[r0:r1, c0:c1]
    np.maximum(window, np.where(d <= 1.0, crown, -np.inf), out=window)


# ---------------------------------------------------------------- slides on the surface


def apply_slides(scene: Scene, slides: list[Slide], pixel_size: float) -> Scene:
    """The post scene with what stood on the slides carried along or removed.

    Trees rooted on a carrying slide's moving mass (slump, slab, deep-seated body) move
    with it; trees rooted elsewhere on a footprint are uprooted or buried. A building
    touching a footprint is destroyed.
    """
    if not slides:
        return scene
    trees = scene.trees
    keep = np.ones(len(trees), dtype=bool)
    row, col = trees.row.copy(), trees.col.copy()
    if len(trees):
        ri = np.clip(np.round(trees.row).astype(int), 0, slides[0].dh.shape[0] - 1)
        ci = np.clip(np.round(trees.col).astype(int), 0, slides[0].dh.shape[1] - 1)
        for slide in slides:
            on = slide.footprint[ri, ci]
            moving = slide.carried[ri, ci] if slide.kind in CARRYING else np.zeros_like(on)
            row[moving] += slide.displacement_m[0] / pixel_size
            col[moving] += slide.displacement_m[1] / pixel_size
            keep &= ~(on & ~moving)
    moved = replace(trees, row=row, col=col).take(keep)
    footprints = np.zeros(slides[0].dh.shape, dtype=bool)
    for slide in slides:
        footprints |= slide.footprint
    footprints = ndimage.binary_dilation(footprints)
    standing = tuple(
        b
        for b in scene.buildings
        if not (building_masks((b,), footprints.shape, pixel_size) & footprints).any()
    )
    return replace(scene, trees=moved, buildings=standing)


# ---------------------------------------------------------------- models


def _grass_layer(
    shape: tuple[int, int],
    pixel_size: float,
    rng: np.random.Generator,
    height_m: tuple[float, float],
    mow_chance: float,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Pre and post grass heights: textured sward that grows or dries, mown in patches."""
    extent = max(shape) * pixel_size
    h0 = rng.uniform(*height_m)
    corr = rng.uniform(0.1, 0.5)
    texture = gaussian_field(shape, pixel_size, rng, corr)
    patchy = gaussian_field(shape, pixel_size, rng, extent / 5)
    pre = h0 * np.clip(1 + 0.35 * texture + 0.2 * patchy, 0.2, None)
    growth = rng.uniform(0.75, 1.5)
    # Wind and growth re-arrange blades: part of the texture is new in the post survey.
    retexture = gaussian_field(shape, pixel_size, rng, corr)
    post = pre * growth * (1 + 0.1 * gaussian_field(shape, pixel_size, rng, extent / 4))
    post = np.clip(post + 0.15 * h0 * retexture, 0.02, None)
    mown = 0
    if rng.uniform() < mow_chance:
        rr, cc = np.mgrid[0 : shape[0], 0 : shape[1]]
        mown = int(rng.integers(1, 4))
        for _ in range(mown):
            centre = rng.uniform(0, 1, size=2) * shape
            axes = rng.uniform(0.1, 0.35, size=2) * extent / pixel_size
            angle = rng.uniform(0, np.pi)
            dr, dc = rr - centre[0], cc - centre[1]
            a = (dc * np.cos(angle) - dr * np.sin(angle)) / axes[0]
            b = (dc * np.sin(angle) + dr * np.cos(angle)) / axes[1]
            post = np.where(a * a + b * b <= 1, rng.uniform(0.03, 0.06), post)
    return pre, post, {"grass_m": h0, "growth": growth, "mown_patches": mown}


def bare(
    ground: np.ndarray,
    pixel_size: float,
    rng: np.random.Generator,
    features: Mapping[str, np.ndarray] | None = None,
) -> SurfacePlan:
    """Bare soil or rock: the DSM is the ground."""
    return SurfacePlan(Scene(), Scene(), {"surface": "bare"})


def grass(
    ground: np.ndarray,
    pixel_size: float,
    rng: np.random.Generator,
    features: Mapping[str, np.ndarray] | None = None,
    height_m: tuple[float, float] = (0.1, 0.5),
    mow_chance: float = 0.5,
    bare_chance: float = 0.0,
) -> SurfacePlan:
    """Grass 0.1-0.5 m, textured; grows or dries between surveys, some patches mown.

    With `bare_chance` the pair is bare instead (the draws are made all the same, so the
    rest of the pair does not depend on the outcome).
    """
    is_bare = rng.uniform() < bare_chance
    pre, post, info = _grass_layer(ground.shape, pixel_size, rng, height_m, mow_chance)
    if is_bare:
        return SurfacePlan(Scene(), Scene(), {"surface": "bare"})
    return SurfacePlan(Scene(grass=pre), Scene(grass=post), {"surface": "grass", **info})


def _draw_trees(
    mask: np.ndarray,
    pixel_size: float,
    rng: np.random.Generator,
    density: float,
    height_m: tuple[float, float],
    radius_m: tuple[float, float],
) -> tuple[Trees, dict[str, Any]]:
    """Trees with crown cover ~`density` where `mask`, patchy (denser and sparser stands).

    Cover is crown area over ground area, so dense stands overlap as real canopies do.
    """
    shape = mask.shape
    extent = max(shape) * pixel_size
    stand = rng.uniform(0.45, 0.95) * (height_m[1] - height_m[0]) + height_m[0]
    mean_r = radius_m[0] + (stand - height_m[0]) / (height_m[1] - height_m[0]) * (
        radius_m[1] - radius_m[0]
    )
    local = density * np.exp(0.6 * gaussian_field(shape, pixel_size, rng, extent / 4))
    local = np.clip(local, 0.0, 0.95) * mask
    peak = max(float(local.max()), 1e-6)
    area = shape[0] * shape[1] * pixel_size**2
    n = int(rng.poisson(peak * area / (np.pi * mean_r**2)))
    r = rng.uniform(0, shape[0] - 1, size=n)
    c = rng.uniform(0, shape[1] - 1, size=n)
    accept = rng.uniform(0, peak, size=n) < local[r.astype(int), c.astype(int)]
    height = np.clip(stand * rng.uniform(0.6, 1.15, size=n), height_m[0], height_m[1])
    frac = (height - height_m[0]) / (height_m[1] - height_m[0])
    radius = np.clip(
        (radius_m[0] + frac * (radius_m[1] - radius_m[0])) * rng.uniform(0.7, 1.3, size=n),
        *radius_m,
    )
    conifers = rng.uniform()
    trees = Trees(
        r,
        c,
        height,
        radius,
        rng.uniform(0.5, 0.8, size=n),
        rng.uniform(size=n) < conifers,
    ).take(accept)
    return trees, {"trees": len(trees), "stand_height_m": stand, "conifer_share": conifers}


def _forest_changes(
    trees: Trees,
    shape: tuple[int, int],
    pixel_size: float,
    rng: np.random.Generator,
    growth_m: tuple[float, float],
    felled: tuple[float, float],
) -> tuple[Trees, dict[str, Any]]:
    """Growth of every tree, felling of a few (scattered or one clearing), planting."""
    n = len(trees)
    grow = rng.uniform(*growth_m) * rng.uniform(0.6, 1.4, size=n)
    grown = replace(
        trees,
        height=trees.height + grow,
        radius=trees.radius * (1 + 0.3 * grow / np.maximum(trees.height, 1.0)),
    )
    share = rng.uniform(*felled)
    if rng.uniform() < 0.3 and n:  # a clearing: the trees nearest a drawn point
        centre = rng.uniform(0, 1, size=2) * shape
        dist = np.hypot(trees.row - centre[0], trees.col - centre[1])
        cut = dist <= np.quantile(dist, share)
    else:
        cut = rng.uniform(size=n) < share
    n_new = int(rng.poisson(max(1.0, 0.8 * np.count_nonzero(cut))))
    saplings = Trees(
        rng.uniform(0, shape[0] - 1, size=n_new),
        rng.uniform(0, shape[1] - 1, size=n_new),
        rng.uniform(1.0, 3.0, size=n_new),
        rng.uniform(0.4, 1.0, size=n_new),
        rng.uniform(0.6, 0.9, size=n_new),
        np.ones(n_new, dtype=bool),
    )
    post = grown.take(~cut).concat(saplings)
    return post, {"felled": int(np.count_nonzero(cut)), "planted": n_new}


def forest(
    ground: np.ndarray,
    pixel_size: float,
    rng: np.random.Generator,
    features: Mapping[str, np.ndarray] | None = None,
    density: tuple[float, float] = (0.05, 0.8),
    height_m: tuple[float, float] = (5.0, 30.0),
    radius_m: tuple[float, float] = (1.5, 6.0),
    growth_m: tuple[float, float] = (0.2, 1.0),
    felled: tuple[float, float] = (0.02, 0.1),
    understory_m: tuple[float, float] = (0.05, 0.3),
) -> SurfacePlan:
    """Forest: crowns 5-30 m tall, cover `density`, with understory; trees grow 0.2-1 m,
    a few are felled and saplings planted."""
    shape = ground.shape
    cover = rng.uniform(*density)
    trees, info = _draw_trees(
        np.ones(shape, dtype=bool), pixel_size, rng, cover, height_m, radius_m
    )
    post_trees, change = _forest_changes(trees, shape, pixel_size, rng, growth_m, felled)
    under_pre, under_post, under = _grass_layer(shape, pixel_size, rng, understory_m, 0.0)
    return SurfacePlan(
        Scene(grass=under_pre, trees=trees),
        Scene(grass=under_post, trees=post_trees),
        {"surface": "forest", "cover": cover, **info, **change, "understory_m": under["grass_m"]},
    )


def _place_buildings(
    free: np.ndarray,
    pixel_size: float,
    rng: np.random.Generator,
    count: int,
    height_m: tuple[float, float],
    side_m: tuple[float, float],
    tries: int,
) -> list[Building]:
    """Up to `count` non-overlapping buildings on `free` pixels (which it updates)."""
    shape = free.shape
    placed: list[Building] = []
    rows, cols = np.nonzero(free)
    if rows.size == 0:
        return placed
    picks = rng.integers(0, rows.size, size=tries)
    for k in range(tries):
        if len(placed) >= count:
            break
        half_l, half_w = sorted(rng.uniform(*side_m, size=2) / 2)[::-1]
        # Heights skew low: most are houses, a few are blocks of flats.
        height = height_m[0] + (height_m[1] - height_m[0]) * rng.uniform() ** 2
        ridge = rng.uniform(1.0, 3.0) if rng.uniform() < 0.5 and height > 5 else 0.0
        angle = rng.choice([0.0, np.pi / 2]) + rng.normal(0.0, np.radians(3.0))
        b = Building(
            float(rows[picks[k]]), float(cols[picks[k]]), half_l, half_w, angle, height, ridge
        )
        yard_px = max(1, int(2.0 / pixel_size))  # a 2 m yard stays free around each
        win = _building_window(b, shape, pixel_size, pad_px=yard_px + 1)
        if win is None:
            continue
        window, inside, _ = win
        reach = inside.shape[0] // 2
        if not (reach <= b.row < shape[0] - reach and reach <= b.col < shape[1] - reach):
            continue  # a building cut by the raster edge would have a wrong base height
        yard = ndimage.binary_dilation(inside, iterations=yard_px)
        if not free[window][yard].all():
            continue
        free[window] &= ~yard
        placed.append(b)
    return placed


def urban(
    ground: np.ndarray,
    pixel_size: float,
    rng: np.random.Generator,
    features: Mapping[str, np.ndarray] | None = None,
    height_m: tuple[float, float] = (4.0, 25.0),
    side_m: tuple[float, float] = (6.0, 25.0),
    changed: tuple[int, int] = (1, 3),
    tree_cover: tuple[float, float] = (0.02, 0.08),
) -> SurfacePlan:
    """Buildings 4-25 m tall on the flat part (off roads and the hill), a few street and
    hill trees; between surveys some buildings are demolished and some built."""
    shape = ground.shape
    features = features or {}
    road = features.get("road", np.zeros(shape, dtype=bool))
    hill = features.get("hill", np.zeros(shape, dtype=bool))
    flat = slope_deg(smooth(ground, 2.0 / pixel_size), pixel_size) < 8.0
    # Nothing is built within 10 m of the hill: a setback from the cut slope's foot.
    setback = ndimage.binary_dilation(hill, iterations=max(1, int(10.0 / pixel_size)))
    free = flat & ~road & ~setback
    area = float(np.count_nonzero(free)) * pixel_size**2
    coverage = rng.uniform(0.1, 0.3)
    mean_footprint = (np.mean(side_m) ** 2) * 0.8
    count = int(coverage * area / mean_footprint)
    buildings = _place_buildings(
        free, pixel_size, rng, count, height_m, side_m, tries=6 * count + 50
    )
    removed = int(rng.integers(changed[0], changed[1] + 1))
    built = int(rng.integers(changed[0], changed[1] + 1))
    gone = set(
        rng.choice(len(buildings), size=min(removed, len(buildings)), replace=False).tolist()
    )
    new = _place_buildings(free, pixel_size, rng, built, height_m, side_m, tries=200)
    trees, info = _draw_trees(
        ~building_masks(tuple(buildings) + tuple(new), shape, pixel_size) & ~road,
        pixel_size,
        rng,
        rng.uniform(*tree_cover),
        (5.0, 15.0),
        (1.5, 4.0),
    )
    post_trees, change = _forest_changes(trees, shape, pixel_size, rng, (0.2, 0.6), (0.0, 0.05))
    kept = tuple(b for i, b in enumerate(buildings) if i not in gone)
    return SurfacePlan(
        Scene(trees=trees, buildings=tuple(buildings)),
        Scene(trees=post_trees, buildings=kept + tuple(new)),
        {
            "surface": "urban",
            "buildings": len(buildings),
            "demolished": len(gone),
            "built": len(new),
            **info,
            **change,
        },
    )


SURFACES: dict[str, SurfaceModel] = {
    "bare": bare,
    "grass": grass,
    "forest": forest,
    "urban": urban,
}


def make_surface(
    name: str,
    ground: np.ndarray,
    pixel_size: float,
    rng: np.random.Generator,
    params: Mapping[str, Any] | None = None,
    features: Mapping[str, np.ndarray] | None = None,
) -> SurfacePlan:
    return SURFACES[name](ground, pixel_size, rng, features=features, **dict(params or {}))
