"""The block structure of DJI SRT files: blocks and their video times.

A block is an index line, a time range line (`00:00:00,000 --> 00:00:00,033`) and text.
Real files bend this: some firmware writes no time range (a bare index, then the
text; the frame counter or the block's clock time then gives the time), and a file may
be several recordings joined (the time ranges, or frame counters, start again at 0).
This module finds the blocks and their times; `recordings` splits a joined file into
its recordings and chooses the video's.
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
