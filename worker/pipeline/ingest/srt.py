"""DJI video telemetry subtitles (.SRT): every variant of docs' drone-formats notes.

Each subtitle block (index, `HH:MM:SS,mmm --> HH:MM:SS,mmm`, text) gives one sample at
the block's start time, which is video time: `time_base == "video"`.

Text shapes recognised (one parser, field by field, so mixtures work too):

- comma style (Phantom 4 Pro/RTK, Mavic Mini, Air 2S old): `GPS (lon, lat, n)`,
  `D 49.21m`, `H 45.60m` (height above take-off), `H.S 1.2m/s`, `HOME (lon, lat, ...)`,
  `F.PRY (pitch, roll, yaw)` aircraft and `G.PRY (pitch, roll, yaw)` gimbal;
- Mavic Pro (old): `HOME(lon,lat) 2017.08.05 14:11:51`, `GPS(lon,lat,sats) BAROMETER:1.9`;
- Matrice 300: `GPS(lat,lon,alt M) BAROMETER:0.3M`: the order flips when the third
  value carries an `M`;
- bracket style (Mavic 2, Air 2/2S, Mavic 3, Mini 3/4 Pro and newer): `FrameCnt`/
  `SrtCnt`, `DiffTime`, a date-time line, `[key: value]` groups, where a group may hold
  several pairs (`[rel_alt: 45.2 abs_alt: 112.4]`), keys may be misspelt (`longtitude`)
  or have spaces before the colon, and any key may be missing.

Traps handled: lon/lat order (and a swap when a "latitude" exceeds 90), latitude and
longitude 0 = no fix, local time without zone (kept as local), radians (detected per
file, see `_angles_in_radians`, or forced with `angle_unit`), `fnum 280` and
`focal_len 240` of old firmware (tenths), UTF-8 BOM, CRLF, `<font>` tags.
"""

from __future__ import annotations

import math
import re
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np

from worker.pipeline.errors import InputError
from worker.pipeline.ingest.flight_log import ANGLE_KEYS, FlightLog, build_flight_log

_TIME_RANGE = re.compile(
    r"^\s*(\d{1,2}):(\d{2}):(\d{2})[,.](\d{1,3})\s*-->\s*(\d{1,2}):(\d{2}):(\d{2})[,.](\d{1,3})"
)
_ARROW = re.compile(r"-->")
_TAG = re.compile(r"<[^>]*>")
_DATETIME = re.compile(
    r"(\d{4})[-./](\d{1,2})[-./](\d{1,2})[ T]+(\d{1,2}):(\d{2}):(\d{2})"
    r"(?:[.,:](\d{1,6}))?(?:[.,:](\d{1,6}))?"
)
_BRACKET = re.compile(r"\[([^\]]*)\]")
_PAIR = re.compile(r"([A-Za-z_][A-Za-z_.]*)\s*:\s*([^\s\],]+)")
_NUM = r"([-+\u2212]?\d+(?:\.\d+)?)"
_TUPLE = r"\(\s*([^(),]+?)\s*,\s*([^(),]+?)\s*(?:,\s*([^(),]+?)\s*)?\)"
_GPS = re.compile(r"\bGPS\s*" + _TUPLE)
_HOME = re.compile(r"\bHOME\s*" + _TUPLE)
_FPRY = re.compile(r"\bF\.PRY\s*" + _TUPLE)
_GPRY = re.compile(r"\bG\.PRY\s*" + _TUPLE)
_H = re.compile(r"(?<![\w.])H\s*[:]?\s*" + _NUM + r"\s*m\b")
_HS = re.compile(r"\bH\.S\s*[:]?\s*" + _NUM)
_BARO = re.compile(r"\bBAROMETER\s*:\s*" + _NUM + r"\s*M?", re.IGNORECASE)
_FRAMECNT = re.compile(r"\b(FrameCnt|SrtCnt)\s*:\s*(\d+)", re.IGNORECASE)
_DIFFTIME = re.compile(r"\bDiffTime\s*:\s*" + _NUM + r"\s*ms", re.IGNORECASE)
_FNUM_COMMA = re.compile(r"\bF/\s*" + _NUM)
_ISO_COMMA = re.compile(r"\bISO\s*:?\s*" + _NUM)

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


def looks_like_srt(text: str) -> bool:
    """True when the text has at least one subtitle time range line."""
    return any(_TIME_RANGE.match(line) for line in text[:20000].split("\n"))


def _seconds(h: str, m: str, s: str, ms: str) -> float:
    return int(h) * 3600 + int(m) * 60 + int(s) + int(ms.ljust(3, "0")) / 1000.0


def _blocks(text: str, name: str) -> list[tuple[int, float, list[tuple[int, str]]]]:
    """(time line number, start seconds, [(line number, text)]) per subtitle block."""
    blocks: list[tuple[int, float, list[tuple[int, str]]]] = []
    for number, raw in enumerate(text.split("\n"), start=1):
        line = _TAG.sub(" ", raw).replace("\ufeff", "").strip()
        if not line:
            continue
        match = _TIME_RANGE.match(line)
        if match:
            blocks.append((number, _seconds(*match.groups()[:4]), []))
            continue
        if _ARROW.search(line) and len(line) < 60:
            raise InputError(f"{name}, line {number}: unreadable subtitle time range {line!r}")
        if line.isdigit() or not blocks:
            continue  # block index, or text before the first block
        blocks[-1][2].append((number, line))
    return blocks


def _num(text: str, name: str, line: int, what: str) -> float:
    s = text.strip().replace("\u2212", "-").rstrip("mM").strip()
    try:
        return float(s)
    except ValueError:
        raise InputError(f"{name}, line {line}: {what} {text.strip()!r} is not a number") from None


def _datetime(match: re.Match) -> datetime:
    y, mo, d, h, mi, s, f1, f2 = match.groups()
    dt = datetime(int(y), int(mo), int(d), int(h), int(mi), int(s))
    micro = 0
    if f1:
        micro = int(f1.ljust(6, "0")) if len(f1) > 3 else int(f1) * 1000
        if f2 and len(f1) <= 3:
            micro += int(f2[:3].ljust(3, "0"))
    return dt + timedelta(microseconds=micro)


def _parse_block(lines: list[tuple[int, str]], name: str, flags: dict[str, Any]) -> dict[str, Any]:
    row: dict[str, Any] = {}
    for number, line in lines:
        row.setdefault("line", number)
        for bracket in _BRACKET.findall(line):
            for key, value in _PAIR.findall(bracket):
                norm = key.strip().lower()
                common = _KEY_ALIASES.get(norm)
                if common is None:
                    continue
                if norm in ("longtitude", "longtitute"):
                    flags["misspelt"] = True
                if norm in ("abs_alt", "rel_alt"):
                    flags["rel_abs"] = True
                if common in _NUMERIC_KEYS:
                    row[common] = _num(value, name, number, key.strip())
                else:
                    row[common] = value
            flags["bracket"] = True
        outside = _BRACKET.sub(" ", line)
        match = _DATETIME.search(outside)
        if match:
            row["datetime"] = _datetime(match)
        match = _GPS.search(outside)
        if match:
            a, b, c = match.groups()
            if c is not None and c.strip().lower().endswith("m"):
                row["lat"], row["lon"] = _num(a, name, number, "GPS"), _num(b, name, number, "GPS")
                row["alt"] = _num(c, name, number, "GPS altitude")
                flags["lat_first"] = True
            else:
                row["lon"], row["lat"] = _num(a, name, number, "GPS"), _num(b, name, number, "GPS")
                flags["gps_tuple"] = True
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
        for regex, key in ((_H, "rel_alt"), (_BARO, "rel_alt"), (_HS, "speed")):
            match = regex.search(outside)
            if match:
                row[key] = _num(match.group(1), name, number, key)
        if _BARO.search(outside):
            flags["barometer"] = True
        match = _FRAMECNT.search(outside)
        if match:
            flags["counter"] = match.group(1).lower()
        match = _DIFFTIME.search(outside)
        if match:
            row["diff_ms"] = float(match.group(1))
        match = _FNUM_COMMA.search(outside)
        if match:
            row["fnum"] = _num(match.group(1), name, number, "F/")
        match = _ISO_COMMA.search(outside)
        if match:
            row["iso"] = _num(match.group(1), name, number, "ISO")
    return row


_GIMBAL_PRY = ("gimbal_pitch", "gimbal_roll", "gimbal_yaw")


def _variant(flags: dict[str, Any]) -> str:
    if flags.get("lat_first"):
        return "matrice300"
    if flags.get("rel_abs"):
        return "mavic3"
    if flags.get("counter") == "srtcnt":
        return "air2"
    if flags.get("bracket"):
        return "mavic2"
    if flags.get("barometer"):
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


def parse_srt(text: str, path: Path | str, *, angle_unit: str = "auto") -> FlightLog:
    """Parse the text of a DJI SRT file into a `FlightLog` (time_base "video")."""
    name = Path(path).name
    blocks = _blocks(text, name)
    if not blocks:
        raise InputError(f"{name}: no subtitle blocks found")
    flags: dict[str, Any] = {}
    rows = []
    for time_line, start, lines in blocks:
        row = _parse_block(lines, name, flags)
        row["t"] = start
        row.setdefault("line", time_line)
        rows.append(row)
    with_position = [r for r in rows if r.get("lat") is not None and r.get("lon") is not None]
    if not with_position:
        first = blocks[0][2][0][1] if blocks[0][2] else ""
        raise InputError(
            f"{name}: the subtitles carry no GPS position (first text: {first[:80]!r}); "
            "this video's SRT has no telemetry"
        )
    warnings: list[str] = []
    variant = _variant(flags)
    # Order check: a "latitude" beyond ±90 with a longitude within it means swapped.
    lats = np.array([r["lat"] for r in with_position])
    lons = np.array([r["lon"] for r in with_position])
    fix = (lats != 0) | (lons != 0)
    if fix.any() and np.all(np.abs(lats[fix]) > 90) and np.all(np.abs(lons[fix]) <= 90):
        for r in with_position:
            r["lat"], r["lon"] = r["lon"], r["lat"]
        warnings.append(f"{name}: latitude and longitude were swapped in the file; corrected")
    if flags.get("misspelt"):
        warnings.append(f"{name}: misspelt key 'longtitude' read as longitude")
    # Altitude: a GPS altitude that is 0 in every block is a placeholder.
    alts = [r.get("alt") for r in rows if r.get("alt") is not None]
    if alts and all(a == 0 for a in alts):
        for r in rows:
            r.pop("alt", None)
        warnings.append(f"{name}: the GPS altitude is 0 in every block; ignored")
    radians = angle_unit == "rad" or (angle_unit == "auto" and _angles_in_radians(rows))
    if radians:
        for r in rows:
            for k in ANGLE_KEYS:
                if r.get(k) is not None:
                    r[k] = math.degrees(r[k])
        if angle_unit == "auto":
            warnings.append(f"{name}: attitude angles are in radians; converted to degrees")
    _old_firmware_units(rows, name, warnings)
    has_datetime = any(r.get("datetime") is not None for r in rows)
    if has_datetime:
        warnings.append(
            f"{name}: the clock times are local time with no zone; they are kept as local"
        )
    step = np.diff([r["t"] for r in rows])
    meta: dict[str, Any] = {
        "blocks": len(rows),
        "block_interval_s": round(float(np.median(step)), 4) if step.size else None,
    }
    if "home" in flags:
        meta["home_lonlat"] = list(flags["home"])
    for key in ("focal_len", "fnum", "iso"):
        values = [r[key] for r in rows if r.get(key) is not None]
        if values:
            meta[key + ("_35mm" if key == "focal_len" else "")] = float(np.median(values))
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


def _old_firmware_units(rows: list[dict[str, Any]], name: str, warnings: list[str]) -> None:
    """`fnum 280` means f/2.8 and `focal_len 240` means 24 mm on older firmware."""
    fnums = [r["fnum"] for r in rows if r.get("fnum") is not None]
    if fnums and float(np.median(fnums)) >= 50:
        for r in rows:
            if r.get("fnum") is not None:
                r["fnum"] /= 100.0
        warnings.append(f"{name}: fnum written in hundredths (old firmware); divided by 100")
    focals = [r["focal_len"] for r in rows if r.get("focal_len") is not None]
    if focals and float(np.median(focals)) >= 100:
        for r in rows:
            if r.get("focal_len") is not None:
                r["focal_len"] /= 10.0
        warnings.append(f"{name}: focal_len written in tenths of mm (old firmware); divided by 10")
