"""One step of a site's history: landslides, then the changes that are not landslides.

`advance` applies the step's slides to the ground (each conserving volume), makes the
trees standing on moving ground fall (carried with the mass and left lying on the
deposit) or vanish (buried), and only then applies nuisance changes (vegetation
growth, small surface changes) outside the slides. The landslide mask is computed
between the previous DSM and the DSM with the slides but without the nuisance, so it
covers exactly the cells whose elevation the slides changed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from worker.simulator.landslide import SlideResult, SlideSpec, apply_slide
from worker.simulator.terrain import Scene
from worker.simulator.texture import LOG
from worker.simulator.vegetation import Trees

STABLE, DEPLETION, DEPOSITION = 0, 1, 2
MASK_CLASSES = {
    "0": "stable",
    "1": "depletion (surface lowered)",
    "2": "deposition (surface raised)",
}


@dataclass
class StepChange:
    """What happened between the previous step and this one."""

    slides: list[SlideResult]
    dsm_before: np.ndarray
    dsm_slides_only: np.ndarray
    mask: np.ndarray  # uint8 classes, see MASK_CLASSES
    events: np.ndarray  # uint8: 1-based index into `slides`, 0 elsewhere
    fallen_trees: int = 0
    vanished_trees: int = 0
    nuisance: dict = field(default_factory=dict)


NuisanceFn = Callable[[Scene, np.ndarray, np.random.Generator], dict]
"""Changes a scene in place outside the `protect` mask; returns a description."""


def advance(
    scene: Scene,
    slides: list[SlideSpec],
    nuisance: NuisanceFn | None,
    rng: np.random.Generator,
    dsm_before: np.ndarray | None = None,
    tree_fall_probability: float = 0.6,
) -> tuple[Scene, StepChange]:
    """The next step of `scene` (a new object; `scene` is not modified)."""
    if dsm_before is None:
        dsm_before, _ = scene.compose()
    nxt = scene.copy()
    grid = nxt.grid
    if nxt.disturbed is None:
        nxt.disturbed = np.zeros(grid.shape, np.float32)
    results: list[SlideResult] = []
    ground_changed = np.zeros(grid.shape, np.uint8)
    trees = nxt.trees
    fallen_total = vanished_total = 0
    for k, spec in enumerate(slides, start=1):
        res = apply_slide(nxt.ground, grid, spec, rng, floor=nxt.floor)
        results.append(res)
        win = (res.rows, res.cols)
        nxt.ground[win] += res.delta
        ch = res.changed
        ground_changed[win][ch] = k
        nxt.disturbed[win] += np.abs(res.delta).astype(np.float32)
        nxt.surface[win][ch] = 0.0
        trees, fallen, vanished = _topple(trees, res, nxt, rng, tree_fall_probability)
        fallen_total += fallen
        vanished_total += vanished
    nxt.trees = trees
    dsm_slides, _ = nxt.compose()
    diff = dsm_slides - dsm_before
    mask = np.zeros(grid.shape, np.uint8)
    mask[diff < 0] = DEPLETION
    mask[diff > 0] = DEPOSITION
    events = ground_changed.copy()
    orphan = (mask > 0) & (events == 0)
    if orphan.any() and results:
        # DSM changes off the moved ground (crowns of trees that fell) belong to the
        # nearest slide.
        _, (ri, ci) = ndimage.distance_transform_edt(events == 0, return_indices=True)
        events[orphan] = events[ri[orphan], ci[orphan]]
    nuis = {}
    if nuisance is not None:
        protect = (mask > 0) | (events > 0)
        nuis = nuisance(nxt, protect, rng)
    return nxt, StepChange(
        slides=results,
        dsm_before=dsm_before,
        dsm_slides_only=dsm_slides,
        mask=mask,
        events=events,
        fallen_trees=fallen_total,
        vanished_trees=vanished_total,
        nuisance=nuis,
    )


def _topple(
    trees: Trees, res: SlideResult, scene: Scene, rng: np.random.Generator, p_fall: float
) -> tuple[Trees, int, int]:
    """Trees rooted on ground the slide moved fall (carried downslope, lying along the
    movement) or vanish."""
    if len(trees) == 0:
        return trees, 0, 0
    grid = scene.grid
    col, row = grid.col_row(trees.x, trees.y)
    ri = np.rint(row).astype(int) - res.rows.start
    ci = np.rint(col).astype(int) - res.cols.start
    h, w = res.depletion.shape
    inside = (ri >= 0) & (ri < h) & (ci >= 0) & (ci < w) & (trees.kind != LOG)
    hit = np.zeros(len(trees), bool)
    idx = np.flatnonzero(inside)
    moved = (res.depletion[ri[idx], ci[idx]] > 0) | (res.deposition[ri[idx], ci[idx]] > 0.3)
    hit[idx[moved]] = True
    if not hit.any():
        return trees, 0, 0
    victims = trees.select(hit)
    keep = trees.select(~hit)
    falls = rng.random(len(victims)) < p_fall
    logs = victims.select(falls)
    n = len(logs)
    if n:
        dx, dy = res.displacement
        carry = rng.uniform(0.6, 1.0, n)
        logs.x = logs.x + dx * carry + rng.normal(0, 0.1 * res.spec.width_m, n) * 0.2
        logs.y = logs.y + dy * carry + rng.normal(0, 0.1 * res.spec.width_m, n) * 0.2
        logs.z_base = scene.height_at(logs.x, logs.y)
        logs.azimuth = res.spec.azimuth_deg + rng.normal(0, 25.0, n)
        # Lying tree: length ~ its height, half-width ~ 70 % of the crown radius, and
        # a height of about 80 % of the crown radius (capped at 1.5 m).
        logs.height = logs.height * 0.9
        logs.crown_depth = np.minimum(logs.crown_radius * 0.8, 1.5)
        logs.crown_radius = logs.crown_radius * 0.7
        logs.kind = np.full(n, LOG, np.int8)
    return Trees.concat([keep, logs]), n, len(victims) - n
