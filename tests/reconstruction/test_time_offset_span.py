"""A short video's time offset held to the span its flight log marks as recording
(worker/pipeline/ingest/time_offset.py), an offset that cannot be tied down reported
as ambiguous, in the report and the survey's quality verdict, rather than guessed, and
one the camera path ties down after all settled by it."""

import json

import numpy as np
import pytest

from worker.pipeline.georef import offset_residual_fn
from worker.pipeline.ingest.flight_log import build_flight_log
from worker.pipeline.ingest.time_offset import (
    UNCERTAIN_OFFSET,
    TimeOffset,
    estimate_time_offset,
    prior_offset,
    refine_time_offset,
    weigh_rivals,
)
from worker.pipeline.quality import survey_quality
from worker.pipeline.reconstruction import write_report
from worker.pipeline.trajectory import Trajectory

RATE_HZ = 10.0
VIDEO_S = 8.0


def _speeds(seed: int, duration: float) -> tuple[np.ndarray, np.ndarray]:
    """Log times and a ground speed that changes at irregular times (turns, stops)."""
    t = np.arange(0.0, duration, 1 / RATE_HZ)
    knots = np.random.default_rng(seed).uniform(1.0, 9.0, int(duration / 2) + 2)
    return t, np.interp(t, np.arange(knots.size) * 2.0, knots)


LINE_M, STEP_M = 40.0, 8.0  # the lawnmower's lines and the step between them


def _ground_path(t: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """(east, north) metres of a lawnmower flown at `speed`: lines of LINE_M north and
    south, STEP_M apart."""
    travelled = np.cumsum(speed) / RATE_HZ
    leg, along = np.divmod(travelled, LINE_M + STEP_M)
    on_line = along < LINE_M
    north = np.where(on_line, along, LINE_M)
    north = np.where(leg % 2 == 1, LINE_M - north, north)
    east = leg * STEP_M + np.where(on_line, 0.0, along - LINE_M)
    return np.column_stack([east, north])


def _log(seed: int, spans: list[tuple[float, float]], duration: float = 60.0):
    """A log at 10 Hz, 60 m above take-off, of a lawnmower, flagged as recording during
    `spans`."""
    t, speed = _speeds(seed, duration)
    path = _ground_path(t, speed)
    lat = 47 + path[:, 1] / 111_195.0
    lon = 8 + path[:, 0] / (111_195.0 * np.cos(np.radians(47)))
    recording = np.zeros(t.size, bool)
    for a, b in spans:
        recording |= (t >= a) & (t < b)
    rows = [
        {
            "line": i + 2,
            "t": float(t[i]),
            "lat": float(lat[i]),
            "lon": float(lon[i]),
            "alt": 500.0,
            "rel_alt": 60.0,
            "recording": int(recording[i]),
        }
        for i in range(t.size)
    ]
    return build_flight_log("flight.csv", "generic_csv", rows), t, speed


def _motion(
    t: np.ndarray, speed: np.ndarray, true_offset: float, seed: int, seconds: float = VIDEO_S
):
    """Image motion (px/s) of a video that starts `true_offset` s into the log."""
    video_t = np.arange(0.0, seconds, 1 / 30)
    rng = np.random.default_rng(seed)
    px = np.interp(video_t + true_offset, t, speed) / 60.0 * 500
    return video_t, px + rng.normal(0, 1.0, video_t.size)


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_the_offset_stays_in_the_recording_span(seed):
    log, t, speed = _log(seed, [(20.0, 20.0 + VIDEO_S)])
    prior = prior_offset(log, VIDEO_S)
    assert prior.allowed_s == pytest.approx([19.0, 21.0], abs=0.11)
    video_t, px = _motion(t, speed, 20.3, seed)
    found = estimate_time_offset(log, video_t, px, prior)
    # 8 s of motion place the video to a few tenths of a second (the trajectory fit then
    # refines it), and never outside the span.
    assert found.method == "motion_correlation"
    assert found.offset_s == pytest.approx(20.3, abs=0.4)
    assert found.allows(found.offset_s) and found.ambiguous_reason is None
    # The refinement searches only offsets the span allows: a residual that is smallest
    # 3 s away (a parallel flight line) is never reached.
    refined = refine_time_offset(found, video_t, lambda d: abs(d - 23.5), search_s=5.0)
    assert refined.allows(refined.offset_s) and refined.offset_s <= 21.0 + 1e-9


LONG_S = 30.0


def _contradicted(seed: int, seconds: float):
    """The log says the camera recorded from 20 s, but the video's motion is that of 37 s
    on: the log is another recording's, or its flag is wrong."""
    log, t, speed = _log(seed, [(20.0, 20.0 + seconds)], duration=120.0)
    video_t, px = _motion(t, speed, 37.0, seed, seconds)
    return estimate_time_offset(log, video_t, px, prior_offset(log, seconds))


@pytest.mark.parametrize("seed", [4, 5])
def test_motion_that_fits_elsewhere_in_the_log_is_reported_not_followed(seed):
    found = _contradicted(seed, LONG_S)
    assert found.allows(found.offset_s)
    assert "outside the recording the log marks" in found.ambiguous_reason
    assert "an offset of 37.0 s" in found.ambiguous_reason
    assert any("uncertain" in w for w in found.warnings)
    # A few seconds of motion match unrelated stretches of a log: not a contradiction.
    assert _contradicted(seed, VIDEO_S).ambiguous_reason is None


def _camera_path(log_t, speed, true_offset: float, seconds: float, seed: int):
    """The reconstructed camera path of a video that starts `true_offset` s into the log:
    the log's path at that time in the reconstruction's own frame (scale, rotation,
    origin of its own) with 5 cm of noise."""
    video_t = np.arange(0.0, seconds, 0.2)
    path = _ground_path(log_t, speed)
    ground = np.column_stack([np.interp(video_t + true_offset, log_t, c) for c in path.T])
    local = np.column_stack([ground, np.full(video_t.size, 60.0)])
    turn = np.radians(35.0)
    rotation = np.array(
        [[np.cos(turn), -np.sin(turn), 0], [np.sin(turn), np.cos(turn), 0], [0, 0, 1]]
    )
    local = 0.2 * local @ rotation.T + [3.0, -1.0, 7.0]
    local += np.random.default_rng(seed).normal(0, 0.05 * 0.2, local.shape)
    n = video_t.size
    return Trajectory(video_t, local, np.repeat(np.eye(3)[None], n, 0), np.ones(n, bool))


@pytest.mark.parametrize("seed", [4, 5])
def test_a_camera_path_that_fits_only_the_recorded_span_settles_the_offset(seed):
    """Image motion that matches another part of the log (low sun, few features) is
    outweighed by the camera path, which fits the log only where the video was
    recorded: the offset is tied down, and the report says what settled it."""
    log, t, speed = _log(seed, [(20.0, 20.0 + LONG_S)], duration=120.0)
    found = _contradicted(seed, LONG_S)
    assert found.rivals_s == [pytest.approx(37.0, abs=0.1)]
    residual_at = offset_residual_fn(_camera_path(t, speed, 20.3, LONG_S, seed), log)
    settled = weigh_rivals(
        refine_time_offset(found, np.arange(0, LONG_S, 0.2), residual_at), residual_at
    )
    assert settled.ambiguous_reason is None
    assert settled.offset_s == pytest.approx(20.3, abs=0.05)
    assert not any(
        w.startswith("the time offset between video and log is uncertain") for w in settled.warnings
    )
    assert any("the camera path settled the time offset" in w for w in settled.warnings)
    assert _verdict(settled)["passed"]


@pytest.mark.parametrize("seed", [4, 5])
def test_a_camera_path_that_fits_elsewhere_keeps_the_offset_ambiguous(seed):
    """Motion and camera path both say the video is from 37 s on, outside the span the
    log marks: the log is another recording's or its flag is wrong; the verdict fails
    and the reason gives both fits."""
    log, t, speed = _log(seed, [(20.0, 20.0 + LONG_S)], duration=120.0)
    found = _contradicted(seed, LONG_S)
    residual_at = offset_residual_fn(_camera_path(t, speed, 37.0, LONG_S, seed), log)
    weighed = weigh_rivals(
        refine_time_offset(found, np.arange(0, LONG_S, 0.2), residual_at), residual_at
    )
    assert weighed.allows(weighed.offset_s)
    assert "outside the recording the log marks" in weighed.ambiguous_reason
    assert "the camera path fits the log with" in weighed.ambiguous_reason
    assert not _verdict(weighed)["passed"]


def test_two_recordings_as_long_as_the_video_are_ambiguous():
    log, _, _ = _log(6, [(5.0, 5.0 + VIDEO_S), (30.0, 30.0 + VIDEO_S)])
    prior = prior_offset(log, VIDEO_S)
    assert prior.ambiguous_reason.startswith("2 of the log's recording spans")
    single, _, _ = _log(6, [(5.0, 5.0 + VIDEO_S), (30.0, 50.0)])
    assert prior_offset(single, VIDEO_S).ambiguous_reason is None


def test_nothing_ties_the_clocks_and_no_motion_tells_is_ambiguous():
    t = np.arange(0, 100, 0.1)
    rows = [{"line": i, "t": ti, "lat": 47 + ti * 5 / 111195, "lon": 8.0} for i, ti in enumerate(t)]
    log = build_flight_log("c.csv", "generic_csv", rows)
    video_t = np.arange(0, 30, 1 / 30)
    found = estimate_time_offset(log, video_t, np.full(video_t.size, 40.0), prior_offset(log))
    assert not found.observable and "nothing ties the video's clock" in found.ambiguous_reason


def _verdict(offset: TimeOffset) -> dict:
    quality = survey_quality({"georeference": {"time_offset": offset.to_dict(), "segments": []}})
    (check,) = [c for c in quality["checks"] if c["name"] == "time_offset"]
    return check


def test_the_quality_verdict_fails_on_an_ambiguous_offset():
    check = _verdict(_contradicted(4, LONG_S))
    assert not check["passed"] and "uncertain" in check["message"]
    assert "wrong part of the flight" in check["message"]
    log, t, speed = _log(4, [(20.0, 20.0 + VIDEO_S)])
    video_t, px = _motion(t, speed, 20.3, 4)
    sound = estimate_time_offset(log, video_t, px, prior_offset(log, VIDEO_S))
    check = _verdict(sound)
    assert check["passed"] and check["value"] == pytest.approx(20.3, abs=0.4)
    assert "the span the log marks as recording, refined by the image motion" in check["message"]


@pytest.mark.parametrize("seed", [4, 5])
def test_the_report_drops_the_earlier_doubt_once_the_offset_is_settled(tmp_path, seed):
    """The frames stage said the offset was uncertain; the georeference settled it: the
    survey's warnings (what the API and the page show) say what settled it, not the
    doubt. Unsettled, the doubt stays."""
    log, t, speed = _log(seed, [(20.0, 20.0 + LONG_S)], duration=120.0)
    found = _contradicted(seed, LONG_S)
    for true_offset, settled in ((20.3, True), (37.0, False)):
        path = _camera_path(t, speed, true_offset, LONG_S, seed)
        residual_at = offset_residual_fn(path, log)
        weighed = weigh_rivals(refine_time_offset(found, path.t, residual_at), residual_at)
        (tmp_path / "frames.json").write_text(json.dumps({"time_offset": found.to_dict()}))
        geo = {"time_offset": weighed.to_dict(), "segments": []}
        (tmp_path / "georeference.json").write_text(json.dumps(geo))
        warnings = write_report(tmp_path)["warnings"]
        doubts = [w for w in warnings if w.startswith(UNCERTAIN_OFFSET)]
        assert (doubts == []) is settled
        assert any("the camera path settled" in w for w in warnings) is settled
