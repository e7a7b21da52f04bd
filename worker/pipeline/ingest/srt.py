"""DJI video telemetry subtitles (.SRT): every variant of docs' drone-formats notes.

Each subtitle block (index, `HH:MM:SS,mmm --> HH:MM:SS,mmm`, text) gives one sample at
the block's start time, which is video time: `time_base == "video"`. Block structure
(missing time ranges) is `srt_blocks`' job, joined recordings `recordings`'; this module
reads the text.

Text shapes recognised (one parser, field by field, so mixtures work too):

- comma style (Phantom 4 Pro/RTK, Mavic Mini, Air 2S old): `GPS (lon, lat, n)`,
  `D 49.21m`, `H 45.60m` (height above take-off), `H.S 1.2m/s`, `HOME (lon, lat, ...)`,
  `F.PRY (pitch, roll, yaw)` aircraft and `G.PRY (pitch, roll, yaw)` gimbal, the angles
  with or without a degree sign;
- Mavic Pro (old): `HOME(lon,lat) 2017.08.05 14:11:51`, `GPS(lon,lat,sats) BAROMETER:1.9`,
  `GPS(N/A,N/A,3)` where a block had no fix; older heights `Hb:12.3` (barometric),
  `Hs:…` and `BAROMETER(91.2)`, all heights above take-off;
- Matrice 300: `GPS(lat,lon,alt M) BAROMETER:0.3M`: the order flips when the third
  value carries an `M`;
- bracket style (Mavic 2, Air 2/2S, Mavic 3, Mini 3/4 Pro and newer): `FrameCnt`/
  `SrtCnt`, `DiffTime`, a date-time line, `[key: value]` groups, where a group may hold
  several pairs (`[rel_alt: 45.2 abs_alt: 112.4]`) or name its subject first
  (`[Drone: Yaw:12.3, Pitch:-1.2, Roll:0.4]`, enterprise models: aircraft attitude), keys
  may be misspelt (`longtitude`) or have spaces before the colon, and any key may be
  missing.

A block that cannot be read is skipped and reported (see `skipped`). Traps handled:
lon/lat order (and a swap when a "latitude" exceeds 90), latitude and longitude 0 or
N/A = no fix, local time without zone (kept as local), radians (detected per file, see
`_angles_in_radians`, or forced with `angle_unit`), `fnum 280` and `focal_len 240` of
old firmware (tenths), implausible focal lengths, UTF-8 BOM, CRLF, `<font>` tags.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from worker.pipeline.errors import InputError
from worker.pipeline.ingest.flight_log import ANGLE_KEYS, FlightLog, build_flight_log
from worker.pipeline.ingest.recordings import VideoClues, choose_recording
from worker.pipeline.ingest.skipped import RecordError, Skipped, off_earth
from worker.pipeline.ingest.srt_blocks import (
    CLOCK,
    DIFFTIME,
    FRAMECNT,
    Block,
    clock_time,
    split_blocks,
    untimed_times,
)
from worker.pipeline.ingest.srt_camera import camera_settings

_BRACKET = re.compile(r"\[([^\]]*)\]")
_PAIR = re.compile(r"([A-Za-z_][A-Za-z_.]*)\s*:\s*([^\s\],]+)")
# `[Drone: Yaw:12.3, Pitch:-1.2]`: a subject, then its own key: value pairs.
_SUBJECT = re.compile(r"^\s*([A-Za-z]+)\s*:\s*([A-Za-z_]+\s*:.*)$")
_NUM = r"([-+\u2212]?\d+(?:\.\d+)?)"
_TUPLE = r"\(\s*([^(),]+?)\s*,\s*([^(),]+?)\s*(?:,\s*([^(),]+?)\s*)?\)"
_GPS = re.compile(r"\bGPS\s*" + _TUPLE)
_HOME = re.compile(r"\bHOME\s*" + _TUPLE)
_FPRY = re.compile(r"\bF\.PRY\s*" + _TUPLE)
_GPRY = re.compile(r"\bG\.PRY\s*" + _TUPLE)
_H = re.compile(r"(?<![\w.])H\s*[:]?\s*" + _NUM + r"\s*m\b")
_HB = re.compile(r"\bHb\s*:\s*" + _NUM)
_HSONAR = re.compile(r"\bHs\s*:\s*" + _NUM)
_HS = re.compile(r"\bH\.S\s*[:]?\s*" + _NUM)
_BARO = re.compile(r"\bBAROMETER\s*(?::|\()\s*" + _NUM + r"\s*M?", re.IGNORECASE)
_FNUM_COMMA = re.compile(r"\bF/\s*" + _NUM)
_ISO_COMMA = re.compile(r"\bISO\s*:?\s*" + _NUM)
_NO_FIX = {"n/a", "na", "-", "--", ""}

# Bracket keys, lower-cased, to the common names (misspellings included).
_KEY_ALIASES = {
    "latitude": "lat",
    "lat": "lat",
    "longitude": "lon",
    "longtitude": "lon",
    "longtitute": "lon",
    "lon": "lon",
    "lng": "lon",
    "altitude": "alt",
    "abs_alt": "alt",
    "rel_alt": "rel_alt",
    "gb_yaw": "gimbal_yaw",
    "gb_pitch": "gimbal_pitch",
    "gb_roll": "gimbal_roll",
    "gimbal_yaw": "gimbal_yaw",
    "gimbal_pitch": "gimbal_pitch",
    "gimbal_roll": "gimbal_roll",
    "drone_yaw": "yaw",
    "drone_pitch": "pitch",
    "drone_roll": "roll",
    "focal_len": "focal_len",
    "fnum": "fnum",
    "iso": "iso",
    "ev": "ev",
    "ct": "ct",
    "shutter": "shutter",
}
_NUMERIC_KEYS = {"lat", "lon", "alt", "rel_alt", "focal_len", "fnum", "iso", "ev", "ct"} | set(
    ANGLE_KEYS
)
_GIMBAL_PRY = ("gimbal_pitch", "gimbal_roll", "gimbal_yaw")


def _num(text: str, name: str, line: int, what: str) -> float:
    s = text.strip().replace("\u2212", "-").rstrip("mM°").strip()
    try:
        return float(s)
    except ValueError:
        raise RecordError(name, line, f"{what} {text.strip()!r} is not a number") from None


def _pairs(bracket: str) -> list[tuple[str, str]]:
    """(key, value) of one `[...]` group; a leading subject prefixes its keys."""
    subject = _SUBJECT.match(bracket)
    if subject:
        prefix = subject.group(1).lower()
        return [(f"{prefix}_{k}", v) for k, v in _PAIR.findall(subject.group(2))]
    return _PAIR.findall(bracket)


def _read_brackets(line: str, number: int, name: str, row: dict, flags: dict) -> None:
    for bracket in _BRACKET.findall(line):
        for key, value in _pairs(bracket):
            norm = key.strip().lower()
            common = _KEY_ALIASES.get(norm)
            if common is None:
                continue
            if norm in ("longtitude", "longtitute"):
                flags["misspelt"] = True
            if norm in ("abs_alt", "rel_alt"):
                flags["rel_abs"] = True
            if common in ("lat", "lon") and value.strip().lower() in _NO_FIX:
                row["no_fix"] = number  # `[latitude: N/A]`: this block had no fix
            elif common in _NUMERIC_KEYS:
                row[common] = _num(value, name, number, key.strip())
            else:
                row[common] = value
            if common == "focal_len":
                # Written without decimals: maybe tenths of mm (old firmware).
                row["focal_integer"] = "." not in value
        flags["bracket"] = True


def _read_gps(outside: str, number: int, name: str, row: dict, flags: dict) -> None:
    match = _GPS.search(outside)
    if not match:
        return
    a, b, c = match.groups()
    if a.strip().lower() in _NO_FIX or b.strip().lower() in _NO_FIX:
        row["no_fix"] = number  # `GPS(N/A,N/A,3)`: this block had no fix
        flags["gps_tuple"] = True
        return
    if c is not None and c.strip().lower().endswith("m"):
        row["lat"], row["lon"] = _num(a, name, number, "GPS"), _num(b, name, number, "GPS")
        row["alt"] = _num(c, name, number, "GPS altitude")
        flags["lat_first"] = True
    else:
        row["lon"], row["lat"] = _num(a, name, number, "GPS"), _num(b, name, number, "GPS")
        flags["gps_tuple"] = True


def _read_heights(outside: str, number: int, name: str, row: dict, flags: dict) -> None:
    """Heights above take-off: `H 45.6m`, `Hb:12.3` (barometric), `BAROMETER:1.9` or
    `BAROMETER(91.2)`; `Hs:` only when the block has none of these."""
    for regex, key in ((_H, "rel_alt"), (_HB, "rel_alt"), (_BARO, "rel_alt"), (_HS, "speed")):
        match = regex.search(outside)
        if match:
            row[key] = _num(match.group(1), name, number, key)
    if _BARO.search(outside):
        flags["barometer"] = True
    match = _HSONAR.search(outside)
    if match and row.get("rel_alt") is None:
        row["rel_alt"] = _num(match.group(1), name, number, "Hs")
        flags["hs"] = True


def _parse_block(lines: list[tuple[int, str]], name: str, flags: dict[str, Any]) -> dict[str, Any]:
    row: dict[str, Any] = {}
    for number, line in lines:
        row.setdefault("line", number)
        _read_brackets(line, number, name, row, flags)
        outside = _BRACKET.sub(" ", line)
        match = CLOCK.search(outside)
        if match:
            row["datetime"] = clock_time(match)
        _read_gps(outside, number, name, row, flags)
        match = _HOME.search(outside)
        if match and "home" not in flags:
            a, b, _ = match.groups()
            flags["home"] = (_num(a, name, number, "HOME"), _num(b, name, number, "HOME"))
        for regex, keys in ((_FPRY, ("pitch", "roll", "yaw")), (_GPRY, _GIMBAL_PRY)):
            match = regex.search(outside)
            if match:
                for key, value in zip(keys, match.groups(), strict=True):
                    if value is not None:
                        row[key] = _num(value, name, number, key)
                flags["pry"] = True
        _read_heights(outside, number, name, row, flags)
        match = FRAMECNT.search(outside)
        if match:
            flags["counter"] = match.group(1).lower()
            row["frame"] = int(match.group(2))
        match = DIFFTIME.search(outside)
        if match:
            row["diff_ms"] = float(match.group(1))
        match = _FNUM_COMMA.search(outside)
        if match:
            row["fnum"] = _num(match.group(1), name, number, "F/")
        match = _ISO_COMMA.search(outside)
        if match:
            row["iso"] = _num(match.group(1), name, number, "ISO")
    return row


def _variant(flags: dict[str, Any]) -> str:
    if flags.get("lat_first"):
        return "matrice300"
    if flags.get("rel_abs"):
        return "mavic3"
    if flags.get("counter") == "srtcnt":
        return "air2"
    if flags.get("bracket"):
        return "mavic2"
    if flags.get("barometer") or flags.get("hs"):
        return "mavic_pro"
    if flags.get("pry"):
        return "phantom4rtk"
    if flags.get("gps_tuple"):
        return "phantom"
    return "unknown"


def _angles_in_radians(rows: list[dict[str, Any]]) -> bool:
    """Whether the file's angles are radians (some firmware writes them so).

    Evidence, strongest first: a gimbal pitch whose magnitude is typically above 0.3
    while every angle stays within ±π (degrees would put a survey gimbal near -90);
    else an aircraft yaw spanning more than 0.5 while pitch and roll stay within ±0.5
    (a flying aircraft in degrees tilts by more than half a degree).
    """
    values = {k: np.array([r[k] for r in rows if r.get(k) is not None]) for k in ANGLE_KEYS}
    present = [v for v in values.values() if v.size]
    if not present:
        return False
    if max(float(np.abs(v).max()) for v in present) > math.pi + 1e-3:
        return False
    gp = values["gimbal_pitch"]
    if gp.size and float(np.median(np.abs(gp))) > 0.3:
        return True
    yaw, tilt = values["yaw"], np.concatenate([values["pitch"], values["roll"]])
    return bool(
        yaw.size > 5 and np.ptp(yaw) > 0.5 and tilt.size and float(np.abs(tilt).max()) < 0.5
    )


def _read_blocks(
    blocks: list[Block], name: str, flags: dict[str, Any], skipped: Skipped
) -> list[dict[str, Any]]:
    """One row per readable block; unreadable ones go to `skipped`."""
    timed = any(b.start is not None for b in blocks)
    rows = []
    for block in blocks:
        block_flags: dict[str, Any] = {}
        try:
            if block.error:
                raise RecordError(name, block.line, block.error)
            if timed and block.start is None:
                raise RecordError(name, block.line, "the block has no time range line")
            row = _parse_block(block.lines, name, block_flags)
        except RecordError as error:
            skipped.add(error)
            continue
        for key, value in block_flags.items():
            flags.setdefault(key, value)
        row["t"] = block.start
        row.setdefault("line", block.line)
        rows.append(row)
    return rows


def parse_srt(
    text: str,
    path: Path | str,
    *,
    angle_unit: str = "auto",
    video: VideoClues | None = None,
    recording: int | None = None,
) -> FlightLog:
    """Parse the text of a DJI SRT file into a `FlightLog` (time_base "video").

    In a file joined from several recordings, `recording` (1-based) is the one to use,
    else the one that matches the `video` (see `recordings`), else the longest; with a
    warning either way.
    """
    name = Path(path).name
    blocks = split_blocks(text)
    if not blocks:
        raise InputError(f"{name}: no subtitle blocks found")
    warnings: list[str] = []
    meta: dict[str, Any] = {}
    blocks = choose_recording(blocks, name, video, warnings, meta, chosen=recording)
    flags: dict[str, Any] = {}
    skipped = Skipped(name, "blocks")
    rows = _read_blocks(blocks, name, flags, skipped)
    if rows and all(r["t"] is None for r in rows):
        rows = untimed_times(rows, name, skipped, warnings)
    with_position = [r for r in rows if r.get("lat") is not None and r.get("lon") is not None]
    if rows and not with_position and not any(r.get("no_fix") for r in rows):
        first = blocks[0].lines[0][1] if blocks[0].lines else ""
        raise InputError(
            f"{name}: the subtitles carry no GPS position (first text: {first[:80]!r}); "
            "this video's SRT has no telemetry"
        )
    variant = _variant(flags)
    _fix_order(with_position, name, warnings)
    rows = _drop_off_earth(rows, name, skipped)
    warnings = skipped.check(len(blocks)) + warnings
    no_fix = [r["no_fix"] for r in rows if r.get("no_fix")]
    if no_fix:
        listed = ", ".join(map(str, no_fix[:10])) + (", …" if len(no_fix) > 10 else "")
        warnings.append(f"{name}: position 'N/A' (no fix) in {len(no_fix)} blocks (lines {listed})")
    if flags.get("misspelt"):
        warnings.append(f"{name}: misspelt key 'longtitude' read as longitude")
    if flags.get("hs"):
        warnings.append(f"{name}: 'Hs' read as the height above take-off (no other height)")
    _zero_altitude(rows, name, warnings)
    radians = angle_unit == "rad" or (angle_unit == "auto" and _angles_in_radians(rows))
    if radians:
        for r in rows:
            for k in ANGLE_KEYS:
                if r.get(k) is not None:
                    r[k] = math.degrees(r[k])
        if angle_unit == "auto":
            warnings.append(f"{name}: attitude angles are in radians; converted to degrees")
    meta.update(camera_settings(rows, variant, name, warnings))
    if any(r.get("datetime") is not None for r in rows):
        warnings.append(
            f"{name}: the clock times are local time with no zone; they are kept as local"
        )
    step = np.diff(sorted(r["t"] for r in rows))
    meta["blocks"] = len(rows)
    meta["block_interval_s"] = round(float(np.median(step)), 4) if step.size else None
    if len(skipped):
        meta["blocks_skipped"] = len(skipped)
    if "home" in flags:
        meta["home_lonlat"] = list(flags["home"])
    return build_flight_log(
        path,
        "dji_srt",
        rows,
        time_base="video",
        variant=variant,
        datetime_zone="local",
        warnings=warnings,
        meta=meta,
    )


def _fix_order(with_position: list[dict], name: str, warnings: list[str]) -> None:
    """A "latitude" beyond ±90 with every longitude within it means swapped."""
    if not with_position:
        return
    lats = np.array([r["lat"] for r in with_position])
    lons = np.array([r["lon"] for r in with_position])
    fix = (lats != 0) | (lons != 0)
    if fix.any() and np.all(np.abs(lats[fix]) > 90) and np.all(np.abs(lons[fix]) <= 90):
        for r in with_position:
            r["lat"], r["lon"] = r["lon"], r["lat"]
        warnings.append(f"{name}: latitude and longitude were swapped in the file; corrected")


def _drop_off_earth(rows: list[dict], name: str, skipped: Skipped) -> list[dict]:
    kept = []
    for r in rows:
        if off_earth(r.get("lat"), r.get("lon")):
            reason = f"latitude {r['lat']} / longitude {r['lon']} is not a position on Earth"
            skipped.add(RecordError(name, r["line"], reason))
        else:
            kept.append(r)
    return kept


def _zero_altitude(rows: list[dict], name: str, warnings: list[str]) -> None:
    """A GPS altitude that is 0 in every block is a placeholder."""
    alts = [r.get("alt") for r in rows if r.get("alt") is not None]
    if alts and all(a == 0 for a in alts):
        for r in rows:
            r.pop("alt", None)
        warnings.append(f"{name}: the GPS altitude is 0 in every block; ignored")
