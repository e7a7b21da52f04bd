"""`read_flight_log`: any flight log the platform reads, recognised from its content.

The formats are tried in the order of `LOG_FORMATS`; adding one is a module with a
`looks_like_…(text)` and a parser that builds a `FlightLog`, plus one entry here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from worker.pipeline.errors import InputError
from worker.pipeline.ingest import csv_logs, srt, srt_blocks
from worker.pipeline.ingest.flight_log import FlightLog
from worker.pipeline.ingest.recordings import VideoClues


@dataclass(frozen=True)
class LogRead:
    """How to read a log: the SRT angle unit, and which recording of a joined file."""

    angle_unit: str = "auto"
    video: VideoClues | None = None  # what the video says, to match its recording
    recording: int | None = None  # chosen by the user (1-based)


@dataclass(frozen=True)
class LogFormat:
    name: str
    recognises: Callable[[str], bool]
    read: Callable[[str, Path, LogRead], FlightLog]


LOG_FORMATS = (
    LogFormat(
        "DJI SRT",
        srt_blocks.looks_like_srt,
        lambda text, path, how: srt.parse_srt(
            text, path, angle_unit=how.angle_unit, video=how.video, recording=how.recording
        ),
    ),
    LogFormat(
        "CSV (AirData, PhantomHelp, Litchi, generic)",
        csv_logs.looks_like_csv,
        lambda text, path, _how: csv_logs.parse_csv_log(text, path),
    ),
)

_BINARY_SNIFF = 4096
_DJI_TXT_HINT = (
    "is a raw DJI flight record (DJIFlightRecord*.txt): from log version 13 on these are "
    "encrypted with a key only DJI holds. Export the flight as CSV instead (AirData UAV, "
    "PhantomHelp/TXTlogToCSV or Litchi) and use that file, or give the video's SRT file"
)


def read_flight_log(
    path: Path | str,
    *,
    angle_unit: str = "auto",
    video: VideoClues | None = None,
    recording: int | None = None,
) -> FlightLog:
    """Read a DJI SRT, an AirData / PhantomHelp / Litchi CSV or a generic CSV.

    The format is recognised from the content, not the file name. `angle_unit`
    ("auto", "deg", "rad") overrides the radians detection of SRT attitudes. In an SRT
    file joined from several recordings, `recording` (1-based) is used when given (an
    InputError lists the recordings when the file has no such one), else the one that
    matches the `video` (its length, frame count and creation time, when known; see
    `recordings`). Unreadable records are skipped and warned about; raises InputError
    naming the file (and lines) when too little can be used.
    """
    path = Path(path)
    name = path.name
    if not path.is_file():
        raise InputError(f"{name}: flight log not found")
    raw = path.read_bytes()
    if not raw.strip():
        raise InputError(f"{name}: the flight log is empty")
    head = raw[:_BINARY_SNIFF]
    if not raw.startswith((b"\xff\xfe", b"\xfe\xff")) and _looks_binary(head):
        if path.suffix.lower() in (".txt", ".dat") or b"DJI" in head[:64]:
            raise InputError(f"{name} {_DJI_TXT_HINT}")
        raise InputError(f"{name}: not a text flight log (binary content)")
    text = _decode(raw, name)
    for log_format in LOG_FORMATS:
        if log_format.recognises(text):
            return log_format.read(text, path, LogRead(angle_unit, video, recording))
    if path.suffix.lower() == ".txt" and name.lower().startswith("djiflightrecord"):
        raise InputError(f"{name} {_DJI_TXT_HINT}")
    raise InputError(
        f"{name}: not a flight log this program reads. Accepted: DJI video subtitles "
        "(.SRT), AirData, PhantomHelp/TXTlogToCSV and Litchi CSV exports, or a CSV with "
        "columns time, lat, lon, alt (see worker/pipeline/ingest/csv_logs.py)"
    )


def _looks_binary(head: bytes) -> bool:
    if not head:
        return False
    if b"\x00" in head:
        return True
    control = sum(1 for b in head if b < 9 or 13 < b < 32)
    return control / len(head) > 0.05


def _decode(raw: bytes, name: str) -> str:
    encodings = ("utf-16",) if raw.startswith((b"\xff\xfe", b"\xfe\xff")) else ()
    for encoding in (*encodings, "utf-8-sig", "latin-1"):
        try:
            text = raw.decode(encoding)
        except UnicodeDecodeError:
            continue
        return text.lstrip("\ufeff").replace("\r\n", "\n").replace("\r", "\n")
    raise InputError(f"{name}: the flight log is not text")
