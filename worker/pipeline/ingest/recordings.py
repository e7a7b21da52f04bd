"""Recordings of a joined DJI SRT file, and which of them belongs to the video.

Some tools join the subtitle files of several recordings into one: the time ranges (or
frame counters) start again at 0 where a recording begins. Only one recording is the
video's. It is told by what the video says of itself (`VideoClues`):

- its length: within a second or a tenth of the video's duration (the SRT's last block
  and the video's last frame do not end together);
- its frame count, where both state one: the video container's count of frames against
  the recording's frame counters (`FrameCnt`/`SrtCnt`), or its number of blocks when it
  writes one block per frame; within 2 frames or 0.5 %;
- its start: the video's creation time against the recording's first clock time. DJI
  writes the clock in local time and the container's time is UTC (or local time marked
  as UTC), so the two may differ by whole time zones: they match when their difference
  is within 2 s of a multiple of 15 minutes, at the recording's start or end (some
  cameras stamp the end of the recording).

A recording matches when no clue the two share disagrees and at least one agrees. When
exactly one matches, it is used; when none or several do, the best (most clues agreeing,
then fewest disagreeing, then nearest in length) is used for now, and the warning names
every recording, which one was used and why, and how to choose: the reconstruction
option `recording` (1-based, as the warning numbers them) picks one explicitly, and a
number the file does not hold is refused with the list of its recordings.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import Any

import numpy as np

from worker.pipeline.errors import InputError
from worker.pipeline.ingest.srt_blocks import CLOCK, Block, clock_time

# A recording restarts when the time range jumps back to (near) 00:00:00, or the frame
# counter back to its first values.
_RESTART_S = 1.0
_RESTART_FRAME = 1
# Blocks no longer than this are one per video frame (DJI writes 1/fps-long blocks on
# most models; older ones one block a second).
_FRAME_BLOCK_S = 0.1
_LENGTH_TOLERANCE = (1.0, 0.1)  # seconds, share of the video's duration
_FRAMES_TOLERANCE = (2, 0.005)  # frames, share of the video's frame count
_START_TOLERANCE_S = 2.0  # creation times are written to the second
_TIME_ZONE_STEP_S = 15 * 60  # time zones are whole quarter hours apart
_MAX_TIME_ZONE_S = 14 * 3600


@dataclass(frozen=True)
class VideoClues:
    """What the video says about the recording it was made in; None where it says
    nothing (`frames` only when the container states its count, `creation_time` as the
    container writes it, without a time zone)."""

    duration_s: float | None = None
    frames: int | None = None
    creation_time: datetime | None = None

    @classmethod
    def from_video_info(cls, info: dict[str, Any] | None) -> VideoClues | None:
        """From a probed video's `VideoInfo.to_dict()` (as ingest.json keeps it)."""
        if not info:
            return None
        created = info.get("creation_time")
        return cls(
            duration_s=info.get("duration_s"),
            frames=info.get("frames") if info.get("frames_stated") else None,
            creation_time=datetime.fromisoformat(created) if created else None,
        )

    def describe(self) -> str:
        parts = []
        if self.duration_s:
            parts.append(f"{self.duration_s:.1f} s")
        if self.frames:
            parts.append(f"{self.frames} frames")
        if self.creation_time:
            parts.append(f"created {self.creation_time:%Y-%m-%d %H:%M:%S}")
        return ", ".join(parts)


@dataclass
class Recording:
    """One recording of the file: its number (1-based), blocks and what they state."""

    number: int
    blocks: list[Block]
    duration_s: float
    frames: int | None  # from the frame counters, or blocks when one per frame
    start: datetime | None  # the first block's clock time (local time)
    lines: tuple[int, int]

    def describe(self) -> str:
        return (
            f"{self.number}: "
            + (f"from {self.start:%Y-%m-%d %H:%M:%S}, " if self.start else "")
            + f"{self.duration_s:.1f} s, "
            + (f"{self.frames} frames, " if self.frames else "")
            + f"{len(self.blocks)} blocks, lines {self.lines[0]}-{self.lines[1]}"
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "lines": list(self.lines),
            "duration_s": round(self.duration_s, 3),
            "frames": self.frames,
            "blocks": len(self.blocks),
            "start": self.start.isoformat() if self.start else None,
        }


def split_recordings(blocks: list[Block]) -> list[list[Block]]:
    """Blocks grouped by recording: a new one starts where the times (or, without time
    ranges, the frame counters) jump back to their start."""
    timed = any(b.start is not None for b in blocks)
    limit = _RESTART_S if timed else _RESTART_FRAME
    recordings: list[list[Block]] = [[]]
    last: float | None = None
    for block in blocks:
        clock = block.start if timed else block.frame
        if clock is not None:
            if last is not None and clock < last and clock <= limit:
                recordings.append([])
            last = clock
        recordings[-1].append(block)
    return [r for r in recordings if r]


def _duration(blocks: list[Block]) -> float:
    starts = [b.start for b in blocks if b.start is not None]
    if starts:
        ends = [b.end if b.end is not None else b.start for b in blocks if b.start is not None]
        return max(ends) - min(starts)
    frames = [b.frame for b in blocks if b.frame is not None]
    diffs = [b.diff_ms for b in blocks if b.diff_ms]
    if frames and diffs:
        return (max(frames) - min(frames) + 1) * float(np.median(diffs)) / 1000.0
    return 0.0


def _frames(blocks: list[Block]) -> int | None:
    """The recording's frame count: its frame counters' span where most blocks have
    one, else its number of blocks where each lasts one frame; None otherwise."""
    counters = [b.frame for b in blocks if b.frame is not None]
    if counters and 2 * len(counters) >= len(blocks):
        return max(counters) - min(counters) + 1
    lengths = [b.end - b.start for b in blocks if b.start is not None and b.end is not None]
    if lengths and 2 * len(lengths) >= len(blocks) and np.median(lengths) <= _FRAME_BLOCK_S:
        return len(blocks)
    return None


def _clock_start(blocks: list[Block]) -> datetime | None:
    """The clock time of the recording's first block that has one."""
    for block in blocks:
        for _, text in block.lines:
            match = CLOCK.search(text)
            if match:
                return clock_time(match)
    return None


def recordings_of(blocks: list[Block]) -> list[Recording]:
    """The file's recordings, numbered from 1 in file order."""
    out = []
    for number, group in enumerate(split_recordings(blocks), start=1):
        last = group[-1].lines[-1][0] if group[-1].lines else group[-1].line
        out.append(
            Recording(
                number=number,
                blocks=group,
                duration_s=_duration(group),
                frames=_frames(group),
                start=_clock_start(group),
                lines=(group[0].line, last),
            )
        )
    return out


def _near_time_zone(offset_s: float, tolerance_s: float) -> bool:
    """Whether a clock difference is a whole number of quarter hours (time zones)."""
    if abs(offset_s) > _MAX_TIME_ZONE_S + tolerance_s:
        return False
    step = _TIME_ZONE_STEP_S
    return abs(offset_s - step * round(offset_s / step)) <= tolerance_s


def clue_verdicts(recording: Recording, video: VideoClues) -> dict[str, bool | None]:
    """Per clue (length, frames, start): whether the recording agrees with the video;
    None where one of them does not state it."""
    verdicts: dict[str, bool | None] = {"length": None, "frames": None, "start": None}
    if video.duration_s:
        seconds, share = _LENGTH_TOLERANCE
        off = abs(recording.duration_s - video.duration_s)
        verdicts["length"] = off <= max(seconds, share * video.duration_s)
    if video.frames and recording.frames:
        frames, share = _FRAMES_TOLERANCE
        verdicts["frames"] = abs(recording.frames - video.frames) <= max(
            frames, share * video.frames
        )
    if video.creation_time and recording.start:
        offset = (video.creation_time - recording.start).total_seconds()
        end_tolerance = _START_TOLERANCE_S + 0.02 * recording.duration_s
        verdicts["start"] = _near_time_zone(offset, _START_TOLERANCE_S) or _near_time_zone(
            offset - recording.duration_s, end_tolerance
        )
    return verdicts


_CLUE_WORDS = {"length": "length", "frames": "frame count", "start": "start"}


def _and(words: list[str]) -> str:
    return " and ".join([", ".join(words[:-1]), words[-1]]) if len(words) > 1 else "".join(words)


def _why(verdicts: dict[str, bool | None]) -> str:
    agree = [_CLUE_WORDS[k] for k, v in verdicts.items() if v is True]
    differ = [_CLUE_WORDS[k] for k, v in verdicts.items() if v is False]
    parts = []
    if agree:
        parts.append(f"its {_and(agree)} {'matches' if len(agree) == 1 else 'match'}")
    if differ:
        parts.append(f"its {_and(differ)} {'does' if len(differ) == 1 else 'do'} not")
    return ", ".join(parts)


def _chosen(recordings: list[Recording], chosen: int, name: str) -> Recording:
    listed = "; ".join(r.describe() for r in recordings)
    if isinstance(chosen, bool) or not isinstance(chosen, int) or chosen < 1:
        raise InputError(
            f"{name}: the recording to use must be a number from 1 to {len(recordings)}, "
            f"not {chosen!r} (the file's recordings: {listed})"
        )
    if chosen > len(recordings):
        holds = "one recording" if len(recordings) == 1 else f"{len(recordings)} recordings"
        raise InputError(
            f"{name}: recording {chosen} was chosen, but the file holds {holds} ({listed}); "
            f"choose one of 1-{len(recordings)}"
        )
    return recordings[chosen - 1]


def choose_recording(
    blocks: list[Block],
    name: str,
    video: VideoClues | None,
    warnings: list[str],
    meta: dict[str, Any],
    chosen: int | None = None,
) -> list[Block]:
    """The blocks of the recording to use (see the module doc); in a joined file the
    choice is warned about with every recording listed, and `meta` gets `recordings`,
    `recording_kept` and `recording_choice` (chosen, matched, ambiguous or no_video).
    Raises InputError naming the recordings when `chosen` is not one of them."""
    recordings = recordings_of(blocks)
    if chosen is not None:
        kept = _chosen(recordings, chosen, name)
        if len(recordings) == 1:
            return blocks
    elif len(recordings) == 1:
        return blocks
    listed = "; ".join(r.describe() for r in recordings)
    joined = f"{name}: the file joins {len(recordings)} recordings ({listed})"
    choose_hint = f"choose one with the option recording (1-{len(recordings)})"
    verdicts = [clue_verdicts(r, video) if video else {} for r in recordings]
    if chosen is not None:
        how = "chosen"
        why = _why(verdicts[kept.number - 1])
        against = f"; against the video ({video.describe()}): {why}" if video and why else ""
        warnings.append(f"{joined}; kept recording {kept.number}, as chosen{against}")
    elif video is None or not video.describe():
        how = "no_video"
        kept = max(recordings, key=lambda r: r.duration_s)
        warnings.append(
            f"{joined}, and there is no video to choose by: kept recording {kept.number}, the "
            "longest, for now; the others are not used. With the survey's video, the "
            "recording that matches it is used; or upload an SRT of one recording, or "
            + choose_hint
        )
    else:
        matching = [
            r
            for r, v in zip(recordings, verdicts, strict=True)
            if True in v.values() and False not in v.values()
        ]

        def rank(r: Recording) -> tuple[int, int, float]:
            v = verdicts[r.number - 1]
            off = abs(r.duration_s - (video.duration_s or 0.0))
            return (-list(v.values()).count(True), list(v.values()).count(False), off)

        if len(matching) == 1:
            how = "matched"
            kept = matching[0]
            warnings.append(
                f"{joined}; kept recording {kept.number}, which matches the video "
                f"({video.describe()}): {_why(verdicts[kept.number - 1])}; the others are "
                "not used"
            )
        else:
            how = "ambiguous"
            kept = min(matching or recordings, key=rank)
            numbers = _and([str(r.number) for r in matching])
            which = {0: "none matches", 2: f"recordings {numbers} both match"}.get(
                len(matching), f"recordings {numbers} all match"
            )
            why = _why(verdicts[kept.number - 1])
            why = f"{why}; the nearest in length" if why else "the nearest in length"
            warnings.append(
                f"{joined}; {which} the video ({video.describe()}) clearly: kept recording "
                f"{kept.number} for now ({why}); check that this log belongs to the video, "
                f"or {choose_hint}"
            )
    meta["recordings"] = [r.to_dict() for r in recordings]
    meta["recording_kept"] = kept.number
    meta["recording_choice"] = how
    return kept.blocks
