"""The reconstruction stages' results: what each writes as `<stage>.json`, typed.

A later stage reads an earlier one's file back with `from_dict` and uses attributes. The
JSON is the one the stages have always written, key for key and in the same order, so
stored results and report.json keep their meaning: a part that is itself a serialised
library object (the log, the video, the intrinsics, a time offset ...) stays a dict, a
key a stage writes only in some cases is a field marked `_OPTIONAL`, left out of
`to_dict` while None, and NaN or infinity is written as null.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from worker.pipeline.stages import StageResult

# Field metadata of a key the stage writes only in some cases: left out of the JSON while
# the field is None (other None fields are written as null).
_OMIT_NONE = "omit_none"
_OPTIONAL = MappingProxyType({_OMIT_NONE: True})


def plain(obj: Any) -> Any:
    """JSON-friendly: numpy scalars and arrays to Python, tuples to lists, NaN and
    infinity to None (strict JSON has no such numbers)."""
    if isinstance(obj, dict):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return plain(obj.tolist())
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating | float):
        value = float(obj)
        return value if np.isfinite(value) else None
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


class ReconstructionStageResult(StageResult):
    """`to_dict` gives exactly what the stage writes to `<stage>.json`."""

    def to_dict(self) -> dict[str, Any]:
        return {
            f.name: plain(getattr(self, f.name))
            for f in dataclasses.fields(self)  # type: ignore[arg-type]
            if not (f.metadata.get(_OMIT_NONE) and getattr(self, f.name) is None)
        }


# kw_only: fields follow the order of the keys in the file, and a required key may come
# after an optional one. Optional keys say in a comment when the stage writes them.
@dataclass(kw_only=True)
class IngestResult(ReconstructionStageResult):
    inputs: dict[str, str | None]  # video, log, images: absolute paths or None
    method: str  # slam or sfm
    warnings: list[str]
    # image sets: the set's summary
    images: dict[str, Any] | None = field(default=None, metadata=_OPTIONAL)
    # video surveys: the probed video
    video: dict[str, Any] | None = field(default=None, metadata=_OPTIONAL)
    intrinsics_source: dict[str, Any]  # at the camera's own size
    intrinsics: dict[str, Any]  # at the processing size
    time_offset_prior: dict[str, Any]  # a TimeOffset
    log: dict[str, Any]  # the flight log's summary
    crs: str  # EPSG:<the survey's UTM zone>
    seconds: float

    @property
    def image_set(self) -> str | None:
        """The image set's folder, None for a video survey."""
        return self.inputs.get("images")


@dataclass(kw_only=True)
class FramesResult(ReconstructionStageResult):
    method: str
    # video: decoding and filtering figures
    frames: dict[str, Any] | None = field(default=None, metadata=_OPTIONAL)
    # video, unless the user gave the offset: the offset image motion gives
    time_offset_estimate: dict[str, Any] | None = field(default=None, metadata=_OPTIONAL)
    time_offset: dict[str, Any]  # the TimeOffset later stages use
    # sfm on video, or images reduced for SfM: frames, width, height; each still's time
    stills: dict[str, Any] | None = field(default=None, metadata=_OPTIONAL)
    still_times: list[float] | None = field(default=None, metadata=_OPTIONAL)
    # image sets: how the images are used
    note: str | None = field(default=None, metadata=_OPTIONAL)
    seconds: float


@dataclass(kw_only=True)
class ReconstructResult(ReconstructionStageResult):
    method: str
    # slam: the frames tracked; with ties between flight lines, their figures
    tracked_frames: int | None = field(default=None, metadata=_OPTIONAL)
    ties: dict[str, Any] | None = field(default=None, metadata=_OPTIONAL)
    # sfm: run_sfm's report
    sfm: dict[str, Any] | None = field(default=None, metadata=_OPTIONAL)
    keyframes: int
    frames_with_pose: int
    sparse_points: int
    dense_points: int
    segments: int
    stats: dict[str, Any]
    video_seconds: float
    seconds: float
    real_time_factor: float | None  # null when the stage took no measurable time


@dataclass(kw_only=True)
class GeoreferenceResult(ReconstructionStageResult):
    time_offset: dict[str, Any]  # the refined TimeOffset
    crs: str
    segments: list[dict[str, Any]]  # per-segment fit and residuals
    time_offset_s: float
    seconds: float
    warnings: list[str]
    # image sets: per photo, residual east/north/up (m) and used or outlier
    photos: list[dict[str, Any]] | None = field(default=None, metadata=_OPTIONAL)
    # slam: the dense pairs matched again on the georeferenced poses
    # (slam/redensify.RedensifyReport, and its seconds)
    redensified: dict[str, Any] | None = field(default=None, metadata=_OPTIONAL)


@dataclass(kw_only=True)
class DsmStageResult(ReconstructionStageResult):
    """The dsm stage's figures (its `dsm` is dsm_export.DsmStageResult's dict)."""

    sparse_points: int
    dense_points: int
    # with sparse_sor: the sparse points it removed
    sparse_outliers_removed: int | None = field(default=None, metadata=_OPTIONAL)
    gsd_m: float
    # with dense_sor, and when there is a dense cloud: the dense points each filter removed
    dense_sor_removed: int | None = field(default=None, metadata=_OPTIONAL)
    dense_grid_removed: int | None = field(default=None, metadata=_OPTIONAL)
    # with wide pairs (DensifyOptions.wide_baseline_ratio): the points the choice between
    # a keyframe's two pairs dropped (the narrow pair's where the wide one agrees, the
    # wide pair's elsewhere)
    dense_pair_choice_removed: int | None = field(default=None, metadata=_OPTIONAL)
    dsm: dict[str, Any]
    points: int
    # when the cameras have ground footprints: the points outside all of them (grown by a
    # margin), dropped; the area seen by two or more cameras (m²) and the share of its
    # cells with a measured, not inpainted, height (left out when no cell is seen twice)
    points_outside_footprint: int | None = field(default=None, metadata=_OPTIONAL)
    overlap_area_m2: float | None = field(default=None, metadata=_OPTIONAL)
    overlap_coverage: float | None = field(default=None, metadata=_OPTIONAL)
    # with dense points: how well independent pairs' heights agree (height_agreement)
    height_agreement: dict[str, Any] | None = field(default=None, metadata=_OPTIONAL)
    # with dense points: the planes taken out of the pairs' heights so that they agree
    # (pair_adjustment.PairPlanes)
    pair_adjustment: dict[str, Any] | None = field(default=None, metadata=_OPTIONAL)
    seconds: float


@dataclass(kw_only=True)
class OrthophotoStageResult(ReconstructionStageResult):
    """The orthophoto stage's figures (its `orthophoto` is orthophoto.OrthophotoResult's
    dict; absent when no orthophoto was made, with the reason among the warnings)."""

    orthophoto: dict[str, Any] | None = None
    warnings: list[str] = field(default_factory=list)
    seconds: float
