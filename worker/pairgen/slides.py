"""Landslide models: each changes the ground and says what it changed.

A slide is drawn in two steps. `SlideSpec.draw` picks its size and depth (metres) from
the generator's ranges; the generator does this for the no-change twin too, because the
pair's noise level is set from the slide depth. `make_slide` then places it on the
terrain and builds its height change, with its own random stream, so the twin (which
never places anything) keeps every other draw identical.

Every model works in slide coordinates: u (metres) downslope from the head scarp, v
across; the debris flow and the rockfall use the arc length s along a path traced down
the smoothed terrain instead of u. The drawn depth is the slide's largest |dh|: each
model's shape is scaled so, whether the largest change is a loss (scar) or a gain
(toe, deposit). The footprint is where |dh| > max(1 cm, 1 % of that depth); dh is zeroed
elsewhere so that the true change and the labels agree pixel for pixel.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import ndimage

from worker.pairgen.fields import gradient, loguniform, smooth, smoothstep
from worker.pairgen.pair import SlideTruth

KINDS = ("rotational", "translational", "debris-flow", "rockfall", "shallow", "deep-seated")

# Width / length of the body (for the path kinds: of the source scar).
WIDTH_RATIO = {
    "rotational": (0.5, 1.0),
    "translational": (0.4, 0.9),
    "debris-flow": (0.5, 1.0),
    "rockfall": (0.6, 1.2),
    "shallow": (0.2, 0.5),  # elongated: 2-5 times longer than wide
    "deep-seated": (0.6, 1.1),
}
# Smoothed-terrain slope (degrees) where each kind may start.
SLOPE_DEG = {
    "rotational": (18.0, 50.0),
    "translational": (18.0, 55.0),
    "debris-flow": (20.0, 50.0),
    "rockfall": (35.0, 80.0),
    "shallow": (15.0, 50.0),
    "deep-seated": (20.0, 50.0),
}
# Kinds whose moving mass carries trees along; the others bury or uproot them.
CARRYING = ("rotational", "translational", "deep-seated")
MIN_WIDTH_PX = 8.0
MIN_LENGTH_PX = 12.0
FOOTPRINT_FRACTION, FOOTPRINT_FLOOR_M = 0.01, 0.01
SEPARATION_PX = 6  # two slides never touch: their footprints stay this far apart


@dataclass(frozen=True)
class SlideSpec:
    """The ranges a generator draws one kind of slide from.

    `length_m` is head scarp to toe for the compact kinds, and the source scar's length
    for debris flows and rockfalls (their runout comes on top). `depth_m` bounds the
    slide's largest |dh|.
    """

    kind: str
    length_m: tuple[float, float]
    depth_m: tuple[float, float]
    width_ratio: tuple[float, float] | None = None
    slope_deg: tuple[float, float] | None = None

    def draw(self, rng: np.random.Generator) -> SlidePlan:
        length = loguniform(rng, *self.length_m)
        ratio = rng.uniform(*(self.width_ratio or WIDTH_RATIO[self.kind]))
        depth = loguniform(rng, *self.depth_m)
        return SlidePlan(self.kind, length, length * ratio, depth)


@dataclass(frozen=True)
class SlidePlan:
    kind: str
    length_m: float
    width_m: float
    depth_m: float


@dataclass
class Slide:
    """A placed slide on the full grid (before it gets its id)."""

    kind: str
    dh: np.ndarray  # float64, 0 outside the footprint
    footprint: np.ndarray  # bool
    carried: np.ndarray  # bool: where the moving mass carries what stands on it
    displacement_m: tuple[float, float]  # (rows, cols) metres, for the carried part
    length_m: float
    description: dict[str, Any] = field(default_factory=dict)

    def truth(self, slide_id: int, pixel_size: float) -> SlideTruth:
        """Sizes measured on the arrays (not the drawn plan)."""
        d = self.dh[self.footprint]
        area = pixel_size * pixel_size
        return SlideTruth(
            id=slide_id,
            kind=self.kind,
            area_m2=float(d.size * area),
            area_px=int(d.size),
            volume_loss_m3=float(-d[d < 0].sum() * area),
            volume_gain_m3=float(d[d > 0].sum() * area),
            max_depth_m=float(np.abs(d).max()) if d.size else 0.0,
            length_m=float(self.length_m),
        )


# ---------------------------------------------------------------- terrain at slide scale


class _SlopeField:
    """Smoothed slope and downslope direction of the pre ground at one scale."""

    def __init__(self, ground: np.ndarray, pixel_size: float, sigma_px: float) -> None:
        z = smooth(ground, max(sigma_px, 1.5))
        self.d_row, self.d_col = gradient(z, pixel_size)
        self.tan = np.hypot(self.d_row, self.d_col)
        self.slope_deg = np.degrees(np.arctan(self.tan))

    def downslope(self, r: float, c: float) -> np.ndarray:
        gr, gc = _bilinear(self.d_row, r, c), _bilinear(self.d_col, r, c)
        norm = np.hypot(gr, gc)
        if norm < 1e-9:
            return np.array([1.0, 0.0])
        return np.array([-gr / norm, -gc / norm])


def _bilinear(a: np.ndarray, r: float, c: float) -> float:
    r = min(max(r, 0.0), a.shape[0] - 1.001)
    c = min(max(c, 0.0), a.shape[1] - 1.001)
    r0, c0 = int(r), int(c)
    fr, fc = r - r0, c - c0
    top = a[r0, c0] * (1 - fc) + a[r0, c0 + 1] * fc
    bottom = a[r0 + 1, c0] * (1 - fc) + a[r0 + 1, c0 + 1] * fc
    return float(top * (1 - fr) + bottom * fr)


def _candidates(
    slope: _SlopeField,
    slope_deg: tuple[float, float],
    inner: tuple[slice, slice],
    rng: np.random.Generator,
    count: int,
    allowed: np.ndarray | None = None,
) -> np.ndarray:
    """Up to `count` random (row, col) pixels on slopes in range, inside `inner` and
    `allowed`.

    Falls back to the steepest third of the inner area when the terrain has too few
    pixels in range (a gentle field still has its steepest banks).
    """
    s = slope.slope_deg[inner]
    if s.size == 0:
        return np.zeros((0, 2), dtype=int)
    free = np.ones(s.shape, dtype=bool) if allowed is None else allowed[inner]
    ok = (s >= slope_deg[0]) & (s <= slope_deg[1]) & free
    if np.count_nonzero(ok) < 50:
        ok = (s >= np.percentile(s, 67)) & free
    rows, cols = np.nonzero(ok)
    pick = rng.choice(rows.size, size=min(count, rows.size), replace=False)
    return np.stack([rows[pick] + inner[0].start, cols[pick] + inner[1].start], axis=1)


# ---------------------------------------------------------------- geometry helpers


def _straight_window(
    head: np.ndarray, e: np.ndarray, length_px: float, width_px: float
) -> tuple[np.ndarray, np.ndarray]:
    """Row/col bounds of the box u in [-0.1 L, 1.1 L], |v| <= 0.6 W."""
    n = np.array([-e[1], e[0]])
    corners = [
        head + e * u + n * v
        for u in (-0.1 * length_px, 1.1 * length_px)
        for v in (-0.6 * width_px, 0.6 * width_px)
    ]
    pts = np.array(corners)
    return np.floor(pts.min(axis=0)).astype(int), np.ceil(pts.max(axis=0)).astype(int) + 1


def _inside(lo: np.ndarray, hi: np.ndarray, shape: tuple[int, int], margin: int) -> bool:
    return bool(
        lo[0] >= margin
        and lo[1] >= margin
        and hi[0] <= shape[0] - margin
        and hi[1] <= shape[1] - margin
    )


def _local_uv(
    lo: np.ndarray, hi: np.ndarray, head: np.ndarray, e: np.ndarray, pixel_size: float
) -> tuple[np.ndarray, np.ndarray]:
    r = np.arange(lo[0], hi[0])[:, None] - head[0]
    c = np.arange(lo[1], hi[1])[None, :] - head[1]
    u = (r * e[0] + c * e[1]) * pixel_size
    v = (-r * e[1] + c * e[0]) * pixel_size
    return u, v


def _trace(
    slope: _SlopeField,
    start: np.ndarray,
    e0: np.ndarray,
    length_px: float,
    shape: tuple[int, int],
    margin: int,
    inertia: float = 0.7,
    stop_tan: float | None = None,
    past_foot_px: float = 0.0,
    clearance: np.ndarray | None = None,
    min_clearance: float = 0.0,
) -> tuple[np.ndarray, int | None] | None:
    """Stations 1 px apart down the smoothed terrain from `start`; None if it leaves
    the raster's inner part or comes within `min_clearance` px of another slide (by
    the `clearance` distance map).

    Inertia keeps the path from zig-zagging across a valley floor. With `stop_tan`, also
    returns the index where the slope first stays below it (the foot of a face), and
    stops `past_foot_px` after it.
    """
    pos = start.astype(float).copy()
    direction = e0 / np.hypot(*e0)
    stations = [pos.copy()]
    foot, gentle = None, 0
    for i in range(int(np.ceil(length_px))):
        down = slope.downslope(pos[0], pos[1])
        direction = inertia * direction + (1 - inertia) * down
        direction /= np.hypot(*direction)
        pos = pos + direction
        if not (margin <= pos[0] < shape[0] - margin and margin <= pos[1] < shape[1] - margin):
            return None
        if clearance is not None and clearance[int(pos[0] + 0.5), int(pos[1] + 0.5)] <= (
            min_clearance
        ):
            return None
        stations.append(pos.copy())
        if stop_tan is not None and foot is None:
            tan = np.hypot(_bilinear(slope.d_row, *pos), _bilinear(slope.d_col, *pos))
            gentle = gentle + 1 if tan < stop_tan else 0
            if gentle >= 3:
                foot = i + 1
        if foot is not None and i + 1 >= foot + past_foot_px:
            break
    return np.array(stations), foot


def _path_coords(
    stations: np.ndarray, pad_px: float, shape: tuple[int, int], pixel_size: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Window bounds and (s, v) metres of its pixels relative to a 1-px-step path.

    Nearest station by a distance transform of the rasterised path (a k-d tree query
    per pixel would cost more than the whole slide). Beyond either end, s continues
    along the end direction so that the head and the toe can be rounded.
    """
    lo = np.floor(stations.min(axis=0) - pad_px).astype(int)
    hi = np.ceil(stations.max(axis=0) + pad_px).astype(int) + 1
    lo, hi = np.maximum(lo, 0), np.minimum(hi, shape)
    size = hi - lo
    index = np.full(size, -1, dtype=np.int64)
    cells = np.round(stations - lo).astype(int)
    cells = np.clip(cells, 0, size - 1)
    index[cells[::-1, 0], cells[::-1, 1]] = np.arange(len(stations))[::-1]
    _, (ir, ic) = ndimage.distance_transform_edt(index < 0, return_indices=True)
    nearest = index[ir, ic]
    directions = np.gradient(stations, axis=0)
    directions /= np.hypot(directions[:, 0], directions[:, 1])[:, None]
    rr = np.arange(lo[0], hi[0])[:, None] - stations[nearest, 0]
    cc = np.arange(lo[1], hi[1])[None, :] - stations[nearest, 1]
    dr, dc = directions[nearest, 0], directions[nearest, 1]
    along = rr * dr + cc * dc
    s = nearest.astype(float) + np.where(
        (nearest == 0) & (along < 0) | (nearest == len(stations) - 1) & (along > 0), along, 0.0
    )
    v = -rr * dc + cc * dr
    return lo, hi, s * pixel_size, v * pixel_size


# ---------------------------------------------------------------- slide shapes


def _rim(width_m: float, pixel_size: float, fraction: float) -> float:
    """Scarp width as a fraction of a half-size, never under 2.5 px (a scarp must show)."""
    return max(fraction, 2.5 * pixel_size / (width_m / 2))


def _rotational(
    u: np.ndarray, v: np.ndarray, plan: SlidePlan, pixel_size: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Slump: a curved head scarp, a block dropped most at the head (tilted back) and a
    toe bulge holding the same volume (mass conserved)."""
    length, width = plan.length_m, plan.width_m
    x, a = u / length, 2 * v / width
    rho = np.sqrt(((x - 0.5) / 0.5) ** 2 + a**2)
    edge = smoothstep((1 - rho) / _rim(min(length, width), pixel_size, 0.1))
    x_mid = rng.uniform(0.55, 0.65)
    loss = np.clip((x_mid - x) / (x_mid - 0.05), 0, 1) * (1 - 0.3 * a**2)
    x_bulge = x_mid - 0.1
    bulge = np.sin(np.pi * np.clip((x - x_bulge) / (1 - x_bulge), 0, 1)) ** 2
    bulge *= np.clip(1 - a**2, 0, None)
    loss, bulge = edge * loss, edge * bulge
    dh = -loss + bulge * (loss.sum() / max(bulge.sum(), 1e-12))
    return dh, edge > 0, {"block_end": x_mid}


def _translational(
    u: np.ndarray,
    v: np.ndarray,
    plan: SlidePlan,
    pixel_size: float,
    rng: np.random.Generator,
    texture: Callable[[float], tuple[np.ndarray, np.ndarray]],
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Planar slab sliding d metres downslope: thinned at the head, piled at the toe.

    The slab carries its surface texture with it, so its interior changes too (by the
    texture's difference), as a real displaced slab does in a DSM difference.
    """
    length, width = plan.length_m, plan.width_m
    shift = min(rng.uniform(0.12, 0.3) * length, rng.uniform(2.0, 8.0))
    slab = length - shift
    edge_m = max(0.08 * min(length, width), 2.5 * pixel_size)

    def plateau(uu: np.ndarray) -> np.ndarray:
        return (
            smoothstep(uu / edge_m)
            * smoothstep((slab - uu) / edge_m)
            * smoothstep((width / 2 - np.abs(v)) / edge_m)
        )

    tex_here, tex_from = texture(shift)
    here, moved = plateau(u), plateau(u - shift)
    dh = plan.depth_m * (moved - here)
    dh += moved * tex_from - here * tex_here
    # The slab stretches as it goes: its body settles a few percent of its thickness and
    # that volume piles up at the toe. Without it the body would show no change at all
    # but texture, and its label would be a lace of holes.
    settle = rng.uniform(0.03, 0.08)
    toe = np.clip(moved - here, 0, None)
    dh -= settle * plan.depth_m * moved
    dh += toe * (settle * plan.depth_m * moved.sum() / max(toe.sum(), 1e-12))
    return dh, here > 0.5, {"displacement_m": shift, "settlement": settle}


def _shallow(
    u: np.ndarray, v: np.ndarray, plan: SlidePlan, pixel_size: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Soil slip: an elongated flat-floored scar, most of its soil in a lobe below."""
    length, width = plan.length_m, plan.width_m
    x, a = u / length, 2 * v / width
    scar_end = rng.uniform(0.55, 0.7)
    rim = _rim(width, pixel_size, 0.15)
    rim_x = rim * width / length
    side = smoothstep((1 - np.abs(a)) / rim)
    scar = smoothstep(x / rim_x) * smoothstep((scar_end - x) / (3 * rim_x)) * side
    start = scar_end - 0.05
    lobe = np.sin(np.pi * np.clip((x - start) / (1 - start), 0, 1)) ** 1.5
    lobe *= np.clip(1 - (a / 1.1) ** 2, 0, None)  # the lobe spreads a little wider
    kept = rng.uniform(0.8, 1.0)  # the rest washes away as muddy runoff
    dh = -scar + lobe * (kept * scar.sum() / max(lobe.sum(), 1e-12))
    return dh, np.zeros_like(scar, dtype=bool), {"scar_end": scar_end, "kept": kept}


def _deep_seated(
    u: np.ndarray, v: np.ndarray, plan: SlidePlan, pixel_size: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Deep-seated slide: main scarp with a graben below it, a subsiding body and a
    broad toe bulge. Boxy in plan (superellipse), as large slope failures are."""
    length, width = plan.length_m, plan.width_m
    x, a = u / length, 2 * v / width
    rho = (np.abs(2 * (x - 0.5)) ** 4 + np.abs(a) ** 4) ** 0.25
    edge = smoothstep((1 - rho) / _rim(min(length, width), pixel_size, 0.04))
    x_graben, w_graben = rng.uniform(0.08, 0.14), rng.uniform(0.02, 0.04)
    graben = np.exp(-(((x - x_graben) / w_graben) ** 2))
    x_mid = rng.uniform(0.6, 0.75)
    body = np.clip((x_mid - x) / x_mid, 0, 1)
    loss = edge * (0.6 * body + 0.5 * graben * np.clip(1 - a**2, 0, None))
    x_bulge = x_mid - 0.1
    bulge = np.sin(np.pi * np.clip((x - x_bulge) / (1 - x_bulge), 0, 1)) ** 2
    bulge = edge * bulge * np.clip(1 - a**4, 0, None)
    bulking = rng.uniform(1.0, 1.05)
    dh = -loss + bulge * (bulking * loss.sum() / max(bulge.sum(), 1e-12))
    return dh, edge > 0, {"graben_at": x_graben, "bulking": bulking}


def _debris_flow(
    s: np.ndarray,
    v: np.ndarray,
    plan: SlidePlan,
    total_m: float,
    pixel_size: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Source scar, a scoured channel with levees, and a lobate fan at the far end."""
    source, width = plan.length_m, plan.width_m
    rho = np.sqrt(((s - source / 2) / (source / 2)) ** 2 + (2 * v / width) ** 2)
    src = smoothstep((1 - rho) / _rim(min(source, width), pixel_size, 0.12)) * (1 - 0.5 * rho**2)
    channel_w = max(rng.uniform(0.3, 0.6) * width, 6 * pixel_size)
    fan_len = rng.uniform(0.2, 0.3) * (total_m - source)
    fan_start = total_m - fan_len
    fan_w = rng.uniform(1.5, 3.0) * width
    scour = rng.uniform(0.1, 0.3)  # channel scour depth / source depth
    in_channel = smoothstep((s - 0.8 * source) / (0.2 * source)) * smoothstep(
        (fan_start + 0.2 * fan_len - s) / (0.2 * fan_len)
    )
    half = channel_w / 2
    bed = np.where(np.abs(v) < half, np.cos(np.pi / 2 * v / half) ** 2, 0.0) * in_channel
    levee_x = np.clip((np.abs(v) - half) / half, 0, 1)
    levee = np.where((levee_x > 0) & (levee_x < 1), np.sin(np.pi * levee_x) ** 2, 0.0)
    levee *= in_channel * 0.3 * scour
    t = np.clip((s - fan_start) / fan_len, 0, None)
    fan_half = (channel_w + (fan_w - channel_w) * np.clip(t, 0, 1) ** 0.7) / 2
    fan = (
        smoothstep(t / 0.3)
        * smoothstep((total_m - s) / (0.12 * fan_len))
        * np.sqrt(np.clip(1 - (v / fan_half) ** 2, 0, None))
    )
    loss = src + scour * bed
    bulking = rng.uniform(1.0, 1.15)
    fan_scale = (bulking * loss.sum() - levee.sum()) / max(fan.sum(), 1e-12)
    dh = -loss + levee + max(fan_scale, 0.0) * fan
    return dh, {
        "runout_m": total_m - source,
        "channel_width_m": channel_w,
        "fan_width_m": fan_w,
        "bulking": bulking,
    }


def _rockfall(
    s: np.ndarray,
    v: np.ndarray,
    plan: SlidePlan,
    foot_m: float,
    pixel_size: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Small scar on the face; a talus cone and scattered blocks at the foot. Rock
    bulks as it breaks, so the deposit outweighs the scar (gain dominant)."""
    source, width = plan.length_m, plan.width_m
    rho = np.sqrt(((s - source / 2) / (source / 2)) ** 2 + (2 * v / width) ** 2)
    scar = smoothstep((1 - rho) / _rim(min(source, width), pixel_size, 0.15)) * (1 - 0.4 * rho**2)
    bulking = rng.uniform(1.3, 1.6)
    loss = scar.sum()
    # Cone of slope ~ tan 35° / 2 holding the bulked volume: radius from its volume.
    volume_px = bulking * loss * plan.depth_m  # in depth-scaled units
    radius = max((3 * volume_px * pixel_size**2 / (np.pi * 0.8 * 0.35)) ** (1 / 3), 4 * pixel_size)
    centre = foot_m + 0.3 * radius
    cone_r = np.sqrt(((s - centre) / radius) ** 2 + (v / (0.8 * radius)) ** 2)
    cone = np.clip(1 - cone_r, 0, None)
    blocks = np.zeros_like(s)
    n_blocks = int(rng.integers(3, 11))
    for _ in range(n_blocks):
        size = max(rng.uniform(0.5, 2.5), 2 * pixel_size)
        bs = centre + rng.uniform(0.3, 2.0) * radius
        bv = rng.normal(0.0, 0.8 * radius)
        height = rng.uniform(0.5, 1.0) * size / plan.depth_m
        soft = max(0.3 * size, pixel_size)
        blocks = np.maximum(
            blocks,
            height
            * smoothstep((size / 2 - np.abs(s - bs)) / soft)
            * smoothstep((size / 2 - np.abs(v - bv)) / soft),
        )
    target = bulking * loss - blocks.sum()
    if target <= 0:  # blocks alone exceed the volume: shrink them, no cone
        blocks *= bulking * loss / blocks.sum()
        target = 0.0
    dh = -scar + blocks + cone * (target / max(cone.sum(), 1e-12))
    return dh, {"foot_m": foot_m, "cone_radius_m": radius, "blocks": n_blocks, "bulking": bulking}


# ---------------------------------------------------------------- placement


def _finish(dh_win: np.ndarray, depth: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Scale to the drawn depth, cut to the footprint; None for an empty shape."""
    peak = np.abs(dh_win).max()
    if not np.isfinite(peak) or peak <= 0:
        return None
    dh_win = dh_win * (depth / peak)
    footprint = np.abs(dh_win) > max(FOOTPRINT_FLOOR_M, FOOTPRINT_FRACTION * depth)
    return np.where(footprint, dh_win, 0.0), footprint


def _clamped(plan: SlidePlan, shape: tuple[int, int], pixel_size: float, margin: int) -> SlidePlan:
    """The plan made realisable: at least MIN_* pixels, at most what fits the raster.

    A debris flow runs out 3-6 times its source length and a rockfall falls to the foot
    of its face, so their sources get a smaller share of the raster.
    """
    room = (min(shape) - 2 * margin) * pixel_size * 0.8
    room /= {"debris-flow": 5.0, "rockfall": 4.0}.get(plan.kind, 1.0)
    length = min(max(plan.length_m, MIN_LENGTH_PX * pixel_size), max(room, 12 * pixel_size))
    width = min(max(plan.width_m, MIN_WIDTH_PX * pixel_size), max(room, 8 * pixel_size))
    return SlidePlan(plan.kind, length, width, plan.depth_m)


@dataclass
class _Fields:
    body: _SlopeField  # at the slide's scale: where it sits, which way is down
    path: _SlopeField | None  # at the channel's scale: where a runout goes


def make_slide(
    plan: SlidePlan,
    ground: np.ndarray,
    pixel_size: float,
    rng: np.random.Generator,
    occupied: np.ndarray | None = None,
    slope_deg: tuple[float, float] | None = None,
    tries: int = 40,
    insist: bool = False,
) -> Slide | None:
    """Place `plan` on a slope of `ground` away from `occupied`; None if it cannot fit.

    Tries random slope pixels; after `tries` misses the slide shrinks by a fifth, up to
    three times. With `insist` (a pair's first slide: a pair must have one) it then
    goes on shrinking, on any slope, four more times.
    """
    shape = ground.shape
    margin = max(8, int(0.04 * min(shape)))
    blocked = (
        ndimage.binary_dilation(occupied, iterations=SEPARATION_PX)
        if occupied is not None and occupied.any()
        else None
    )
    plan = _clamped(plan, shape, pixel_size, margin)
    slopes = slope_deg or SLOPE_DEG[plan.kind]
    for shrink in range(8 if insist else 4):
        if shrink >= 4:
            slopes = (0.0, 90.0)
        if shrink:
            plan = SlidePlan(
                plan.kind,
                max(plan.length_m * 0.8, MIN_LENGTH_PX * pixel_size),
                max(plan.width_m * 0.8, MIN_WIDTH_PX * pixel_size),
                plan.depth_m,
            )
        fields = _Fields(
            _SlopeField(ground, pixel_size, 0.2 * plan.length_m / pixel_size),
            # The path follows the terrain at the channel's scale, not the slide's.
            _SlopeField(ground, pixel_size, max(0.5 * plan.width_m / pixel_size, 2.0))
            if plan.kind in ("debris-flow", "rockfall")
            else None,
        )
        half = int(min(plan.length_m, plan.width_m) / pixel_size / 2)
        inner = (
            slice(margin + half, max(shape[0] - margin - half, margin + half)),
            slice(margin + half, max(shape[1] - margin - half, margin + half)),
        )
        # Pixels' distance to another slide: centres closer than half this one's size,
        # and runout paths closer than half its width, cannot work.
        clearance = ndimage.distance_transform_edt(~blocked) if blocked is not None else None
        allowed = clearance > half if clearance is not None else None
        for centre in _candidates(fields.body, slopes, inner, rng, tries, allowed):
            slide = _attempt(
                plan, centre, fields, ground, pixel_size, rng, margin, blocked, clearance
            )
            if slide is None:
                continue
            if blocked is not None and (slide.footprint & blocked).any():
                continue
            slide.description["shrunk"] = shrink
            return slide
    return None


def _attempt(
    plan: SlidePlan,
    centre: np.ndarray,
    fields: _Fields,
    ground: np.ndarray,
    pixel_size: float,
    rng: np.random.Generator,
    margin: int,
    blocked: np.ndarray | None = None,
    clearance: np.ndarray | None = None,
) -> Slide | None:
    shape = ground.shape
    e = fields.body.downslope(float(centre[0]), float(centre[1]))
    length_px, width_px = plan.length_m / pixel_size, plan.width_m / pixel_size
    head = centre - e * length_px / 2
    describe: dict[str, Any] = {
        "kind": plan.kind,
        "length_m": plan.length_m,
        "width_m": plan.width_m,
        "depth_m": plan.depth_m,
        "head_rc": [float(head[0]), float(head[1])],
        "downslope_deg": float(np.degrees(np.arctan2(e[1], -e[0])) % 360),  # from north
        "slope_deg": float(fields.body.slope_deg[int(centre[0]), int(centre[1])]),
    }
    displacement = (0.0, 0.0)
    if plan.kind in ("debris-flow", "rockfall"):
        assert fields.path is not None
        built = _attempt_path(
            plan, head, e, fields.path, pixel_size, rng, margin, describe, clearance
        )
        if built is None:
            return None
        lo, hi, dh_win, s = built
        carried_win = np.zeros(dh_win.shape, dtype=bool)
    else:
        lo, hi = _straight_window(head, e, length_px, width_px)
        if not _inside(lo, hi, shape, margin):
            return None
        u, v = _local_uv(lo, hi, head, e, pixel_size)
        if blocked is not None:
            # Cheap test before building the shape: the body's box against other slides.
            body = (u >= 0) & (u <= plan.length_m) & (np.abs(v) <= plan.width_m / 2)
            if (body & blocked[lo[0] : hi[0], lo[1] : hi[1]]).any():
                return None
        s = u
        if plan.kind == "translational":
            texture = _texture_sampler(ground, lo, hi, e, pixel_size)
            dh_win, carried_win, extra = _translational(u, v, plan, pixel_size, rng, texture)
            shift = extra["displacement_m"]
        else:
            model = {"rotational": _rotational, "shallow": _shallow, "deep-seated": _deep_seated}
            dh_win, carried_win, extra = model[plan.kind](u, v, plan, pixel_size, rng)
            # Slumps and deep slides move their mass a fifth to a half of their depth.
            shift = rng.uniform(0.2, 0.5) * plan.depth_m
        describe.update(extra)
        if plan.kind in CARRYING:
            displacement = (float(e[0] * shift), float(e[1] * shift))
            describe["displacement_m"] = shift
    finished = _finish(dh_win, plan.depth_m)
    if finished is None:
        return None
    dh_win, foot_win = finished
    window = (slice(lo[0], hi[0]), slice(lo[1], hi[1]))
    dh = np.zeros(shape)
    footprint = np.zeros(shape, dtype=bool)
    carried = np.zeros(shape, dtype=bool)
    dh[window], footprint[window], carried[window] = dh_win, foot_win, carried_win
    length = float(s[foot_win].max() - s[foot_win].min())
    return Slide(plan.kind, dh, footprint, carried, displacement, length, describe)


def _texture_sampler(
    ground: np.ndarray, lo: np.ndarray, hi: np.ndarray, e: np.ndarray, pixel_size: float
) -> Callable[[float], tuple[np.ndarray, np.ndarray]]:
    """Surface texture (ground minus its 1 m smoothing) at the window's pixels and at the
    pixels `shift` metres upslope, where the slab material now at a pixel came from."""
    pad = 2
    r0, c0 = max(lo[0] - pad, 0), max(lo[1] - pad, 0)
    r1, c1 = min(hi[0] + pad, ground.shape[0]), min(hi[1] + pad, ground.shape[1])
    z = ground[r0:r1, c0:c1]
    tex = z - ndimage.gaussian_filter(z, max(1.0 / pixel_size, 1.5), mode="nearest")

    def sample(shift_m: float) -> tuple[np.ndarray, np.ndarray]:
        rr, cc = np.mgrid[lo[0] : hi[0], lo[1] : hi[1]].astype(float)
        here = tex[lo[0] - r0 : hi[0] - r0, lo[1] - c0 : hi[1] - c0]
        src_r = rr - e[0] * shift_m / pixel_size - r0
        src_c = cc - e[1] * shift_m / pixel_size - c0
        moved = ndimage.map_coordinates(tex, [src_r, src_c], order=1, mode="nearest")
        return here, moved

    return sample


def _attempt_path(
    plan: SlidePlan,
    head: np.ndarray,
    e: np.ndarray,
    path_field: _SlopeField,
    pixel_size: float,
    rng: np.random.Generator,
    margin: int,
    describe: dict[str, Any],
    clearance: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    shape = path_field.tan.shape
    source = plan.length_m
    # Paths keep half a width from other slides: checked while tracing, before any
    # shape is built (a debris flow's arrays can span much of the raster).
    keep_off = plan.width_m / pixel_size / 2
    if plan.kind == "debris-flow":
        total = source * (1 + rng.uniform(3.0, 6.0))
        traced = _trace(
            path_field,
            head,
            e,
            total / pixel_size,
            shape,
            margin,
            clearance=clearance,
            min_clearance=keep_off,
        )
        if traced is None:
            return None
        stations, _ = traced
        pad = 2.0 * plan.width_m / pixel_size + 3
        lo, hi, s, v = _path_coords(stations, pad, shape, pixel_size)
        dh_win, extra = _debris_flow(s, v, plan, total, pixel_size, rng)
    else:
        past = (0.6 * source + 20.0) / pixel_size  # room for the cone and the blocks
        traced = _trace(
            path_field,
            head,
            e,
            max(100.0, 6 * source) / pixel_size + past,
            shape,
            margin,
            inertia=0.5,
            stop_tan=np.tan(np.radians(22.0)),
            past_foot_px=past,
            clearance=clearance,
            min_clearance=keep_off,
        )
        if traced is None:
            return None
        stations, foot = traced
        if foot is None:  # no foot within reach: the blocks stop where the path ends
            foot = max(len(stations) - 1 - int(past), 1)
        foot_m = max(foot * pixel_size, 1.2 * source)
        pad = 2.0 * plan.width_m / pixel_size + 20.0 / pixel_size
        lo, hi, s, v = _path_coords(stations, pad, shape, pixel_size)
        dh_win, extra = _rockfall(s, v, plan, foot_m, pixel_size, rng)
    # The path may fit while its deposit or levees reach the edge: reject that.
    nz = np.nonzero(np.abs(dh_win) > FOOTPRINT_FRACTION * np.abs(dh_win).max())
    if nz[0].size == 0:
        return None
    if not _inside(
        np.array([lo[0] + nz[0].min(), lo[1] + nz[1].min()]),
        np.array([lo[0] + nz[0].max() + 1, lo[1] + nz[1].max() + 1]),
        shape,
        margin,
    ):
        return None
    describe.update(extra)
    return lo, hi, dh_win, s


# ---------------------------------------------------------------- one slide, by kind

SlideArrays = tuple[np.ndarray, np.ndarray, SlideTruth]


def place_slide(
    kind: str,
    ground: np.ndarray,
    pixel_size: float,
    rng: np.random.Generator,
    length_m: float,
    depth_m: float,
    width_m: float | None = None,
    occupied: np.ndarray | None = None,
    slide_id: int = 1,
) -> SlideArrays | None:
    """A slide of `kind` (one of KINDS) placed on `ground`: (dh, footprint, truth), or None
    when it cannot fit. `length_m` is the slide's length; for a debris flow its source's,
    for a rockfall its scar's."""
    if kind not in KINDS:
        raise ValueError(f"unknown slide kind {kind!r}; kinds are {', '.join(KINDS)}")
    width = length_m * float(np.mean(WIDTH_RATIO[kind])) if width_m is None else width_m
    slide = make_slide(SlidePlan(kind, length_m, width, depth_m), ground, pixel_size, rng, occupied)
    if slide is None:
        return None
    return slide.dh, slide.footprint, slide.truth(slide_id, pixel_size)
