"""The registry of pair generators: terrain + slides + surface + errors, seeded.

A pair is built from six independent random streams (grid, terrain, slide plan, slide
placement, surface, errors) spawned from (generator name, seed). The no-change twin
runs the same streams and simply skips the placement, so its terrain, surface changes
and errors are those of the pair, draw for draw.

Depth classes. What decides whether a slide can be found is not its depth in metres
but its depth relative to the pair's level of detection (LoD = 1.96 x the NMAD of the
observation error), and its size in pixels. Every generator states its sizes in metres
for its pixel size (agri-shallow's 1-5 m slumps at 2-5 cm pixels span 20-250 pixels,
fractal-forest's 25-60 m slides at 20 cm 125-300), and each pair draws its noise level
so that its shallowest slide lands in a drawn depth class: 12 % near the noise floor
(0.5-1 LoD), 13 % at 1-3 LoD, 75 % at 3-12 LoD. The generator's noise range caps this:
fractal-forest's 5-15 cm noise under 1.5-6 m slides never goes below ~2 LoD.
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from worker.pairgen.errors import apply_errors, draw_errors
from worker.pairgen.pair import DsmPair
from worker.pairgen.slides import Slide, SlideSpec, make_slide
from worker.pairgen.surfaces import apply_slides, make_surface, render
from worker.pairgen.terrain import make_terrain

LOD_Z = 1.96
SURFACE_CHANGE_M = 0.3
# (share, lowest, highest) target depth of the shallowest slide, in LoDs.
DEPTH_MIX = ((0.12, 0.5, 1.0), (0.13, 1.0, 3.0), (0.75, 3.0, 12.0))
# NMAD of a difference of two surveys with independent Gaussian noise of std sigma.
NMAD_PER_SIGMA = float(np.sqrt(2.0))
STREAMS = ("grid", "terrain", "plan", "place", "surface", "errors")


@dataclass
class PairParts:
    """A pair with the intermediate surfaces it was made from (for tests and reports)."""

    pair: DsmPair
    ground_pre: np.ndarray
    ground_post: np.ndarray
    pre_true: np.ndarray  # DSMs without observation errors
    post_true: np.ndarray
    surface_heights: np.ndarray  # (post_true - ground_post) - (pre_true - ground_pre)
    sigma_m: float


@dataclass(frozen=True)
class PairGenerator:
    """One family of pairs. `make(seed)` is deterministic; `make(seed, True)` is its twin."""

    name: str
    summary: str
    terrain: str
    slide_specs: tuple[SlideSpec, ...]
    surface: str
    errors: tuple[str, ...]
    pixel_size: tuple[float, float]  # metres, drawn uniformly per pair
    noise_sigma_m: tuple[float, float]  # per-survey noise level, drawn per pair
    side_px: tuple[int, int] = (384, 640)  # rows and cols drawn independently
    terrain_params: Mapping[str, Any] = field(default_factory=dict)
    surface_params: Mapping[str, Any] = field(default_factory=dict)
    error_params: Mapping[str, Any] = field(default_factory=dict)
    depth_mix: tuple[tuple[float, float, float], ...] = DEPTH_MIX
    # Typical NMAD of the observation error per unit sigma: sqrt(2) for noise alone,
    # more where registration, strips or doming add theirs (measured over 30 seeds).
    nmad_per_sigma: float = NMAD_PER_SIGMA

    @property
    def slides(self) -> tuple[str, ...]:
        return tuple(spec.kind for spec in self.slide_specs)

    def make(self, seed: int, no_change: bool = False) -> DsmPair:
        """Pair `seed`; with `no_change`, its twin: same draws, no slides."""
        return self.build(seed, no_change).pair

    def build(self, seed: int, no_change: bool = False) -> PairParts:
        """`make`, keeping the surfaces the pair was made from."""
        return _build(self, seed, no_change)


def _streams(name: str, seed: int) -> dict[str, np.random.Generator]:
    # crc32, not hash(): Python salts str hashes per process.
    root = np.random.SeedSequence([zlib.crc32(name.encode()), int(seed)])
    return {
        k: np.random.default_rng(s) for k, s in zip(STREAMS, root.spawn(len(STREAMS)), strict=True)
    }


def _draw_sigma(
    gen: PairGenerator, depth_m: float, rng: np.random.Generator
) -> tuple[float, float]:
    """Noise level putting a slide of `depth_m` at a drawn depth (in LoDs), clipped to
    the generator's range; returns (sigma, target LoDs)."""
    shares = np.array([m[0] for m in gen.depth_mix])
    lo, hi = gen.depth_mix[int(rng.choice(len(shares), p=shares / shares.sum()))][1:]
    target = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
    sigma = depth_m / (LOD_Z * target * gen.nmad_per_sigma)
    return float(np.clip(sigma, *gen.noise_sigma_m)), target


def _nmad(values: np.ndarray) -> float:
    v = values[np.isfinite(values)]
    if v.size == 0:
        return float("nan")
    return float(1.4826 * np.median(np.abs(v - np.median(v))))


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _build(gen: PairGenerator, seed: int, no_change: bool) -> PairParts:
    rng = _streams(gen.name, seed)
    shape = (
        int(rng["grid"].integers(gen.side_px[0], gen.side_px[1] + 1)),
        int(rng["grid"].integers(gen.side_px[0], gen.side_px[1] + 1)),
    )
    pixel = round(float(rng["grid"].uniform(*gen.pixel_size)), 4)
    # The plan is drawn for the twin too: the noise level depends on it.
    n_slides = 1 + int(rng["plan"].uniform() < 0.5)
    specs = [
        gen.slide_specs[int(rng["plan"].integers(len(gen.slide_specs)))] for _ in range(n_slides)
    ]
    plans = [spec.draw(rng["plan"]) for spec in specs]
    # The shallowest slide gets the drawn depth class; a second one can only be deeper.
    sigma, target = _draw_sigma(gen, min(p.depth_m for p in plans), rng["plan"])

    features: dict[str, np.ndarray] = {}
    ground_pre = make_terrain(
        gen.terrain, shape, pixel, rng["terrain"], gen.terrain_params, features
    )
    slides: list[Slide] = []
    if not no_change:
        occupied = np.zeros(shape, dtype=bool)
        for spec, plan in zip(specs, plans, strict=True):
            slide = make_slide(
                plan, ground_pre, pixel, rng["place"], occupied, spec.slope_deg, insist=not slides
            )
            if slide is not None:
                slides.append(slide)
                occupied |= slide.footprint
    true_dh = np.zeros(shape)
    labels = np.zeros(shape, dtype=np.int16)
    moving = np.zeros(shape, dtype=bool)  # footprints and the masses that carry trees
    for i, slide in enumerate(slides, start=1):
        true_dh += slide.dh
        labels[slide.footprint] = i
        moving |= slide.footprint | slide.carried
    ground_post = ground_pre + true_dh

    surface = make_surface(
        gen.surface, ground_pre, pixel, rng["surface"], gen.surface_params, features
    )
    pre_true = render(surface.pre, ground_pre, pixel)
    post_true = render(apply_slides(surface.post, slides, pixel), ground_post, pixel)
    surface_heights = (post_true - ground_post) - (pre_true - ground_pre)
    # Slides need no mark (nor trees riding on them); elsewhere every change > 0.3 m is
    # a surface change, including a crown overhanging a slide whose tree the slide took.
    surface_change = (np.abs(surface_heights) > SURFACE_CHANGE_M) & ~moving

    errors = draw_errors(gen.errors, shape, pixel, sigma, rng["errors"], gen.error_params)
    pre, post = apply_errors(errors, pre_true, post_true)
    observation_error = (post - post_true) - (pre - pre_true)
    nmad = _nmad(observation_error)
    truths = [s.truth(i, pixel) for i, s in enumerate(slides, start=1)]
    description = {
        "summary": gen.summary,
        "terrain": gen.terrain,
        "surface": surface.description,
        "errors": errors.description,
        "noise_sigma_m": sigma,
        "target_depth_lod": target,
        "planned_slides": [
            {"kind": p.kind, "length_m": p.length_m, "width_m": p.width_m, "depth_m": p.depth_m}
            for p in plans
        ],
        "slides": [
            {**s.description, "depth_lod": t.max_depth_m / (LOD_Z * nmad) if nmad > 0 else None}
            for s, t in zip(slides, truths, strict=True)
        ],
    }
    pair = DsmPair(
        generator=gen.name,
        seed=int(seed),
        pixel_size=pixel,
        pre=pre.astype(np.float32),
        post=post.astype(np.float32),
        true_dh=true_dh.astype(np.float32),
        slide_labels=labels,
        slides=truths,
        surface_change=surface_change,
        observation_error=observation_error.astype(np.float32),
        no_change=bool(no_change),
        description=_jsonable(description),
    )
    return PairParts(pair, ground_pre, ground_post, pre_true, post_true, surface_heights, sigma)


GENERATORS: dict[str, PairGenerator] = {
    g.name: g
    for g in (
        PairGenerator(
            name="fractal-forest",
            summary="Fractal 20-45° hillslope under forest (cover 5-80 %, growth and felling), "
            "0.2 m pixels; rotational or translational slides 25-60 m long, 1.5-6 m deep; "
            "white noise 5-15 cm and a post registration error up to 2.5 px and 0.5 m.",
            terrain="fractal",
            slide_specs=(
                SlideSpec("rotational", (25.0, 60.0), (1.5, 6.0)),
                SlideSpec("translational", (25.0, 60.0), (1.5, 6.0)),
            ),
            surface="forest",
            errors=("white", "shift"),
            pixel_size=(0.2, 0.2),
            noise_sigma_m=(0.05, 0.15),
            nmad_per_sigma=2.3,
            error_params={"shift_px": (0.2, 2.5), "vertical_m": 0.5},
        ),
        PairGenerator(
            name="ridge-debris",
            summary="Ridges and valleys under grass, 0.1-0.3 m pixels; debris flows "
            "(3-6x runout) and shallow slips; correlated noise, doming and tilt.",
            terrain="ridge-valley",
            slide_specs=(
                SlideSpec("debris-flow", (4.0, 15.0), (0.5, 3.0)),
                SlideSpec("shallow", (4.0, 20.0), (0.3, 1.0)),
            ),
            surface="grass",
            errors=("correlated", "doming", "tilt"),
            pixel_size=(0.1, 0.3),
            noise_sigma_m=(0.02, 0.25),
            nmad_per_sigma=1.7,
        ),
        PairGenerator(
            name="terraced-strips",
            summary="Terraced slope (1-3 m risers), bare or grass, 0.05-0.1 m pixels; "
            "translational and shallow slides; flight-strip steps, inpainted holes, white "
            "noise.",
            terrain="terraced",
            slide_specs=(
                SlideSpec("translational", (4.0, 20.0), (0.4, 2.0), slope_deg=(12.0, 60.0)),
                SlideSpec("shallow", (3.0, 12.0), (0.3, 1.0), slope_deg=(12.0, 60.0)),
            ),
            surface="grass",
            surface_params={"bare_chance": 0.5},
            errors=("white", "strips", "holes"),
            pixel_size=(0.05, 0.1),
            noise_sigma_m=(0.01, 0.12),
            nmad_per_sigma=2.0,
        ),
        PairGenerator(
            name="agri-shallow",
            summary="Gentle fields (< 10°, parcel banks, a ditch, furrows) under growing "
            "grass, 0.02-0.05 m pixels; shallow slips and small slumps 1-5 m long, "
            "0.05-0.5 m deep; white + correlated noise, post at half or third resolution.",
            terrain="agricultural",
            slide_specs=(
                SlideSpec("shallow", (1.0, 5.0), (0.05, 0.5), slope_deg=(3.0, 40.0)),
                SlideSpec("rotational", (1.0, 5.0), (0.05, 0.5), slope_deg=(3.0, 40.0)),
            ),
            surface="grass",
            surface_params={"height_m": (0.05, 0.25)},
            errors=("white", "correlated", "resolution"),
            pixel_size=(0.02, 0.05),
            noise_sigma_m=(0.005, 0.05),
            nmad_per_sigma=1.5,
            error_params={"correlation_m": (0.1, 3.0)},
        ),
        PairGenerator(
            name="urban-rockfall",
            summary="Town with buildings 4-25 m (some demolished, some built) below a "
            "40-55° cut slope, 0.25-0.5 m pixels; rockfalls and translational slides on "
            "the cut; outlier spikes, holes, post rotated up to 0.2°, white noise.",
            terrain="urban",
            slide_specs=(
                SlideSpec("rockfall", (3.0, 12.0), (0.5, 4.0)),
                SlideSpec("translational", (10.0, 40.0), (1.0, 5.0), slope_deg=(30.0, 70.0)),
            ),
            surface="urban",
            errors=("white", "outliers", "holes", "rotation"),
            pixel_size=(0.25, 0.5),
            noise_sigma_m=(0.03, 0.3),
            nmad_per_sigma=1.5,
        ),
        PairGenerator(
            name="mountain-deep",
            summary="Steep (30-50°) mountain flank with sparse forest, 0.5-1 m pixels; "
            "deep-seated slides 10-20 m deep and debris flows; correlated noise, tilt and "
            "a post shift up to 3 px.",
            terrain="mountain",
            slide_specs=(
                SlideSpec("deep-seated", (80.0, 300.0), (10.0, 20.0)),
                SlideSpec("debris-flow", (10.0, 40.0), (1.0, 5.0)),
            ),
            surface="forest",
            surface_params={"density": (0.05, 0.25)},
            errors=("correlated", "tilt", "shift"),
            pixel_size=(0.5, 1.0),
            noise_sigma_m=(0.1, 1.0),
            nmad_per_sigma=1.8,
            error_params={"shift_px": (0.2, 3.0), "vertical_m": 0.5},
        ),
        PairGenerator(
            name="real-relief",
            summary="Real Appalachian relief (matplotlib's sample USGS DEM of the Jacksboro "
            "fault) scaled down with its slopes kept, under forest (cover 5-40 %), 0.5-1 m "
            "pixels; rotational slumps 20-70 m, 1-8 m deep, and debris flows; white + "
            "correlated noise, tilt and a post shift up to 2 px.",
            terrain="real",
            slide_specs=(
                SlideSpec("rotational", (20.0, 70.0), (1.0, 8.0)),
                SlideSpec("debris-flow", (8.0, 25.0), (1.0, 4.0)),
            ),
            surface="forest",
            surface_params={"density": (0.05, 0.4)},
            errors=("white", "correlated", "tilt", "shift"),
            pixel_size=(0.5, 1.0),
            noise_sigma_m=(0.05, 0.6),
            nmad_per_sigma=2.6,
            error_params={"shift_px": (0.2, 2.0), "vertical_m": 0.5},
        ),
    )
}


def make_pair(name: str, seed: int, no_change: bool = False) -> DsmPair:
    """Pair `seed` of generator `name` (its no-change twin with `no_change`)."""
    if name not in GENERATORS:
        raise KeyError(f"unknown generator {name!r}; available: {', '.join(GENERATORS)}")
    return GENERATORS[name].make(seed, no_change)
