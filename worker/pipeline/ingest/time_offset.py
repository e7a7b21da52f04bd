"""The offset between the video clock and the flight-log clock, estimated rather than assumed.

Convention: `log_time = video_time + offset_s`.

1. A prior (`prior_offset`): 0 for DJI SRT files (their clock is the video's); the start of
   the log's recording span matching the video's duration (AirData `isVideo`, Litchi
   `isTakingVideo`, PhantomHelp `CAMERA.isVideo`); the video's container creation time
   against the log's UTC clock; else the log start, with a warning and a wide search.
2. An estimate from motion (`estimate_time_offset`): the image motion measured by
   tracking (pixels per second; proportional to ground speed / height for a camera
   looking down) is correlated with the log's ground speed divided by its height above
   take-off, over offsets around the prior. The best normalised correlation wins
   when it is high and distinct; otherwise the prior is kept and the result says the
   offset was not observable (constant speed gives no signal).
3. A refinement from the reconstructed trajectory (`refine_time_offset`): the offset
   that minimises the residual of a similarity fit between camera positions and log
   positions, searched finely around the current estimate.
4. Rivals weighed on the trajectory (`weigh_rivals`): offsets other evidence pointed at
   and that were not taken (the image motion's peak outside the recording span, other
   recording spans as long as the video) are fitted too; an offset that fits the
   trajectory several times better than every rival is tied down after all.

Where the log marks its recording span, the offset is held to it: every estimate and the
refinement search only offsets that keep the video inside that span (give or take
`recording_tolerance_s`; `TimeOffset.allowed_s`). Image motion of a short flight over
parallel lines matches several parts of a log about as well; the span says which part the
video is. An offset that cannot be tied down (nothing ties the clocks and the motion does
not tell, the motion matches best outside the marked span, several recording spans fit
the video) is kept with its reason in `ambiguous_reason`: the report warns and the
survey's quality verdict fails on it (quality.py), rather than a silent guess. Where
the ambiguity names rivals (`TimeOffset.rivals_s`), step 4 may settle it: image motion
over a low sun or a field of few features can match another part of the log better than
the recorded one, while the camera path fits only one of them.

`check_overlap` raises a clear error when the log does not cover the video.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from datetime import datetime
from enum import StrEnum
from typing import Any

import numpy as np

from worker.pipeline.errors import InputError
from worker.pipeline.ingest.flight_log import FlightLog

_EARTH_RADIUS_M = 6_371_000.0


class PriorSource(StrEnum):
    """What the offset's prior came from (the values are kept in ingest.json and frames.json)."""

    srt = "srt"  # DJI SRT: the log's clock is the video's
    recording_flag = "recording_flag"  # the log's recording span
    creation_time = "creation_time"  # the video's creation time against the log's UTC
    log_start = "log_start"  # nothing ties the clocks: searched over the whole log
    image_exif = "image_exif"  # photos: each carries its own position, no offset
    user = "user"  # given in the options, used as it is


class OffsetMethod(StrEnum):
    """How the offset in use was found."""

    prior = "prior"
    motion_correlation = "motion_correlation"
    trajectory_fit = "trajectory_fit"
    bundle_adjustment = "bundle_adjustment"  # with the cameras, against RTK positions
    user = "user"


@dataclass
class TimeOffsetOptions:
    search_s: float = 20.0  # half-width of the search around the prior
    wide_search_s: float = 600.0  # when the prior is only "log start"
    step_s: float = 0.05
    resample_hz: float = 10.0
    smooth_s: float = 1.0
    min_correlation: float = 0.6
    min_distinctness: float = 0.1  # peak minus the best score outside its own lobe
    highpass_s: float = 10.0  # slower changes of speed are removed before correlating
    min_overlap: float = 0.5  # share of the video the log must cover
    # How far the video may reach beyond the log's recording span: the flag is sampled
    # at the log's rate, and logged positions lag the camera by a few tenths of a second.
    recording_tolerance_s: float = 1.0
    # Image motion overrules nothing on a shorter video: over a few seconds it matches
    # unrelated stretches of a log (r = 0.83 against 0.53 at the true offset on an 8-s
    # flight), so only a video this long can contradict the recording span.
    min_contradicting_video_s: float = 20.0
    # `weigh_rivals`: each rival's best residual within +/- rival_search_s, and how many
    # times worse than the kept offset's every rival must fit to settle the offset. On
    # three mounds flights whose recorded span was right (seeds 105, 119, 120) the
    # motion's rival 4-19 s away fitted 4.7-50 times worse; a path that cannot tell the
    # offsets apart fits them about equally.
    rival_search_s: float = 1.0
    rival_step_s: float = 0.1
    rival_ratio: float = 3.0


@dataclass
class TimeOffset:
    offset_s: float  # log_time = video_time + offset_s
    prior_s: float
    prior_source: PriorSource
    method: OffsetMethod
    score: float | None = None
    observable: bool = False
    warnings: list[str] = field(default_factory=list)
    # [lowest, highest] offset that keeps the video inside the log's recording span;
    # None where the log marks none.
    allowed_s: list[float] | None = None
    # Why the offset could not be tied down (None: it could); see the module doc.
    ambiguous_reason: str | None = None
    # Offsets other evidence pointed at that were not taken (`weigh_rivals`).
    rivals_s: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        # Read back from a stage's JSON the flags are plain strings: make them members.
        self.prior_source = PriorSource(self.prior_source)
        self.method = OffsetMethod(self.method)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["offset_s"] = round(self.offset_s, 4)
        d["prior_s"] = round(self.prior_s, 4)
        if self.score is not None:
            d["score"] = round(self.score, 4)
        if self.allowed_s is not None:
            d["allowed_s"] = [round(v, 4) for v in self.allowed_s]
        d["rivals_s"] = [round(v, 4) for v in self.rivals_s]
        return d

    def allows(self, offset_s: float) -> bool:
        """Whether `offset_s` keeps the video inside the log's recording span."""
        if self.allowed_s is None:
            return True
        return self.allowed_s[0] - 1e-9 <= offset_s <= self.allowed_s[1] + 1e-9

    def mark_ambiguous(self, reason: str, rivals_s: tuple[float, ...] = ()) -> None:
        """Keep the offset, say why it is uncertain (the first reason stays) and which
        other offsets the evidence pointed at, if any."""
        self.warnings.append(f"{UNCERTAIN_OFFSET}{reason}")
        if self.ambiguous_reason is None:
            self.ambiguous_reason = reason
        self.rivals_s.extend(float(r) for r in rivals_s)

    def copy(self) -> TimeOffset:
        return TimeOffset(
            **{**asdict(self), "warnings": list(self.warnings), "rivals_s": list(self.rivals_s)}
        )


# How an uncertain offset's warning begins (the report drops the earlier stages' ones
# once the georeference has settled the offset).
UNCERTAIN_OFFSET = "the time offset between video and log is uncertain: "


def prior_offset(
    log: FlightLog,
    video_duration_s: float | None = None,
    video_creation_utc: str | None = None,
    options: TimeOffsetOptions | None = None,
) -> TimeOffset:
    """The best guess before looking at any image (see the module doc)."""
    options = options or TimeOffsetOptions()
    warnings: list[str] = []
    if log.time_base == "video":
        return TimeOffset(0.0, 0.0, PriorSource.srt, OffsetMethod.prior)
    segments = log.recording_segments()
    if segments:
        return _prior_from_recording(segments, video_duration_s, log, options)
    epoch = log.utc_epoch
    if video_creation_utc and epoch is not None:
        created = datetime.fromisoformat(video_creation_utc)
        offset = (created - epoch).total_seconds()
        return TimeOffset(
            offset, offset, PriorSource.creation_time, OffsetMethod.prior, warnings=warnings
        )
    warnings.append(
        "nothing ties the video clock to the log clock (no recording flag, no UTC times): "
        "the offset is searched over the whole log"
    )
    return TimeOffset(0.0, 0.0, PriorSource.log_start, OffsetMethod.prior, warnings=warnings)


def _prior_from_recording(
    segments: list[tuple[float, float]],
    video_duration_s: float | None,
    log: FlightLog,
    options: TimeOffsetOptions,
) -> TimeOffset:
    """The start of the recording span whose length best matches the video, and the
    offsets that keep the video inside that span."""
    if video_duration_s:
        start, end = min(segments, key=lambda s: abs((s[1] - s[0]) - video_duration_s))
    else:
        start, end = segments[0]
    result = TimeOffset(start, start, PriorSource.recording_flag, OffsetMethod.prior)
    if len(segments) > 1:
        result.warnings.append(
            f"the log has {len(segments)} recording spans; took the one starting at "
            f"{start:.1f} s, whose length best matches the video"
        )
    if not video_duration_s:
        return result
    tolerance = _recording_tolerance(log, options)
    result.allowed_s = [start - tolerance, max(end - video_duration_s, start) + tolerance]
    fitting = [s for s in segments if abs((s[1] - s[0]) - video_duration_s) <= tolerance]
    if len(fitting) > 1:
        spans = ", ".join(f"{a:.1f}-{b:.1f} s" for a, b in fitting)
        result.mark_ambiguous(
            f"{len(fitting)} of the log's recording spans are as long as the video "
            f"({spans}); the one starting at {start:.1f} s was taken",
            tuple(a for a, _ in fitting if a != start),
        )
    return result


def _recording_tolerance(log: FlightLog, options: TimeOffsetOptions) -> float:
    """`recording_tolerance_s`, or two log samples where the log is sparser."""
    steps = np.diff(log.t)
    step = float(np.median(steps)) if steps.size else 0.0
    return max(options.recording_tolerance_s, 2.0 * step)


def log_ground_speed(log: FlightLog) -> tuple[np.ndarray, np.ndarray]:
    """(t, horizontal speed in m/s) from the log positions (local flat-earth metres)."""
    ok = log.valid
    t, lat, lon = log.t[ok], log.lat[ok], log.lon[ok]
    if t.size < 3:
        return t, np.zeros_like(t)
    lat0 = np.radians(np.median(lat))
    x = np.radians(lon - lon[0]) * _EARTH_RADIUS_M * np.cos(lat0)
    y = np.radians(lat - lat[0]) * _EARTH_RADIUS_M
    vx, vy = np.gradient(x, t), np.gradient(y, t)
    return t, np.hypot(vx, vy)


def _smooth(values: np.ndarray, window: int) -> np.ndarray:
    if window <= 1:
        return values
    kernel = np.ones(window) / window
    padded = np.pad(values, (window // 2, window - 1 - window // 2), mode="edge")
    return np.convolve(padded, kernel, mode="valid")


def _height_scale(log: FlightLog, t: np.ndarray) -> np.ndarray:
    """Height above take-off at log times t (for speed / height), floored at 5 m."""
    height = log.rel_alt if log.rel_alt is not None else None
    if height is None and log.alt_ref == "takeoff":
        height = log.alt
    if height is None or not np.isfinite(height).any():
        return np.ones_like(t)
    ok = np.isfinite(height)
    h = np.interp(t, log.t[ok], height[ok])
    return np.maximum(h, 5.0)


def estimate_time_offset(
    log: FlightLog,
    video_t: np.ndarray,
    image_speed: np.ndarray,
    prior: TimeOffset,
    options: TimeOffsetOptions | None = None,
) -> TimeOffset:
    """Correlate image motion (px/s at video times) with log speed / height.

    Returns the prior (method `prior`, observable False) when the correlation is weak
    or not distinct, with a warning that says so. Only offsets the prior allows (the
    log's recording span) are taken; a prior that ties nothing and a motion that does not
    tell leave the offset ambiguous (see the module doc).
    """
    options = options or TimeOffsetOptions()
    result = _estimate(log, video_t, image_speed, prior, options)
    if not result.observable and prior.prior_source == PriorSource.log_start:
        result.mark_ambiguous(
            "nothing ties the video's clock to the log's (no recording flag, no UTC time) "
            "and the image motion does not tell the offset; the log's start was assumed. "
            "Give the offset (time_offset_s) if the DSM looks wrong"
        )
    return result


def _estimate(
    log: FlightLog,
    video_t: np.ndarray,
    image_speed: np.ndarray,
    prior: TimeOffset,
    options: TimeOffsetOptions,
) -> TimeOffset:
    video_t = np.asarray(video_t, dtype=float)
    image_speed = np.asarray(image_speed, dtype=float)
    ok = np.isfinite(image_speed)
    video_t, image_speed = video_t[ok], image_speed[ok]
    result = TimeOffset(
        prior.offset_s,
        prior.offset_s,
        prior.prior_source,
        OffsetMethod.prior,
        warnings=list(prior.warnings),
        allowed_s=prior.allowed_s,
        ambiguous_reason=prior.ambiguous_reason,
        rivals_s=list(prior.rivals_s),
    )
    if video_t.size < 10 or video_t[-1] - video_t[0] < 5.0:
        result.warnings.append("video too short to estimate the time offset from motion")
        return result
    step = 1.0 / options.resample_hz
    grid = np.arange(video_t[0], video_t[-1], step)
    window = max(1, round(options.smooth_s * options.resample_hz))
    highpass = max(3, round(options.highpass_s * options.resample_hz))
    visual = _smooth(np.interp(grid, video_t, image_speed), window)
    visual = visual - _smooth(visual, highpass)
    lt, lspeed = log_ground_speed(log)
    if lt.size < 3:
        result.warnings.append("the log has too few positions to estimate the time offset")
        return result
    lgrid = np.arange(lt[0], lt[-1], step)
    lsignal = _smooth(np.interp(lgrid, lt, lspeed) / _height_scale(log, lgrid), window)
    lsignal = lsignal - _smooth(lsignal, highpass)
    if np.std(visual) < 1e-6 * max(np.mean(visual), 1e-9) or np.std(lsignal) < 1e-9:
        result.warnings.append("constant motion: the time offset cannot be observed")
        return result
    offsets = _search_offsets(prior, grid, lt, options)
    if offsets.size == 0:
        result.warnings.append("the log is too short for the video")
        return result
    scores = np.array([_correlation(grid, visual, lgrid, lsignal, d, options) for d in offsets])
    if not np.isfinite(scores).any():
        result.warnings.append("the log and the video do not overlap at any tested offset")
        return result
    allowed = np.array([prior.allows(float(d)) for d in offsets])
    inside = np.where(allowed, scores, np.nan)
    if not np.isfinite(inside).any():
        result.warnings.append(
            "the log and the video do not overlap within the log's recording span"
        )
        return result
    best = int(np.nanargmax(inside))
    peak = float(inside[best])
    if grid[-1] - grid[0] >= options.min_contradicting_video_s:
        _check_outside_the_span(result, offsets, scores, allowed, peak, options)
    rival = _rival_peak(inside, best)
    refined = _parabola(offsets, inside, best)
    if _rising_beyond(scores, allowed, best):
        result.score = peak
        result.warnings.append(
            f"image motion and log speed correlate best at the edge of the log's recording "
            f"span (r = {peak:.2f}), not at a peak within it; kept the {prior.prior_source} "
            f"offset {prior.offset_s:.2f} s"
        )
        return result
    if peak < options.min_correlation or peak - rival < options.min_distinctness:
        result.score = peak
        result.warnings.append(
            f"image motion and log speed correlate weakly (r = {peak:.2f}, next best "
            f"{rival:.2f}); kept the {prior.prior_source} offset {prior.offset_s:.2f} s"
        )
        return result
    if prior.allowed_s is not None:
        refined = float(np.clip(refined, *prior.allowed_s))
    result.offset_s = refined
    result.method = OffsetMethod.motion_correlation
    result.score = peak
    result.observable = True
    return result


def _search_offsets(
    prior: TimeOffset, grid: np.ndarray, lt: np.ndarray, options: TimeOffsetOptions
) -> np.ndarray:
    """The offsets tried: around the prior, the whole log when nothing ties the clocks,
    and at least the whole range the log's recording span allows."""
    wide = prior.prior_source == PriorSource.log_start
    half = options.wide_search_s if wide else options.search_s
    lo = prior.offset_s - half
    hi = prior.offset_s + half
    if prior.prior_source == PriorSource.creation_time:
        lo -= grid[-1] - grid[0]  # the stamp may be the end of the recording
    if wide:
        lo = lt[0] - grid[0] - (grid[-1] - grid[0]) * (1 - options.min_overlap)
        hi = lt[-1] - grid[0] - (grid[-1] - grid[0]) * options.min_overlap
    if prior.allowed_s is not None:
        lo, hi = min(lo, prior.allowed_s[0]), max(hi, prior.allowed_s[1])
    return np.arange(lo, hi + options.step_s / 2, options.step_s)


def _rising_beyond(scores: np.ndarray, allowed: np.ndarray, best: int) -> bool:
    """Whether the best allowed score sits on the edge of the allowed offsets with a
    higher score just outside: the correlation peaks elsewhere, not within the span."""
    for beyond in (best - 1, best + 1):
        outside = 0 <= beyond < scores.size and not allowed[beyond]
        if outside and np.isfinite(scores[beyond]) and scores[beyond] > scores[best]:
            return True
    return False


def _check_outside_the_span(
    result: TimeOffset,
    offsets: np.ndarray,
    scores: np.ndarray,
    allowed: np.ndarray,
    peak_inside: float,
    options: TimeOffsetOptions,
) -> None:
    """Motion that matches the log distinctly better outside the recording span than in
    it, at one distinct offset, contradicts the span (another flight's log, a flag that
    lies): ambiguous."""
    outside = np.where(allowed, np.nan, scores)
    if not np.isfinite(outside).any():
        return
    best = int(np.nanargmax(outside))
    peak = float(outside[best])
    distinct = peak - _rival_peak(scores, best) >= options.min_distinctness
    if (
        distinct
        and peak >= options.min_correlation
        and peak - peak_inside >= options.min_distinctness
    ):
        lo, hi = result.allowed_s or (np.nan, np.nan)
        result.mark_ambiguous(
            f"the image motion matches the log best at an offset of {offsets[best]:.1f} s "
            f"(r = {peak:.2f}), which puts the video outside the recording the log marks "
            f"(offsets {lo:.1f} to {hi:.1f} s, r = {peak_inside:.2f} there); the offset was "
            "kept within the recording. Check that the log is this video's",
            (float(offsets[best]),),
        )


def _correlation(
    grid: np.ndarray,
    visual: np.ndarray,
    lgrid: np.ndarray,
    lsignal: np.ndarray,
    offset: float,
    options: TimeOffsetOptions,
) -> float:
    times = grid + offset
    inside = (times >= lgrid[0]) & (times <= lgrid[-1])
    if inside.mean() < options.min_overlap:
        return np.nan
    a = visual[inside]
    b = np.interp(times[inside], lgrid, lsignal)
    a = a - a.mean()
    b = b - b.mean()
    denom = np.sqrt((a * a).sum() * (b * b).sum())
    return float((a * b).sum() / denom) if denom > 0 else np.nan


def _rival_peak(scores: np.ndarray, best: int) -> float:
    """Best score outside the main lobe around `best`: the lobe ends where the score
    first falls halfway from the peak to the median score, on each side, and is then
    doubled in width so that its own shoulders do not count as rivals."""
    filled = np.where(np.isfinite(scores), scores, -np.inf)
    peak = filled[best]
    level = peak - 0.5 * (peak - float(np.nanmedian(scores)))
    lo = best
    while lo > 0 and filled[lo - 1] > level:
        lo -= 1
    hi = best
    while hi < len(filled) - 1 and filled[hi + 1] > level:
        hi += 1
    lo, hi = max(0, best - 2 * (best - lo)), min(len(filled) - 1, best + 2 * (hi - best))
    outside = np.concatenate([filled[:lo], filled[hi + 1 :]])
    outside = outside[np.isfinite(outside)]
    return float(outside.max()) if outside.size else -1.0


def _parabola(x: np.ndarray, y: np.ndarray, i: int) -> float:
    if 0 < i < len(x) - 1 and np.isfinite(y[i - 1 : i + 2]).all():
        denom = y[i - 1] - 2 * y[i] + y[i + 1]
        if denom < 0:
            shift = 0.5 * (y[i - 1] - y[i + 1]) / denom
            return float(x[i] + np.clip(shift, -1, 1) * (x[1] - x[0]))
    return float(x[i])


def refine_time_offset(
    current: TimeOffset,
    traj_t: np.ndarray,
    residual_at: Callable[[float], float],
    search_s: float = 1.0,
    step_s: float = 0.02,
) -> TimeOffset:
    """Search offsets within ±search_s of `current` (and within the log's recording
    span, `current.allowed_s`) for the smallest trajectory residual.

    `residual_at(offset)` returns the robust residual (metres) of the similarity fit
    between camera positions at `traj_t` and log positions at `traj_t + offset`
    (georef provides it). The offset is kept when the minimum is flat (no motion
    change along the track makes it observable).
    """
    offsets = np.arange(current.offset_s - search_s, current.offset_s + search_s + 1e-9, step_s)
    # Never an offset that moves the video out of the log's recording span.
    offsets = offsets[[current.allows(float(d)) for d in offsets]]
    if offsets.size < 3:
        return current.copy()
    costs = np.array([residual_at(float(d)) for d in offsets])
    result = current.copy()
    if not np.isfinite(costs).any() or traj_t.size < 4:
        return result
    best = int(np.nanargmin(costs))
    refined = _parabola(offsets, -costs, best)
    spread = float(np.nanmax(costs) - np.nanmin(costs))
    if spread < 0.05 * float(np.nanmin(costs)) or best in (0, len(offsets) - 1):
        result.warnings.append("trajectory fit does not constrain the time offset; kept")
        return result
    result.offset_s = refined
    result.method = OffsetMethod.trajectory_fit
    result.observable = True
    result.score = float(costs[best])
    return result


def weigh_rivals(
    current: TimeOffset,
    residual_at: Callable[[float], float],
    options: TimeOffsetOptions | None = None,
) -> TimeOffset:
    """Settle an ambiguous offset that names rivals by the trajectory fit.

    `residual_at` as for `refine_time_offset`. The offset in use keeps its residual;
    each rival gets its best within +/- `rival_search_s`. When every rival fits at
    least `rival_ratio` times worse, the ambiguity is cleared and a warning tells what
    settled it; otherwise the reason is kept with the residuals added to it.
    """
    options = options or TimeOffsetOptions()
    result = current.copy()
    if result.ambiguous_reason is None or not result.rivals_s:
        return result
    kept = residual_at(result.offset_s)
    steps = np.arange(-options.rival_search_s, options.rival_search_s + 1e-9, options.rival_step_s)
    rivals = {r: np.array([residual_at(r + float(d)) for d in steps]) for r in result.rivals_s}
    best = {r: float(np.nanmin(c)) if np.isfinite(c).any() else np.nan for r, c in rivals.items()}
    fits = ", ".join(f"{v:.2f} m near {r:.1f} s" for r, v in best.items())
    told = f"fits the log with {kept:.2f} m at {result.offset_s:.2f} s, {fits}"
    settled = np.isfinite(kept) and all(
        np.isfinite(v) and v >= options.rival_ratio * kept for v in best.values()
    )
    if not settled:
        result.ambiguous_reason = f"{result.ambiguous_reason}; the camera path {told}"
        return result
    result.warnings = [w for w in result.warnings if not w.startswith(UNCERTAIN_OFFSET)]
    result.warnings.append(
        f"the camera path settled the time offset: it {told}, at least "
        f"{options.rival_ratio:g} times better than the other offsets the evidence pointed "
        f"at ({result.ambiguous_reason})"
    )
    result.ambiguous_reason = None
    return result


def check_overlap(
    log: FlightLog,
    offset_s: float,
    video_duration_s: float,
    min_overlap: float = 0.5,
    video_name: str = "the video",
) -> float:
    """Share of the video's duration covered by log positions; InputError below
    `min_overlap`."""
    ok = log.valid
    if ok.sum() < 2:
        raise InputError(f"{log.path}: fewer than two GPS positions")
    t0, t1 = float(log.t[ok][0]), float(log.t[ok][-1])
    v0, v1 = offset_s, offset_s + max(video_duration_s, 1e-9)
    covered = max(0.0, min(t1, v1) - max(t0, v0)) / (v1 - v0)
    if covered < min_overlap:
        epoch = log.epoch
        zone = f" {log.datetime_zone}" if log.datetime_zone else ""
        span = (
            f"{epoch.isoformat()}{zone} + {t0:.0f} to {t1:.0f} s"
            if epoch
            else f"{t0:.0f} to {t1:.0f} s"
        )
        raise InputError(
            f"the flight log {log.path.rsplit('/', 1)[-1]} does not overlap {video_name} in "
            f"time: the log covers {span}, the video maps to {v0:.0f} to {v1:.0f} s on the "
            f"log clock ({covered:.0%} covered). Is it the log of the same flight?"
        )
    return covered
