"""A survey's quality verdict: whether its reconstruction met the bounds a DSM is trusted by.

`survey_quality(stages)` reads the stage results a reconstruction wrote (report.json's
`stages`, see `reconstruction.write_report`) and answers

    {"passed": bool, "checks": [{"name", "value", "bound", "passed", "message"}]}

with one entry per check that applies to the survey (a check whose figure the survey has
not got, such as the stated accuracy of a stand-alone GPS log, is not made):

- `georeference_accuracy`: the georeference fits the positions within the accuracy the
  log states (RTK); its own check (`georef.check_stated_accuracy`) decides, this one
  reports the worst segment's horizontal RMS residual against its bound.
- `georeference_residual`: for logs stating no accuracy, the horizontal RMS distance
  between the placed cameras and their logged positions, after the georeference.
- `overlap_coverage`: the share of the area seen by two or more cameras with measured,
  not inpainted, heights (the dsm stage's `overlap_coverage`).
- `segments_dropped`: flight segments the georeference could not place and left out;
  passes while one remains (with none the job fails), its message says how many went.
- `photo_outliers`: the share of a photo set's photos whose GPS was left out as wrong.
- `georeference_shape`: how well a photo set's GPS positions fix the map's scale and
  rotation (`robust_fit.shape_uncertainty`): the 2-sigma position error they leave at the
  camera farthest from the centre, against 2 cells of the DSM. Stand-alone GPS over a small
  site misses it (decimetre noise over tens of metres: centimetres at the edge); it says so
  rather than let the DSM's and the orthophoto's cell size promise more.
- `height_agreement`: the dense heights of image pairs that share no frame agree, where
  both measured a cell, to within 3 cells of the DSM (1 sigma; `height_agreement`). A
  survey flown high with short baselines, or over canopy that matches badly, misses it:
  its DSM's relief is noisier than its cells, however well it is georeferenced.
- `time_offset`: a video's offset to its flight log could be tied down (the log's clock,
  its recording span, the video's creation time or the image motion); an ambiguous one
  (`time_offset.TimeOffset.ambiguous_reason`) fails, since positions matched to the wrong
  part of a flight place the DSM metres off with residuals that look fine.

A survey that misses a bound is still a DSM: the verdict says how far to trust it, and
the report lists every failed check's message among its warnings, so no miss is silent.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

from worker.pipeline.georef import GeorefOptions, accuracy_bounds

# The georeference's own warning for a segment it could not fit (georef_map.py).
_SEGMENT_LEFT_OUT = re.compile(r"^segment (\d+) left out\b")


@dataclass(frozen=True)
class QualityBounds:
    """What a survey must meet to pass; each bound says why it sits where it does."""

    # A fit may miss the log's stated (RTK) accuracy by this factor plus this allowance
    # for the reconstruction's own error: the georeference's defaults, so the verdict
    # shows the bound the georeference checked against.
    stated_accuracy_factor: float = GeorefOptions.stated_accuracy_factor
    reconstruction_allowance_m: float = GeorefOptions.reconstruction_allowance_m
    # Logs stating no accuracy (stand-alone GPS): the georeference's bound (its scale-break
    # cut uses the same).
    max_standalone_residual_m: float = GeorefOptions.max_standalone_residual_m
    # Below this share of measured cells where two or more cameras overlap, the DSM there
    # is mostly interpolated, and a change detected there mostly guessed.
    min_overlap_coverage: float = 0.8
    # The robust photo fit names a few wrong GPS fixes; when more than this share of the
    # photos is wrong the remaining ones are suspect too (bad reception, a wrong log).
    max_photo_outlier_share: float = 0.2
    # A map whose scale and rotation the positions fix only to more than this many DSM
    # cells at its edge places far features off by more than its own resolution shows.
    max_shape_error_cells: float = 2.0
    # Heights that independent pairs measure this many DSM cells apart (1 sigma) or more:
    # the relief is noisier than the cells show (the many-flight benchmark counts a DSM
    # more than 3 cells off its truth as off).
    max_height_disagreement_cells: float = 3.0


def survey_quality(
    stages: dict[str, dict[str, Any]], bounds: QualityBounds | None = None
) -> dict[str, Any]:
    """The verdict over the stage results `stages` (stage name -> its `<stage>.json`)."""
    bounds = bounds or QualityBounds()
    geo = stages.get("georeference") or {}
    dsm = stages.get("dsm") or {}
    segments = geo.get("segments") or []
    found = [
        _accuracy_check(segments, bounds),
        _residual_check(segments, bounds),
        _overlap_check(dsm, bounds),
        _segments_check(geo, segments) if geo else None,
        _photo_check(geo.get("photos"), bounds),
        _shape_check(segments, dsm, bounds),
        _agreement_check(dsm, bounds),
        _time_offset_check(geo.get("time_offset")),
    ]
    checks = [c for c in found if c is not None]
    return {"passed": all(c["passed"] for c in checks), "checks": checks}


def failed_messages(quality: dict[str, Any]) -> list[str]:
    """The messages of the checks a verdict failed, in check order."""
    return [c["message"] for c in quality["checks"] if not c["passed"]]


def _check(
    name: str,
    value: float | None,
    bound: float | None,
    passed: bool,
    message: str,
    text: tuple[str, dict[str, str]],
) -> dict[str, Any]:
    key, figures = text
    return {
        "name": name,
        "value": None if value is None else round(float(value), 4),
        "bound": None if bound is None else round(float(bound), 4),
        "passed": bool(passed),
        "message": message,
        # The message as a catalogue key and its figures (formatted as in the message),
        # so that a page in another language words it in its own (frontend i18n
        # `qualityText.*`); `message` stays the server's English.
        "text": {"key": key, "figures": figures},
    }


def _segment_number(segment: dict[str, Any], count: int) -> str:
    """The segment's number where the survey has several segments, else ''."""
    return str(segment.get("segment")) if count > 1 else ""


def _horizontal(residuals: dict[str, Any] | None) -> float | None:
    """The horizontal RMS of a residual table (rms_east, rms_north); None without one."""
    if not residuals or residuals.get("rms_east") is None or residuals.get("rms_north") is None:
        return None
    return math.hypot(residuals["rms_east"], residuals["rms_north"])


def _segment_words(segment: dict[str, Any], count: int) -> str:
    """' (segment 2)' where the survey has several segments, else ''."""
    return f" (segment {segment.get('segment')})" if count > 1 else ""


def _accuracy_check(segments: list[dict[str, Any]], bounds: QualityBounds) -> dict[str, Any] | None:
    georef = GeorefOptions(
        stated_accuracy_factor=bounds.stated_accuracy_factor,
        reconstruction_allowance_m=bounds.reconstruction_allowance_m,
    )
    rows = []
    for seg in segments:
        fit = seg.get("fit") or {}
        # A video segment is checked after the adjustment (georef_map._check_segments),
        # a photo set by its robust fit (robust_fit.georeference_photos).
        if seg.get("within_stated_accuracy") is not None:
            within, stated = seg["within_stated_accuracy"], seg.get("stated_sigma_m")
            residuals = seg.get("residuals_after_m")
        else:
            within, stated = fit.get("within_stated_accuracy"), fit.get("stated_sigma_m")
            residuals = fit.get("residuals_m")
        rms_h = _horizontal(residuals)
        if within is None or not stated or rms_h is None:
            continue  # the log states no accuracy here: georeference_residual's case
        bound_h, bound_v = accuracy_bounds(stated, georef)
        rms_v = (residuals or {}).get("rms_up")
        rows.append((bool(within), rms_h, bound_h, rms_v, bound_v, seg))
    if not rows:
        return None
    # The failing segment furthest off its bound, else the closest to it.
    _, rms_h, bound_h, rms_v, bound_v, seg = max(rows, key=lambda r: (not r[0], r[1] / r[2]))
    passed = all(r[0] for r in rows)
    where = _segment_words(seg, len(segments))
    segment = _segment_number(seg, len(segments))
    figures = {"segment": segment, "rms_h": f"{rms_h:.2f}", "bound_h": f"{bound_h:.2f}"}
    if passed:
        key = "accuracy.within"
        message = (
            f"The survey is as accurate as its flight log states{where}: the cameras and "
            f"their logged positions differ by {rms_h:.2f} m (horizontal RMS), within the "
            f"{bound_h:.2f} m the stated accuracy allows."
        )
    elif rms_h > bound_h:
        key = "accuracy.horizontal"
        message = (
            f"The survey is less accurate than its flight log states{where}: the cameras and "
            f"their logged positions differ by {rms_h:.2f} m (horizontal RMS) where the "
            f"stated accuracy allows {bound_h:.2f} m. The reconstruction is distorted or "
            "some logged positions are wrong; the DSM may be off by that much."
        )
    elif rms_v is not None and rms_v > bound_v:
        key = "accuracy.vertical"
        figures |= {"rms_v": f"{rms_v:.2f}", "bound_v": f"{bound_v:.2f}"}
        message = (
            f"The survey is less accurate than its flight log states{where}: the cameras' "
            f"heights and their logged ones differ by {rms_v:.2f} m (vertical RMS) where the "
            f"stated accuracy allows {bound_v:.2f} m (horizontally {rms_h:.2f} m of "
            f"{bound_h:.2f} m). The reconstruction is distorted or some logged heights are "
            "wrong; the DSM's heights may be off by that much."
        )
    else:
        # The georeference checks only the positions that state an accuracy; the fit's
        # figures here are over all its positions, and may stay within the bounds.
        key = "accuracy.stated"
        figures |= {"factor": f"{bounds.stated_accuracy_factor:g}"}
        message = (
            f"The survey is less accurate than its flight log states{where}: the logged "
            "positions that state an accuracy are further from the reconstruction than "
            f"{bounds.stated_accuracy_factor:g} times that accuracy allows (over all "
            f"positions {rms_h:.2f} m horizontal RMS, allowed {bound_h:.2f} m). The "
            "reconstruction is distorted or some logged positions are wrong."
        )
    return _check("georeference_accuracy", rms_h, bound_h, passed, message, (key, figures))


def _residual_check(segments: list[dict[str, Any]], bounds: QualityBounds) -> dict[str, Any] | None:
    rows = []
    for seg in segments:
        stated = seg.get(
            "within_stated_accuracy", (seg.get("fit") or {}).get("within_stated_accuracy")
        )
        if stated is not None:
            continue  # checked against the log's own stated accuracy instead
        rms_h = _horizontal(seg.get("residuals_after_m"))
        if rms_h is not None:
            rows.append((rms_h, seg))
    if not rows:
        return None
    rms_h, seg = max(rows, key=lambda r: r[0])
    bound = bounds.max_standalone_residual_m
    passed = rms_h <= bound
    where = _segment_words(seg, len(segments))
    segment = _segment_number(seg, len(segments))
    figures = {"segment": segment, "rms_h": f"{rms_h:.2f}", "bound": f"{bound:.1f}"}
    if passed:
        message = (
            f"The placed cameras agree with the logged GPS positions to {rms_h:.2f} m "
            f"(horizontal RMS){where}, within the {bound:.1f} m allowed for stand-alone GPS."
        )
    else:
        message = (
            f"The survey may be distorted or its flight log wrong: the placed cameras are "
            f"{rms_h:.2f} m (horizontal RMS) from the logged GPS positions{where}, more than "
            f"the {bound:.1f} m allowed for stand-alone GPS (whose drift within a flight is "
            "about 1 m)."
        )
    key = "residual.within" if passed else "residual.over"
    return _check("georeference_residual", rms_h, bound, passed, message, (key, figures))


def _overlap_check(dsm: dict[str, Any], bounds: QualityBounds) -> dict[str, Any] | None:
    coverage = dsm.get("overlap_coverage")
    if coverage is None:
        return None  # no footprints, no cell seen twice, or a result from before the figure
    bound = bounds.min_overlap_coverage
    passed = coverage >= bound
    if passed:
        message = (
            f"{coverage:.0%} of the area seen by two or more cameras has measured heights "
            f"(at least {bound:.0%} needed)."
        )
    else:
        message = (
            f"Only {coverage:.0%} of the area seen by two or more cameras has measured "
            f"heights, below the {bound:.0%} needed: the rest of the DSM there is filled "
            "in or missing, and changes found there are uncertain."
        )
    figures = {"coverage": f"{coverage:.0%}", "bound": f"{bound:.0%}"}
    key = "overlap.enough" if passed else "overlap.short"
    return _check("overlap_coverage", coverage, bound, passed, message, (key, figures))


def _segments_check(geo: dict[str, Any], segments: list[dict[str, Any]]) -> dict[str, Any]:
    dropped = [w for w in geo.get("warnings") or [] if _SEGMENT_LEFT_OUT.match(w)]
    kept = len(segments)
    total = kept + len(dropped)
    passed = kept >= 1
    if not dropped:
        message = (
            "The flight's one segment was placed on the ground."
            if total == 1
            else f"All {total} flight segments were placed on the ground."
        )
    else:
        message = (
            f"{len(dropped)} of {_count(total, 'flight segment')} could not be placed on "
            f"the ground and {'was' if len(dropped) == 1 else 'were'} left out: the DSM "
            f"shows only what the other {kept} covered."
        )
    key = "segments.dropped" if dropped else "segments.one" if total == 1 else "segments.all"
    figures = {"dropped": str(len(dropped)), "total": str(total), "kept": str(kept)}
    text = (key, figures)
    return _check("segments_dropped", float(len(dropped)), None, passed, message, text)


def _photo_check(
    photos: list[dict[str, Any]] | None, bounds: QualityBounds
) -> dict[str, Any] | None:
    if not photos:
        return None  # a video survey
    outliers = sum(1 for p in photos if p.get("status") == "outlier")
    share = outliers / len(photos)
    bound = bounds.max_photo_outlier_share
    passed = share <= bound
    figures = f"{outliers} of {_count(len(photos), 'photo')} ({share:.0%})"
    if passed:
        message = (
            f"{figures} had GPS positions that disagree with the others and were left out "
            f"of the georeference, within the {bound:.0%} allowed."
        )
    else:
        message = (
            f"{figures} had GPS positions that disagree with the others and were left out "
            f"of the georeference, more than the {bound:.0%} allowed: the GPS of the "
            "remaining photos is suspect too (bad reception or a wrong log)."
        )
    counts = {"outliers": str(outliers), "photos": str(len(photos))}
    shares = {"share": f"{share:.0%}", "bound": f"{bound:.0%}"}
    text = ("photos.within" if passed else "photos.over", counts | shares)
    return _check("photo_outliers", share, bound, passed, message, text)


def _shape_check(
    segments: list[dict[str, Any]], dsm: dict[str, Any], bounds: QualityBounds
) -> dict[str, Any] | None:
    shapes = [(seg.get("fit") or {}).get("shape_sigma") for seg in segments]
    shapes = [shape for shape in shapes if shape]
    cell = (dsm.get("dsm") or {}).get("resolution_m")
    if not shapes or not cell:
        return None  # a video survey, or a result from before the figure
    shape = max(shapes, key=lambda s: s["at_edge_m"])
    error = shape["at_edge_m"]
    bound = bounds.max_shape_error_cells * cell
    passed = error <= bound
    figures = (
        f"scale within {100 * shape['scale']:.2f} % and rotation within "
        f"{shape['rotation_deg']:.2f}° (1 sigma): up to {100 * error:.1f} cm at the site's "
        f"edge (2 sigma)"
    )
    if passed:
        message = (
            f"The GPS positions fix the map's {figures}, within the "
            f"{bounds.max_shape_error_cells:g} DSM cells ({100 * bound:.1f} cm) allowed."
        )
    else:
        message = (
            f"The GPS positions fix the map's {figures}, more than the "
            f"{bounds.max_shape_error_cells:g} DSM cells ({100 * bound:.1f} cm) allowed: "
            "features far from the centre may sit that far from their true place (RTK "
            "positions or ground control points would fix it)."
        )
    text = (
        "shape.within" if passed else "shape.over",
        {
            "scale": f"{100 * shape['scale']:.2f}",
            "rotation": f"{shape['rotation_deg']:.2f}",
            "error_cm": f"{100 * error:.1f}",
            "cells": f"{bounds.max_shape_error_cells:g}",
            "bound_cm": f"{100 * bound:.1f}",
        },
    )
    return _check("georeference_shape", error, bound, passed, message, text)


def _agreement_check(dsm: dict[str, Any], bounds: QualityBounds) -> dict[str, Any] | None:
    agreement = dsm.get("height_agreement")
    cell = (dsm.get("dsm") or {}).get("resolution_m")
    if not agreement or not cell:
        return None  # no dense points, or a result from before the figure
    value = agreement["agreement_m"]
    bound = bounds.max_height_disagreement_cells * cell
    passed = value <= bound
    cells = value / cell
    figures = {
        "cm": f"{100 * value:.1f}",
        "cells": f"{cells:.1f}",
        "bound": f"{bounds.max_height_disagreement_cells:g}",
    }
    measured = (
        f"Heights measured by image pairs that share no frame agree to {100 * value:.1f} cm "
        f"(1 sigma), {cells:.1f} DSM cells"
    )
    if passed:
        message = f"{measured}, within the {bounds.max_height_disagreement_cells:g} allowed."
    else:
        message = (
            f"{measured}, more than the {bounds.max_height_disagreement_cells:g} allowed: the "
            "DSM's relief is noisier than its cells, and height changes of that order cannot "
            "be told from its noise (fly lower, or keep the frames further apart)."
        )
    text = ("agreement.within" if passed else "agreement.over", figures)
    return _check("height_agreement", value, bound, passed, message, text)


# How each source of the offset is told in a message.
_OFFSET_SOURCES = {
    "srt": "the log's own clock, which is the video's",
    "recording_flag": "the span the log marks as recording",
    "creation_time": "the video's creation time",
    "log_start": "the image motion",
    "user": "the offset given",
}
_OFFSET_REFINED = {
    "motion_correlation": "refined by the image motion",
    "trajectory_fit": "refined on the reconstructed trajectory",
    "bundle_adjustment": "refined with the cameras against the log's positions",
}


def _time_offset_check(offset: dict[str, Any] | None) -> dict[str, Any] | None:
    if not offset or "ambiguous_reason" not in offset:
        return None  # a result from before the check
    source = offset.get("prior_source")
    if source == "image_exif":
        return None  # photos carry their own positions: no offset
    reason = offset["ambiguous_reason"]
    value = offset.get("offset_s")
    if reason is None:
        how = _OFFSET_SOURCES.get(str(source), str(source))
        refined = _OFFSET_REFINED.get(str(offset.get("method")))
        if refined and source != "log_start":
            how += f", {refined}"
        message = f"The flight log was matched to the video in time by {how}."
        shown_refinement = str(offset.get("method")) if refined and source != "log_start" else ""
        text = ("timeOffset.matched", {"source": str(source), "refined": shown_refinement})
    else:
        message = (
            f"The time offset between the video and its flight log is uncertain: {reason}. "
            "Positions may have been matched to the wrong part of the flight, which places "
            "the DSM metres off while its residuals look fine; give the offset if you know it."
        )
        text = ("timeOffset.uncertain", {"reason": str(reason)})
    return _check("time_offset", value, None, reason is None, message, text)


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}{'' if n == 1 else 's'}"
