"""Landslides on a height field that conserve volume.

A slide is described geometrically (`SlideSpec`):

- **Source.** A failure surface made of a basal plane that daylights at the toe and
  dips downslope at `failure_angle_deg` (gentler than the slope, so the slide is deeper
  upslope), a head scarp rising at `head_angle_deg` beyond `length_m` upslope of the
  toe, and flanks rising at `flank_angle_deg` outside an elliptical planform of width
  `width_m`. Everything above that surface is depleted (optionally never below a
  non-erodible floor). With head and flank angles at or below the angle of repose the
  scar is stable; steeper values make the cohesive scarps of real soil slides.
- **Deposit.** The depleted volume comes to rest downslope as a debris fan: an
  elliptical cone with a rounded top centred `runout_m` beyond the toe, elongated
  along the movement, with flanks at `deposit_angle_deg` (which must exceed the
  slope it rests on). Its apex height is solved (bisection)
  so that the deposit holds exactly the depleted volume (times `bulking`), then the
  thickness is rescaled so that the two volumes agree to rounding error. Because the
  deposit surface never exceeds the deposit angle, no slope relaxation is needed.

Changes thinner than `min_change_m` are dropped before volumes are balanced (the final
rescaling moves thicknesses by well under a percent), so the changed cells are those
whose elevation moved by about that much or more, and no others.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from worker.simulator.georef import Grid
from worker.simulator.texture import fbm


@dataclass(frozen=True)
class SlideSpec:
    """Geometry of one landslide event (local metres, degrees)."""

    name: str
    toe_xy: tuple[float, float]
    azimuth_deg: float
    length_m: float
    width_m: float
    failure_angle_deg: float
    head_angle_deg: float = 34.0
    flank_angle_deg: float = 32.0
    runout_m: float = 2.0
    deposit_angle_deg: float = 18.0
    deposit_spread: float = 0.6
    """Radius of the rounded top of the deposit fan, relative to the source half-width."""
    deposit_elongation: float = 1.6
    """The fan is this many times longer along the movement than across it."""
    floor_z: float | None = None
    """Material below this height does not move (e.g. the firm floor under a sand pile)."""
    roughness: float = 0.04
    """Relative roughness of the failure surface and of the deposit."""
    bulking: float = 1.0
    min_change_m: float = 0.001
    label: str = ""

    @property
    def direction(self) -> np.ndarray:
        a = np.radians(self.azimuth_deg)
        return np.array([np.sin(a), np.cos(a)])


@dataclass
class SlideResult:
    """What a slide did. Arrays cover the window `rows, cols` of the scene grid."""

    spec: SlideSpec
    rows: slice
    cols: slice
    depletion: np.ndarray
    deposition: np.ndarray
    depleted_m3: float
    deposited_m3: float
    volume_error_m3: float
    relative_volume_error: float
    depleted_area_m2: float
    deposited_area_m2: float
    max_depth_m: float
    max_thickness_m: float
    source_centroid: tuple[float, float]
    deposit_centroid: tuple[float, float]
    apex_iterations: int
    extra: dict = field(default_factory=dict)

    @property
    def delta(self) -> np.ndarray:
        """Elevation change in the window (deposition - depletion)."""
        return self.deposition - self.depletion

    @property
    def changed(self) -> np.ndarray:
        return (self.depletion > 0) | (self.deposition > 0)

    @property
    def displacement(self) -> tuple[float, float]:
        return (
            self.deposit_centroid[0] - self.source_centroid[0],
            self.deposit_centroid[1] - self.source_centroid[1],
        )

    def summary(self) -> dict:
        return {
            "name": self.spec.name,
            "label": self.spec.label,
            "depleted_m3": round(self.depleted_m3, 6),
            "deposited_m3": round(self.deposited_m3, 6),
            "volume_error_m3": float(f"{self.volume_error_m3:.3e}"),
            "relative_volume_error": float(f"{self.relative_volume_error:.3e}"),
            "depleted_area_m2": round(self.depleted_area_m2, 4),
            "deposited_area_m2": round(self.deposited_area_m2, 4),
            "max_depth_m": round(self.max_depth_m, 4),
            "max_thickness_m": round(self.max_thickness_m, 4),
            "source_centroid_local": [round(v, 3) for v in self.source_centroid],
            "deposit_centroid_local": [round(v, 3) for v in self.deposit_centroid],
            "spec": {k: v for k, v in asdict(self.spec).items() if k not in ("name", "label")},
        }


class _WindowTooSmall(Exception):
    pass


def _window_for(spec: SlideSpec, grid: Grid, scale: float = 1.0):
    d = spec.direction
    toe = np.asarray(spec.toe_xy, float)
    reach_up = (spec.length_m + spec.width_m) * scale
    reach_down = (spec.runout_m * 1.6 + spec.width_m * 1.5 + 2.0) * scale
    half = (spec.width_m * 1.5 + spec.runout_m * 0.6 + 2.0) * scale
    n = np.array([d[1], -d[0]])
    corners = []
    for a in (-reach_up, reach_down):
        for b in (-half, half):
            corners.append(toe + a * d + b * n)
    c = np.array(corners)
    return grid.window(c[:, 0].min(), c[:, 1].min(), c[:, 0].max(), c[:, 1].max())


def apply_slide(
    ground: np.ndarray,
    grid: Grid,
    spec: SlideSpec,
    rng: np.random.Generator,
    floor: np.ndarray | None = None,
) -> SlideResult:
    """Compute the slide `spec` on `ground` (not modified). Add `result.delta` to
    `ground[result.rows, result.cols]` to apply it. `floor` (same grid as `ground`), if
    given, is a non-erodible surface the failure cannot cut below."""
    state = rng.bit_generator.state
    for scale in (1.0, 1.6, 2.6, 4.2):
        rng.bit_generator.state = state  # the same noise whatever the window
        try:
            return _apply_slide(ground, grid, spec, rng, floor, scale)
        except _WindowTooSmall:
            continue
    raise ValueError(f"slide {spec.name!r} does not fit in the scene: check its geometry")


def _apply_slide(ground, grid, spec, rng, floor, scale) -> SlideResult:
    rows, cols = _window_for(spec, grid, scale)
    sub = grid.sub(rows, cols)
    g = ground[rows, cols].astype(np.float64)
    fl = None
    if floor is not None:
        fl = floor[rows, cols].astype(np.float64)
    if spec.floor_z is not None:
        fl = np.full_like(g, spec.floor_z) if fl is None else np.maximum(fl, spec.floor_z)
    xs, ys = sub.mesh()
    d = spec.direction
    toe = np.asarray(spec.toe_xy, float)
    u = (xs - toe[0]) * d[0] + (ys - toe[1]) * d[1]  # downslope distance from the toe
    v = (xs - toe[0]) * d[1] - (ys - toe[1]) * d[0]  # across-slope distance
    col, row = sub.col_row(toe[0], toe[1])
    ri = int(np.clip(np.rint(row), 0, g.shape[0] - 1))
    ci = int(np.clip(np.rint(col), 0, g.shape[1] - 1))
    # On a non-erodible floor the rupture daylights on the floor itself (under any
    # earlier deposit lying at the toe).
    z_toe = g[ri, ci] if fl is None else fl[ri, ci]

    tb = np.tan(np.radians(spec.failure_angle_deg))
    th = np.tan(np.radians(spec.head_angle_deg))
    tf = np.tan(np.radians(spec.flank_angle_deg))
    length = spec.length_m
    plane = z_toe - tb * u
    head = z_toe + tb * length + th * (-length - u)
    base = np.where(u < -length, head, plane)
    base = np.maximum(base, z_toe + tf * u)  # the surface rises again beyond the toe
    # Elliptical planform, a little longer than the source so it does not pinch shut.
    half_len = length / 2.0 + spec.width_m / 4.0
    shape = np.sqrt(np.clip(1.0 - ((u + length / 2.0) / half_len) ** 2, 0.0, 1.0))
    half_w = spec.width_m / 2.0 * shape
    surface = base + tf * np.maximum(np.abs(v) - half_w, 0.0)
    noise = fbm(g.shape, rng, [max(1.0, 1.5 / grid.res * spec.width_m / 10.0)], [1.0])
    scale_z = spec.roughness * (length * (np.tan(np.radians(30.0)) - tb) + 0.05)
    surface = surface + scale_z * noise
    if fl is not None:
        surface = np.maximum(surface, fl)
    depletion = np.clip(g - surface, 0.0, None)
    depletion[depletion < spec.min_change_m] = 0.0
    cell = grid.cell_area
    v_dep = float(depletion.sum() * cell)
    if v_dep <= 0:
        raise ValueError(f"slide {spec.name!r} removes no material: check its geometry")
    after_dep = g - depletion

    # Deposit: a fan around the point `runout_m` beyond the toe, elongated along the
    # movement, with a rounded top and flanks at the deposit angle.
    td = np.tan(np.radians(spec.deposit_angle_deg))
    du = (u - spec.runout_m) / spec.deposit_elongation
    r0 = spec.deposit_spread * spec.width_m / 2.0
    dist = np.sqrt(du * du + v * v + r0 * r0) - r0
    lobes = fbm(g.shape, rng, [max(1.0, spec.width_m / 4.0 / grid.res)], [1.0])
    dist = dist * (1.0 + 0.5 * spec.roughness * 4 * lobes)
    target = v_dep * spec.bulking

    def volume(apex: float) -> tuple[float, np.ndarray]:
        t = np.clip(apex - td * dist - after_dep, 0.0, None)
        return float(t.sum() * cell), t

    lo = float(after_dep.min())
    hi = float(after_dep.max()) + target / cell + 1.0
    iterations = 0
    thick = np.zeros_like(g)
    for iterations in range(1, 101):  # noqa: B007 - reported below
        mid = 0.5 * (lo + hi)
        vol, thick = volume(mid)
        if abs(vol - target) <= 1e-10 * target:
            break
        if vol < target:
            lo = mid
        else:
            hi = mid
    # Texture of the deposit surface, then exact volume balance.
    thick = thick * (1.0 + spec.roughness * np.clip(noise, -2.5, 2.5))
    thick[thick < spec.min_change_m] = 0.0
    thick *= target / float(thick.sum() * cell)
    # The slide touches the window border only if the window is too small.
    for a in (thick, depletion):
        if a[0, :].any() or a[-1, :].any() or a[:, 0].any() or a[:, -1].any():
            raise _WindowTooSmall

    v_acc = float(thick.sum() * cell)
    err = v_acc - v_dep * spec.bulking

    def centroid(wts: np.ndarray) -> tuple[float, float]:
        s = float(wts.sum())
        return float((xs * wts).sum() / s), float((ys * wts).sum() / s)

    return SlideResult(
        spec=spec,
        rows=rows,
        cols=cols,
        depletion=depletion,
        deposition=thick,
        depleted_m3=v_dep,
        deposited_m3=v_acc,
        volume_error_m3=err,
        relative_volume_error=abs(err) / v_dep,
        depleted_area_m2=float((depletion > 0).sum() * cell),
        deposited_area_m2=float((thick > 0).sum() * cell),
        max_depth_m=float(depletion.max()),
        max_thickness_m=float(thick.max()),
        source_centroid=centroid(depletion),
        deposit_centroid=centroid(thick),
        apex_iterations=iterations,
    )
