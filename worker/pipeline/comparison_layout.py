"""What every comparison stage shares: the work folder's files, the context, a method's shape.

Layout of a comparison's work folder (the stage that writes each file):

    pre_aligned.tif        align        pre DSM on the common metric grid (float32, -9999)
    post_aligned.tif       align        post DSM on the same grid
    post_coregistered.tif  coregister   post DSM corrected onto pre
    stable_mask.tif        coregister   uint8: 1 stable terrain, 0 excluded, 255 nodata
    dh.tif                 difference   post - pre in metres (float32, -9999)
    significance.tif       difference   uint8: 0 none, 1 loss, 2 gain, 255 nodata
    lod.tif                difference   per-pixel LoD95 in metres (float32, -9999)
    error_model.json       difference   sigma_dh(slope, curvature) and the variogram
    detections.geojson     the method's detection stage: landslide polygons, WGS84 lon/lat

A detection method adds files of its own (the cnn method's probability.tif and
cells.geojson); its `DetectionMethod.stage` lists them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from worker.pipeline.align import AlignOptions
from worker.pipeline.coregister import CoregisterOptions
from worker.pipeline.difference import DifferenceOptions
from worker.pipeline.stages import GEOJSON, Output, StageSpec

PRE_ALIGNED = "pre_aligned.tif"
POST_ALIGNED = "post_aligned.tif"
POST_COREGISTERED = "post_coregistered.tif"
STABLE_MASK = "stable_mask.tif"
DH = "dh.tif"
SIGNIFICANCE = "significance.tif"
LOD = "lod.tif"
ERROR_MODEL = "error_model.json"
DETECTIONS = "detections.geojson"

# What every detection stage may read: the change and both surfaces it came from.
DETECTION_INPUTS = (PRE_ALIGNED, POST_COREGISTERED, DH, SIGNIFICANCE)
DETECTIONS_OUTPUT = Output(DETECTIONS, product="detections", media_type=GEOJSON)


class StageOptions(Protocol):
    """What the stages read of a comparison's options (comparison.ComparisonOptions, which
    this module cannot import: it imports the methods, and the methods import this)."""

    align: AlignOptions
    coregister: CoregisterOptions
    difference: DifferenceOptions
    method: str
    detection: Any  # the method's own options (its `options_type`)


@dataclass
class ComparisonContext:
    """Everything a comparison stage reads: the two DSMs, the work folder, the options."""

    pre_path: Path
    post_path: Path
    work_dir: Path
    options: StageOptions

    def file(self, name: str) -> Path:
        return Path(self.work_dir) / name

    @property
    def detection(self) -> Any:
        """The options of the comparison's detection method (its `options_type`)."""
        return self.options.detection


@dataclass(frozen=True)
class DetectionMethod:
    """A way to turn Δh and its significance into landslide polygons.

    The method's `stage` runs after align, coregister and difference; it reads files of
    `DETECTION_INPUTS`, writes `detections.geojson` (`DETECTIONS_OUTPUT`) and any products of
    its own. Its options are a dataclass of `options_type`, stored in a comparison's
    parameters under `options_key`. `needs_model` says the method runs a registered model:
    the job layer resolves the model a comparison names into the path of its card and puts
    it in the options' `model` field.
    """

    name: str
    summary: str  # one line for people: what it does and where it stands on the benchmark
    stage: StageSpec[ComparisonContext]
    options_type: type
    options_key: str
    needs_model: bool = False
    check_request: Callable[[Any], None] | None = None
