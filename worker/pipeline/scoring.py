"""The `score` stage of the `scored` method: change candidates scored as landslides.

Candidates are the regions of significant change of the LoD method plus regions that are
significant only as an area: where the mean of z = dh / sigma over a disk of the errors'
correlation size exceeds `area_z` in units of its own standard error (sqrt(n_eff)), so a
shallow slide under the pixel LoD but wide and coherent is still a candidate. Each
candidate is described once (change_regions.describe_region) and scored by the
calibrated scorer (scorer.py); those whose probability reaches the scorer's threshold
are the detections, `score` being that probability. Tall objects that appeared or
vanished with no ground motion around them are set aside as surface changes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from worker.pipeline.change_regions import (
    ChangeRasters,
    Region,
    RegionOptions,
    clean_mask,
    describe_region,
    label_regions,
    load_change_rasters,
    min_area_m2,
    region_detection,
    significant_regions,
    split_surface_changes,
)
from worker.pipeline.detection_record import write_detections
from worker.pipeline.error_model import area_t
from worker.pipeline.errors import InputError
from worker.pipeline.geo import crs_to_string
from worker.pipeline.progress import ProgressFn, no_progress
from worker.pipeline.scorer import load_scorer
from worker.pipeline.vectorize import VectorizeResult, detection_totals


@dataclass
class ScoreOptions(RegionOptions):
    area_z: float = 4.0  # area-level significance of a candidate, in standard errors
    # The scorer was fitted on candidates of the minimum area; smaller ones stay out.
    small_region_lod_ratio: float | None = None
    min_pixel_z: float = 1.0  # and each of its pixels at least this many sigmas
    scorer: str | None = None  # path of a scorer JSON; None: the shipped default
    threshold: float | None = None  # None: the scorer's operating threshold

    def __post_init__(self) -> None:
        # One answer everywhere (API, CLI, page): only the LoD method sets mown grass
        # aside; the scorer was fitted on candidates the rule never set aside.
        if self.vegetation_cut:
            raise InputError("the scored method does not set aside mown grass (vegetation_cut)")


@dataclass
class ScoreResult(VectorizeResult):
    """The LoD method's result fields, plus the scoring's."""

    candidates: int
    threshold: float
    model: str


def score_candidates(
    dh_path: Path,
    significance_path: Path,
    pre_path: Path,
    post_path: Path,
    out_geojson: Path,
    options: ScoreOptions | None = None,
    progress: ProgressFn = no_progress,
    method: str = "scored",
) -> ScoreResult:
    """Write the scored detections to `out_geojson` (atomically)."""
    options = options or ScoreOptions()
    start = time.perf_counter()
    scorer = load_scorer(Path(options.scorer) if options.scorer else None)
    threshold = scorer.threshold if options.threshold is None else float(options.threshold)
    rasters = load_change_rasters(dh_path, significance_path, pre_path, post_path)
    regions = candidate_regions(rasters, options)
    progress(0.6)
    landslides, surface = split_surface_changes(regions, options)
    probabilities = scorer.probability([r.traits for r in landslides])
    detections = [
        region_detection(r, rasters.crs, float(p), method, scorer.reference)
        for r, p in zip(landslides, probabilities, strict=True)
        if p >= threshold
    ]
    collection = write_detections(out_geojson, detections, rasters.crs)
    progress(1.0)
    return ScoreResult(
        **detection_totals(collection, surface),
        min_area_m2=round(min_area_m2(rasters, options), 3),
        method=method,
        crs=crs_to_string(rasters.crs),
        seconds=time.perf_counter() - start,
        candidates=len(regions),
        threshold=threshold,
        model=scorer.reference,
    )


def candidate_regions(rasters: ChangeRasters, options: ScoreOptions) -> list[Region]:
    """Every candidate region, described (pixel-significant or area-significant)."""
    mask = significant_regions(rasters, options) | area_significant(rasters, options)
    labels, keep, windows = label_regions(mask, rasters, options)
    return [
        describe_region(rasters, labels, label, window, options)
        for label, window in zip(keep, windows, strict=True)
    ]


def area_significant(rasters: ChangeRasters, options: ScoreOptions) -> np.ndarray:
    """Pixels whose neighbourhood's mean dh is significant as an area (see module doc)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        z = rasters.dh / rasters.sigma
    valid = np.isfinite(z)
    if not valid.any():
        return np.zeros(z.shape, dtype=bool)
    mean, t, weight = area_t(z, rasters.model, rasters.pixel_size)
    with np.errstate(invalid="ignore"):
        candidate = valid & (weight > 0.5) & (np.abs(t) > options.area_z)
        candidate &= np.abs(z) > options.min_pixel_z
        candidate &= np.sign(z) == np.sign(mean)
    return clean_mask(candidate, options)
