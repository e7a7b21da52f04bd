"""Where a monocular reconstruction's scale breaks, found against the flight log.

A monocular SLAM carries its scale from keyframe to keyframe. Where the view changes
faster than the map can follow (a climb or a descent with the camera looking down, a
fast turn onto the lines of a cross pattern), the scale can jump or collapse while the
tracking goes on: the segment is then two maps of different scales joined, and no
similarity (nor a bundle adjustment with the log's positions as priors, which pulls at
each keyframe only by their sigmas) places both. On one of the many-flight benchmark's
flights (the paper's 3-D path with a cross grid, stand-alone GPS) the map's steps
shrank from 0.37 of the log's to 0.64 at the turn and on to 1/140 by the end; the
cameras after the turn were 4-17 m from the truth and the DSM had 5 % of its cells off
by more than 1.5 m.

The log measures the distance flown independently of the images. Per keyframe, the
local scale is the log's displacement over the next `min_travel_m` metres flown (or
the last, at the segment's end) divided by the reconstruction's displacement between the
same keyframes; GNSS errors drift slowly, so a displacement over a few seconds is good
to a few percent even from stand-alone GPS. A segment is cut where the local scale
leaves the median of the last `window` keyframes of its run by more than a factor of
`tolerance` for `persistence` keyframes in a row (a single wild value is noise); slow
drift, which the world adjustment corrects, moves the median along and cuts nothing.
Each run long enough to be placed on its own (`min_run_keyframes`, and a quarter of the
segment's longest run) becomes a segment of its own, georeferenced on its own; the
stretches between them are left out, with the reason in the georeference's warnings.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from worker.pipeline.georef import log_to_utm, umeyama
from worker.pipeline.ingest.flight_log import FlightLog
from worker.pipeline.slam.result import SparseMap


@dataclass
class ScaleBreakOptions:
    enabled: bool = True
    min_travel_m: float = 8.0  # the log's displacement a local scale is measured over
    tolerance: float = 1.3  # a local scale this many times the run's (or 1/this) breaks it
    persistence: int = 3  # keyframes in a row beyond the tolerance that make a break
    window: int = 15  # the run's last keyframes whose median scale is the reference
    # Runs shorter than both of these are left out: too short to be placed on their own
    # (a broken stretch falls into many short runs), or short beside the longest run.
    min_run_keyframes: int = 12
    min_run_share: float = 0.25  # of the segment's longest run


def local_scales(world: np.ndarray, centres: np.ndarray, min_travel_m: float) -> np.ndarray:
    """Per keyframe (in time order): the log's displacement to the first later keyframe
    at least `min_travel_m` away in the log, over the reconstruction's displacement
    between the same two keyframes; at the end, where no later keyframe is that far,
    the same towards the last earlier one; NaN where neither exists."""
    n = len(world)
    scales = np.full(n, np.nan)
    for i in range(n):
        later = np.flatnonzero(np.linalg.norm(world[i + 1 :] - world[i], axis=1) >= min_travel_m)
        if later.size:
            j = i + 1 + int(later[0])
        else:
            earlier = np.flatnonzero(np.linalg.norm(world[:i] - world[i], axis=1) >= min_travel_m)
            if not earlier.size:
                continue
            j = int(earlier[-1])
        moved = float(np.linalg.norm(centres[j] - centres[i]))
        if moved > 0:
            scales[i] = float(np.linalg.norm(world[j] - world[i])) / moved
    return scales


def consistent_runs(scales: np.ndarray, options: ScaleBreakOptions) -> list[tuple[int, int]]:
    """[start, end) ranges of keyframes between scale breaks (see the module doc); one
    range covering all where there is none."""
    n = len(scales)
    logs = np.log(scales)
    limit = float(np.log(options.tolerance))
    runs: list[tuple[int, int]] = []
    start = 0
    recent: list[float] = []
    for i in range(n):
        if not np.isfinite(logs[i]):
            continue
        if recent:
            reference = float(np.median(recent[-options.window :]))
            if abs(logs[i] - reference) > limit:
                ahead = logs[i : i + options.persistence]
                ahead = ahead[np.isfinite(ahead)]
                if len(ahead) == options.persistence and (np.abs(ahead - reference) > limit).all():
                    runs.append((start, i))
                    start, recent = i, [float(logs[i])]
                continue  # an isolated wild value: not part of the reference
        recent.append(float(logs[i]))
    runs.append((start, n))
    return runs


@dataclass
class LeftOut:
    segment: int  # the piece's own segment number, after the split
    reason: str


@dataclass
class ScaleCuts:
    cut: list[int] = field(default_factory=list)  # the segments that were cut
    kept: list[int] = field(default_factory=list)  # their pieces kept (to be placed again)
    left_out: list[LeftOut] = field(default_factory=list)  # their pieces to leave out


def _fit_rms_h(centres: np.ndarray, world: np.ndarray) -> float:
    """RMS horizontal residual of the similarity that best maps `centres` onto `world`."""
    fitted = umeyama(centres, world).apply(centres)
    return float(np.sqrt(((fitted - world)[:, :2] ** 2).sum(axis=1).mean()))


def split_at_scale_breaks(
    sparse: SparseMap,
    log: FlightLog,
    placed: dict[int, tuple[float, float]],
    epsg: int,
    bound_m: float,
    options: ScaleBreakOptions,
) -> ScaleCuts:
    """Cut the segments of `sparse` (in place) at their scale breaks against `log`.

    `placed`: per georeferenced segment, its time offset and its cameras' RMS horizontal
    residual against the log; a segment within `bound_m` is not looked at, nor one not
    placed. Each run long enough becomes a segment, each stretch between them too, when
    every run kept fits the log within `bound_m` on its own. Returns which segments were
    cut, the pieces kept and those to leave out, with their reason."""
    cuts = ScaleCuts()
    left_out = cuts.left_out
    for segment in sparse.segments:
        if segment not in placed or placed[segment][1] <= bound_m:
            continue
        offset_s = placed[segment][0]
        index = np.flatnonzero(sparse.kf_segment == segment)
        if index.size < 2 * options.min_run_keyframes:
            continue
        values = log.interpolate(sparse.kf_t[index] + offset_s)
        ok = np.isfinite(values["lat"]) & np.isfinite(values["lon"]) & np.isfinite(values["alt"])
        if ok.sum() < 2 * options.min_run_keyframes:
            continue
        index = index[ok]
        world = log_to_utm(values["lon"][ok], values["lat"][ok], values["alt"][ok], epsg)
        centres = sparse.kf_centres()[index]
        scales = local_scales(world, centres, options.min_travel_m)
        runs = consistent_runs(scales, options)
        if len(runs) == 1:
            continue
        longest = max(b - a for a, b in runs)
        needed = max(options.min_run_keyframes, options.min_run_share * longest)
        # Consecutive runs too short to keep are one stretch, left out as one.
        pieces: list[tuple[int, int, bool]] = []
        for a, b in runs:
            keep = b - a >= needed
            if pieces and not keep and not pieces[-1][2]:
                pieces[-1] = (pieces[-1][0], b, False)
            else:
                pieces.append((a, b, keep))
        kept = [(a, b) for a, b, keep in pieces if keep]
        if len(pieces) == 1 or any(_fit_rms_h(centres[a:b], world[a:b]) > bound_m for a, b in kept):
            continue
        cuts.cut.append(segment)
        current = segment
        for number, (a, b, keep) in enumerate(pieces):
            if number:
                current = sparse.split_segment(current, int(index[a]))
            if keep:
                cuts.kept.append(current)
                continue
            before = scales[a - 1] if a > 0 else np.nan
            finite = scales[a:b][np.isfinite(scales[a:b])]
            inside = float(np.median(finite)) if finite.size else np.nan
            change = (
                f" (its distances {before / inside:.2f} times what they were, against the log's)"
                if np.isfinite(before) and np.isfinite(inside)
                else ""
            )
            t0, t1 = sparse.kf_t[index[a]], sparse.kf_t[index[b - 1]]
            left_out.append(
                LeftOut(
                    current,
                    f"the part of segment {segment} from {t0:.1f} s to {t1:.1f} s: the "
                    f"reconstruction's scale broke there{change}, and no stretch of it "
                    f"keeps one scale long enough to be placed on its own ({b - a} keyframes)",
                )
            )
    return cuts
