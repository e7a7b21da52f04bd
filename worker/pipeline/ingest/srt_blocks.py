"""The block structure of DJI SRT files: blocks, their video times, and joined recordings.

A block is an index line, a time range line (`00:00:00,000 --> 00:00:00,033`) and text.
Real files bend this: some firmware writes no time range (a bare index, then the
text; the frame counter or the block's clock time then gives the time), and a file may
be several recordings joined (the time ranges, or frame counters, start again at 0).
This module finds the blocks, their times and, in a joined file, keeps one recording:
the one whose length matches the video when the caller knows it, else the longest.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from typing import Any

import numpy as np

from worker.pipeline.ingest.skipped import RecordError, Skipped

TIME_RANGE = re.compile(
    r"^\s*(\d{1,2}):(\d{2}):(\d{2})[,.](\d{1,3})\s*-->\s*(\d{1,2}):(\d{2}):(\d{2})[,.](\d{1,3})"
)
_ARROW = re.compile(r"-->")
_TAG = re.compile(r"<[^>]*>")
_NUM = r"([-+\u2212]?\d+(?:\.\d+)?)"
FRAMECNT = re.compile(r"\b(FrameCnt|SrtCnt)\s*:\s*(\d+)", re.IGNORECASE)
DIFFTIME = re.compile(r"\bDiffTime\s*:\s*" + _NUM + r"\s*ms", re.IGNORECASE)
# A block's clock time (`2026-07-01 09:00:00,123,456`, `2017.08.05 14:11:51`), local time.
CLOCK = re.compile(
    r"(\d{4})[-./](\d{1,2})[-./](\d{1,2})[ T]+(\d{1,2}):(\d{2}):(\d{2})"
    r"(?:[.,:](\d{1,6}))?(?:[.,:](\d{1,6}))?"
)
# Telemetry text that marks an SRT without time ranges (it has bare index lines instead).
_TELEMETRY = re.compile(r"FrameCnt|SrtCnt|\bGPS\s*\(|\[\s*lat(?:itude)?\s*:", re.IGNORECASE)
_INDEX = re.compile(r"^\s*\d+\s*$", re.MULTILINE)
# A recording restarts when the time range jumps back to (near) 00:00:00, or the frame
# counter back to its first values.
_RESTART_S = 1.0
_RESTART_FRAME = 1


@dataclass
class Block:
    line: int  # first line of the block (index or time range), for messages
    start: float | None = None  # video seconds; None when the block has no time range
    end: float | None = None
    lines: list[tuple[int, str]] = field(default_factory=list)  # (line number, text)
    error: str | None = None  # why the block's time range could not be read
    frame: int | None = None  # FrameCnt / SrtCnt, the clock of blocks without time range
    diff_ms: float | None = None  # DiffTime: milliseconds per frame


def looks_like_srt(text: str) -> bool:
    """True for subtitle time ranges, or telemetry text under bare block indices."""
    head = text[:20000]
    if any(TIME_RANGE.match(line) for line in head.split("\n")):
        return True
    return bool(_TELEMETRY.search(head) and _INDEX.search(head))


def clock_time(match: re.Match) -> datetime:
    """The date-time a `CLOCK` match reads (milliseconds and microseconds, when written)."""
    y, mo, d, h, mi, s, f1, f2 = match.groups()
    dt = datetime(int(y), int(mo), int(d), int(h), int(mi), int(s))
    micro = 0
    if f1:
        micro = int(f1.ljust(6, "0")) if len(f1) > 3 else int(f1) * 1000
        if f2 and len(f1) <= 3:
            micro += int(f2[:3].ljust(3, "0"))
    return dt + timedelta(microseconds=micro)


def _seconds(h: str, m: str, s: str, ms: str) -> float:
    return int(h) * 3600 + int(m) * 60 + int(s) + int(ms.ljust(3, "0")) / 1000.0


def split_blocks(text: str) -> list[Block]:
    """The subtitle blocks of the text, with tags and BOMs removed from their lines.

    A block starts at a time range line (or at the index line just before it) and, in
    files without time ranges, at a bare index line after a blank line.
    """
    blocks: list[Block] = []
    after_blank = True
    for number, raw in enumerate(text.split("\n"), start=1):
        line = _TAG.sub(" ", raw).replace("\ufeff", "").strip()
        if not line:
            after_blank = True
            continue
        fresh = bool(blocks) and blocks[-1].start is None and not blocks[-1].lines
        fresh = fresh and blocks[-1].error is None
        match = TIME_RANGE.match(line)
        if match:
            times = match.groups()
            block = blocks[-1] if fresh else Block(number)
            block.start, block.end = _seconds(*times[:4]), _seconds(*times[4:])
            if not fresh:
                blocks.append(block)
        elif _ARROW.search(line) and len(line) < 60:
            block = blocks[-1] if fresh else Block(number)
            block.error = f"unreadable subtitle time range {line!r}"
            if not fresh:
                blocks.append(block)
        elif line.isdigit() and after_blank:
            blocks.append(Block(number))
        elif blocks:
            blocks[-1].lines.append((number, line))
            _counter(blocks[-1], line)
        after_blank = False
    return [b for b in blocks if b.lines or b.error or b.start is not None]


def _counter(block: Block, line: str) -> None:
    match = FRAMECNT.search(line)
    if match:
        block.frame = int(match.group(2))
    match = DIFFTIME.search(line)
    if match:
        block.diff_ms = float(match.group(1).replace("\u2212", "-"))


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


def _duration(recording: list[Block]) -> float:
    starts = [b.start for b in recording if b.start is not None]
    if starts:
        ends = [b.end if b.end is not None else b.start for b in recording if b.start is not None]
        return max(ends) - min(starts)
    frames = [b.frame for b in recording if b.frame is not None]
    diffs = [b.diff_ms for b in recording if b.diff_ms]
    if frames and diffs:
        return (max(frames) - min(frames) + 1) * float(np.median(diffs)) / 1000.0
    return 0.0


def _clock_start(recording: list[Block]) -> datetime | None:
    """The clock time of the recording's first block that has one (DJI writes local
    time), to tell the recordings apart by when they were flown."""
    for block in recording:
        for _, text in block.lines:
            match = CLOCK.search(text)
            if match:
                return clock_time(match)
    return None


def choose_recording(
    blocks: list[Block],
    name: str,
    video_duration_s: float | None,
    warnings: list[str],
    meta: dict[str, Any],
) -> list[Block]:
    """The blocks of the recording to use; in a joined file, the choice is warned about,
    with every recording listed (start, length, blocks, lines) so that the user can tell
    which one was used and which were set aside."""
    recordings = split_recordings(blocks)
    if len(recordings) == 1:
        return blocks
    durations = [_duration(r) for r in recordings]
    starts = [_clock_start(r) for r in recordings]
    spans = [(r[0].line, r[-1].lines[-1][0] if r[-1].lines else r[-1].line) for r in recordings]
    listed = "; ".join(
        f"{i + 1}: "
        + (f"from {start:%Y-%m-%d %H:%M:%S}, " if start else "")
        + f"{d:.1f} s, {len(r)} blocks, lines {a}-{b}"
        for i, (r, start, d, (a, b)) in enumerate(
            zip(recordings, starts, durations, spans, strict=True)
        )
    )
    joined = f"{name}: the file joins {len(recordings)} recordings ({listed})"
    if video_duration_s:
        kept = min(range(len(recordings)), key=lambda i: abs(durations[i] - video_duration_s))
        # A second or a tenth of the video either way: the SRT's last block and the video's
        # last frame do not end together.
        off = abs(durations[kept] - video_duration_s)
        if off <= max(1.0, 0.1 * video_duration_s):
            why = f"its length matches the video's {video_duration_s:.1f} s"
        else:
            why = (
                f"the nearest to the video's {video_duration_s:.1f} s, though {off:.1f} s "
                "off: check that this log belongs to the video"
            )
        warnings.append(f"{joined}; kept recording {kept + 1}: {why}; the others are not used")
    else:
        kept = max(range(len(recordings)), key=lambda i: durations[i])
        warnings.append(
            f"{joined}, and there is no video to choose by: kept recording {kept + 1}, the "
            "longest, for now; the others are not used. With the survey's video, the "
            "recording whose length matches it is used; or upload an SRT of one recording"
        )
    meta["recordings"] = [
        {
            "lines": list(span),
            "duration_s": round(d, 3),
            "blocks": len(r),
            "start": start.isoformat() if start else None,
        }
        for r, start, d, span in zip(recordings, starts, durations, spans, strict=True)
    ]
    meta["recording_kept"] = kept + 1
    return recordings[kept]


def untimed_times(
    rows: list[dict[str, Any]], name: str, skipped: Skipped, warnings: list[str]
) -> list[dict[str, Any]]:
    """Times for blocks without time ranges: frame counter × frame interval, else the
    clock time of each block (relative to the first), so t = 0 is the first frame.
    Rows with neither go to `skipped`."""
    diffs = [r["diff_ms"] for r in rows if r.get("diff_ms")]
    framed = [r for r in rows if r.get("frame") is not None]
    if diffs and 2 * len(framed) >= len(rows):
        step, first = float(np.median(diffs)) / 1000.0, min(r["frame"] for r in framed)
        for r in framed:
            r["t"] = (r["frame"] - first) * step
        source = "the frame counter (FrameCnt × DiffTime)"
    else:
        stamps = [r["datetime"] for r in rows if r.get("datetime") is not None]
        for r in rows:
            if r.get("datetime") is not None:
                r["t"] = (r["datetime"] - min(stamps)).total_seconds()
        source = "the clock time of each block"
    kept = []
    for r in rows:
        if r.get("t") is None:
            reason = "no time range line, frame counter or clock time"
            skipped.add(RecordError(name, r["line"], reason))
        else:
            kept.append(r)
    if kept:
        warnings.append(f"{name}: the blocks have no time range lines; times from {source}")
    return kept
