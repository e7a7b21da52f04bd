"""Pairs of DSMs that slidewatch reconstructed from simulated survey video.

The other generators draw DSMs with errors modelled on what photogrammetry does; these
are what the reconstruction pipeline really makes: the survey simulator renders a video
with its DJI SRT log over the real-scale hillslope, before and after 1-3 random slides
(`slidewatch simulate --scenario hillslope --random-slides N`), and each survey goes
through the same stages as `slidewatch reconstruct` (visual SLAM, trajectory
georeferencing without ground control, DSM with inpainting). The DSMs are put on one
grid at the reconstruction's resolution as they came out, georeferencing error
included: co-registering them is the comparison's job. The twin is the same seed
simulated without slides (`--no-slides`: vegetation growth and small surface changes
only).

Truth comes from the simulator: slide ids from its event raster, the ground change of
the slides from its DEMs, surface changes from its DSMs minus DEMs (trees grown or
felled), the observation error from the reconstructions minus the true DSMs. The flight
covers part of the simulated area: the pair is cut to where both surveys have
elevations, and a slide the surveys saw less than a quarter of is left out (its pixels
become nodata), neither to be found nor a false alarm.

Simulating and reconstructing take minutes per pair, so every step is cached under
`cache_dir` (the benchmark's work dir): a simulation with its manifest, a
reconstruction with its summary, are complete and never redone. A flight that fails to
reconstruct makes the pair unavailable (PairUnavailable, with the reason): the
benchmark reports it and goes on.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
import rasterio.warp
from rasterio.enums import Resampling
from rasterio.transform import from_origin

from worker.pairgen.pair import DsmPair, PairUnavailable, SlideTruth
from worker.pipeline.atomic import write_text_atomic
from worker.pipeline.errors import InputError
from worker.pipeline.raster_io import read_elevation, warp_elevation

NAME = "simulator-video"
SCENARIO = "hillslope"
SURFACE_CHANGE_M = 0.3  # as the pair generators mark surface changes
SUMMARY_FILE = "reconstruction.json"


@dataclass(frozen=True)
class ReconstructedPairs:
    """The `simulator-video` generator; `cache_dir` keeps its simulations and
    reconstructions."""

    cache_dir: Path
    name: str = NAME
    summary: str = (
        "DSMs reconstructed by slidewatch (visual SLAM, no ground control) from simulated "
        "30 s videos of the real-scale hillslope (400 m x 300 m, forest, 100 m flights, "
        "RTK or stand-alone GNSS), before and after 1-3 random slides; ~0.5 m pixels."
    )
    video_seconds: float = 30.0
    fps: float = 10.0

    def simulation(self, seed: int, no_change: bool) -> Any:
        """The simulation options of a pair (its twin: the same without slides)."""
        from worker.simulator import SimulationOptions

        rng = np.random.default_rng([seed, 0x71DE0])
        gnss = "rtk" if rng.uniform() < 0.5 else "standalone"
        # Slides fall anywhere on the 400 m x 300 m area; the flight sees about a third.
        slides = int(rng.integers(3, 7))
        return SimulationOptions(
            seed=seed,
            steps=2,
            survey="video",
            video_seconds=self.video_seconds,
            fps=self.fps,
            gnss=gnss,
            slides=not no_change,
            random_slides=0 if no_change else slides,
            write_ortho=False,
        )

    def make(self, seed: int, no_change: bool = False) -> DsmPair:
        folder = Path(self.cache_dir) / f"seed{seed}" / ("twin" if no_change else "pair")
        manifest = _simulated(folder / "simulation", self.simulation(seed, no_change))
        surveys = [_reconstructed(manifest, k, folder / f"step{k}") for k in (1, 2)]
        return _pair(self, manifest, surveys, seed, no_change)


def _simulated(out: Path, options: Any) -> Any:
    """The simulation in `out`, made now unless complete (its manifest written last)."""
    from worker.simulator import simulate_scenario
    from worker.simulator.manifest import Manifest

    manifest = out / "manifest.json"
    if manifest.exists():
        return Manifest.load(manifest)
    shutil.rmtree(out, ignore_errors=True)
    return simulate_scenario(SCENARIO, out, options)


def _reconstructed(manifest: Any, step: int, folder: Path) -> dict[str, Any]:
    """The summary of a step's reconstruction (its DSM at "dsm"), made now unless it is
    there."""
    from worker.pipeline.reconstruction import (
        ReconstructionInputs,
        ReconstructionOptions,
        reconstruct_survey,
    )

    summary = folder / SUMMARY_FILE
    if summary.exists():
        recorded = json.loads(summary.read_text())
        if recorded.get("error"):
            raise PairUnavailable(recorded["error"])
        return recorded
    survey = manifest.survey(step)
    shutil.rmtree(folder / "work", ignore_errors=True)
    try:
        result = reconstruct_survey(
            ReconstructionInputs(
                video=str(manifest.resolve(survey["video"])),
                log=str(manifest.resolve(survey["srt"])),
            ),
            folder / "work",
            ReconstructionOptions(method="slam"),
        )
    except InputError as exc:  # the pipeline refused the flight: a result, not a crash
        reason = f"step {step}: the reconstruction failed: {exc}"
        write_text_atomic(summary, json.dumps({"error": reason}))
        raise PairUnavailable(reason) from exc
    recorded = {**result.summary(), "dsm": str(result.dsm_path)}
    write_text_atomic(summary, json.dumps(recorded))
    return recorded


def _pair(
    generator: ReconstructedPairs,
    manifest: Any,
    surveys: list[dict[str, Any]],
    seed: int,
    no_change: bool,
) -> DsmPair:
    dsms = [Path(s["dsm"]) for s in surveys]
    grid = manifest.data["grid"]
    pixel = max(_resolution(p) for p in dsms)  # the coarser of the two DSMs
    shape = (
        int((grid["north"] - grid["south"]) // pixel),
        int((grid["east"] - grid["west"]) // pixel),
    )
    transform = from_origin(grid["west"], grid["north"], pixel, pixel)
    crs = manifest.data["crs"]

    def on_grid(path: Path, resampling: Resampling = Resampling.average) -> np.ndarray:
        with rasterio.open(path) as src:
            out = np.full(shape, np.nan, dtype=np.float32)
            rasterio.warp.reproject(
                src.read(1).astype(np.float32),
                out,
                src_transform=src.transform,
                src_crs=src.crs,
                src_nodata=src.nodata,
                dst_transform=transform,
                dst_crs=crs,
                dst_nodata=np.nan,
                resampling=resampling,
            )
        return out

    def reconstructed(path: Path) -> np.ndarray:
        values, profile = read_elevation(path)
        return warp_elevation(values, profile["transform"], profile["crs"], transform, crs, shape)

    pre, post = reconstructed(dsms[0]), reconstructed(dsms[1])
    dsm1, dsm2 = on_grid(manifest.truth(1, "dsm")), on_grid(manifest.truth(2, "dsm"))
    dem1, dem2 = on_grid(manifest.truth(1, "dem")), on_grid(manifest.truth(2, "dem"))
    labels = np.zeros(shape, dtype=np.int16)
    if not no_change:
        events = on_grid(manifest.truth(2, "events"), Resampling.mode)
        labels = np.nan_to_num(events, nan=0.0).astype(np.int16)
    seen = np.isfinite(pre) & np.isfinite(post)
    for slide_id in np.unique(labels[labels > 0]):
        footprint = labels == slide_id
        if np.count_nonzero(footprint & seen) < 0.25 * np.count_nonzero(footprint):
            pre[footprint] = post[footprint] = np.nan
            labels[footprint] = 0
    rows, cols = np.nonzero(seen)
    if rows.size == 0:
        raise PairUnavailable("the two reconstructions do not overlap")
    window = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
    pre, post, labels = pre[window], post[window], labels[window]
    dsm1, dsm2, dem1, dem2 = (a[window] for a in (dsm1, dsm2, dem1, dem2))
    # Ids 1..n in order, as the other generators number their slides.
    ids = np.unique(labels[labels > 0])
    renumber = np.zeros(int(labels.max()) + 1, dtype=np.int16)
    renumber[ids] = np.arange(1, ids.size + 1)
    labels = renumber[labels]
    on_slide = labels > 0
    true_dh = np.where(on_slide, dem2 - dem1, 0.0).astype(np.float32)
    surface = (dsm2 - dem2) - (dsm1 - dem1)
    with np.errstate(invalid="ignore"):
        surface_change = (np.abs(surface) > SURFACE_CHANGE_M) & ~on_slide
    slides = [_slide(i, labels, true_dh, pixel) for i in np.unique(labels[on_slide])]
    options = generator.simulation(seed, no_change)
    return DsmPair(
        generator=generator.name,
        seed=int(seed),
        pixel_size=float(pixel),
        pre=pre,
        post=post,
        true_dh=true_dh,
        slide_labels=labels,
        slides=slides,
        surface_change=surface_change,
        observation_error=((post - dsm2) - (pre - dsm1)).astype(np.float32),
        no_change=bool(no_change),
        description={
            "summary": generator.summary,
            "gnss": options.gnss,
            "window_px": [int(window[0].start), int(window[1].start), *pre.shape],
            "random_slides": options.random_slides,
            "reconstructions": [{k: v for k, v in s.items() if k != "dsm"} for s in surveys],
        },
    )


def _resolution(path: Path) -> float:
    with rasterio.open(path) as src:
        return float(abs(src.transform.a))


def _slide(slide_id: int, labels: np.ndarray, true_dh: np.ndarray, pixel: float) -> SlideTruth:
    footprint = labels == slide_id
    dh = true_dh[footprint]
    rows, cols = np.nonzero(footprint)
    area = pixel * pixel
    return SlideTruth(
        id=int(slide_id),
        kind="simulated-slide",
        area_m2=float(footprint.sum() * area),
        area_px=int(footprint.sum()),
        volume_loss_m3=float(-dh[dh < 0].sum() * area),
        volume_gain_m3=float(dh[dh > 0].sum() * area),
        max_depth_m=float(np.abs(dh).max()) if dh.size else 0.0,
        length_m=float(max(np.ptp(rows), np.ptp(cols)) * pixel) if rows.size else 0.0,
    )
