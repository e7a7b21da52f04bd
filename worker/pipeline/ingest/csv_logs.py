"""Flight-record CSV exports: AirData, PhantomHelp / TXTlogToCSV, Litchi, and our generic CSV.

The flavour is recognised from the header. Units are read from the header names
(`height_above_takeoff(feet)`, `OSD.height [m]`, `speed(mph)`) and converted to metres and
metres per second. A latitude/longitude of 0 means no fix. Delimiters `,`, `;` and tab
are accepted, as is an Excel `sep=` first line.

Generic CSV (our own minimal schema), one header line then one row per sample:

    time,lat,lon,alt[,rel_alt,roll,pitch,yaw,gimbal_roll,gimbal_pitch,gimbal_yaw,speed,recording]

- `time`: ISO 8601 (`2024-05-01T10:00:00.250Z`; an offset such as `+02:00` is converted
  to UTC; without a zone the time is taken as UTC, with a warning), or seconds as a
  number (relative; no wall clock then).
- `lat`, `lon`: WGS84 degrees. `alt`: metres above sea level / the ellipsoid.
  `rel_alt`: metres above the take-off point (used when `alt` is absent).
- angles in degrees, DJI conventions (yaw clockwise from north, gimbal pitch -90 down);
  `speed` m/s; `recording` 1 while the camera records video, else 0.
  `latitude`, `longitude`, `altitude` are accepted for `lat`, `lon`, `alt`.

A row that cannot be read (a garbled number or date, no time, a position off the
Earth) is skipped and reported with its line; the file is refused only when too few
rows remain (see `skipped`).
"""

from __future__ import annotations

import csv
import io
import re
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from worker.pipeline.errors import InputError
from worker.pipeline.ingest.flight_log import FlightLog, build_flight_log, parse_float
from worker.pipeline.ingest.skipped import RecordError, Skipped, off_earth

_FEET = 0.3048
_LENGTH_UNITS = {"feet": _FEET, "ft": _FEET, "foot": _FEET, "meters": 1.0, "metres": 1.0, "m": 1.0}
_SPEED_UNITS = {
    "mph": 0.44704,
    "m/s": 1.0,
    "mps": 1.0,
    "km/h": 1 / 3.6,
    "kmh": 1 / 3.6,
    "kph": 1 / 3.6,
    "ft/s": _FEET,
}
_UNIT = re.compile(r"^(.*?)\s*[\(\[]\s*([^\)\]]*)\s*[\)\]]\s*$")


def looks_like_csv(text: str) -> bool:
    header = _header_line(text)
    if header is None:
        return False
    delimiter = _delimiter(header)
    names = {_norm(n) for n in header.split(delimiter)}
    return len(names) >= 3 and bool(
        names & {"lat", "latitude", "osd.latitude", "gps.latitude", "gps_lat"}
    )


def _header_line(text: str) -> str | None:
    for line in text.split("\n"):
        if line.strip() and not line.lower().startswith("sep="):
            return line
    return None


def _delimiter(header: str) -> str:
    counts = {d: header.count(d) for d in (",", ";", "\t")}
    return max(counts, key=counts.get)


def _norm(name: str) -> str:
    return name.strip().strip('"').strip().lower()


def _split_unit(name: str) -> tuple[str, str | None]:
    """`height_above_takeoff(feet)` -> ("height_above_takeoff", "feet")."""
    match = _UNIT.match(name)
    if match:
        return match.group(1).strip(), match.group(2).strip().lower()
    return name, None


class _Table:
    """Header lookup by base name (unit suffix stripped) with unit conversion."""

    def __init__(self, header: list[str], name: str) -> None:
        self.name = name
        self.columns: dict[str, tuple[int, str | None]] = {}
        for i, raw in enumerate(header):
            base, unit = _split_unit(_norm(raw))
            self.columns.setdefault(base, (i, unit))
            self.columns.setdefault(_norm(raw), (i, unit))

    def has(self, *names: str) -> bool:
        return all(n in self.columns for n in names)

    def first(self, *names: str) -> str | None:
        return next((n for n in names if n in self.columns), None)

    def unit(self, key: str) -> str | None:
        return self.columns[key][1]

    def text(self, row: list[str], key: str | None) -> str:
        if key is None or key not in self.columns:
            return ""
        i = self.columns[key][0]
        return row[i] if i < len(row) else ""

    def number(self, row: list[str], key: str | None, line: int, kind: str = "") -> float | None:
        if key is None or key not in self.columns:
            return None
        value = parse_float(self.text(row, key), self.name, line, key)
        if value is None:
            return None
        unit = self.unit(key)
        if kind == "length" and unit is not None:
            factor = _LENGTH_UNITS.get(unit)
            if factor is None:
                raise InputError(f"{self.name}: unknown length unit {unit!r} of column {key}")
            value *= factor
        elif kind == "speed" and unit is not None:
            factor = _SPEED_UNITS.get(unit)
            if factor is None:
                raise InputError(f"{self.name}: unknown speed unit {unit!r} of column {key}")
            value *= factor
        return value


def parse_csv_log(text: str, path: Path | str) -> FlightLog:
    """Parse a CSV flight log of any supported flavour into a `FlightLog`."""
    name = Path(path).name
    lines = text.split("\n")
    start = 0
    delimiter = None
    while start < len(lines) and not lines[start].strip():
        start += 1
    if start < len(lines) and lines[start].lower().startswith("sep="):
        delimiter = lines[start][4:5] or ","
        start += 1
    body = "\n".join(lines[start:])
    header_text = _header_line(body) or ""
    delimiter = delimiter or _delimiter(header_text)
    reader = csv.reader(io.StringIO(body), delimiter=delimiter)
    try:
        header = next(reader)
    except StopIteration:
        raise InputError(f"{name}: the CSV file has no header") from None
    table = _Table(header, name)
    records: list[tuple[int, list[str]]] = []
    for row in reader:
        if not any(cell.strip() for cell in row):
            continue
        records.append((reader.line_num + start, row))
    if not records:
        raise InputError(f"{name}: the CSV file has a header but no rows")
    flavour, parse_row = _flavour(table)
    warnings: list[str] = []
    zone: dict[str, str | None] = {"zone": None}
    skipped = Skipped(name, "rows")
    rows = []
    for line, row in records:
        try:
            rows.append(_usable(parse_row(table, row, line, zone, warnings), name))
        except RecordError as error:
            skipped.add(error)
    warnings[:0] = skipped.check(len(records))
    meta: dict[str, Any] = {"columns": len(header)}
    if len(skipped):
        meta["rows_skipped"] = len(skipped)
    if flavour == "litchi_csv":
        _litchi_raw_gimbal(rows, name, warnings)
    return build_flight_log(
        path,
        flavour,
        rows,
        time_base="log",
        datetime_zone=zone["zone"],
        warnings=_unique(warnings),
        meta=meta,
    )


def _usable(out: dict[str, Any], name: str) -> dict[str, Any]:
    """The parsed row, or RecordError when it has no time or an impossible position."""
    if out.get("t") is None and out.get("datetime") is None:
        raise RecordError(name, out["line"], "the record has no time")
    if off_earth(out.get("lat"), out.get("lon")):
        reason = f"latitude {out['lat']} / longitude {out['lon']} is not a position on Earth"
        raise RecordError(name, out["line"], reason)
    return out


def _unique(items: list[str]) -> list[str]:
    return list(dict.fromkeys(items))


_RowParser = Callable[[_Table, list[str], int, dict[str, str | None], list[str]], dict[str, Any]]


def _flavour(table: _Table) -> tuple[str, _RowParser]:
    keys = table.columns
    if any(k.startswith(("osd.", "custom.", "gimbal.")) for k in keys):
        if not table.has("osd.latitude", "osd.longitude"):
            raise InputError(f"{table.name}: PhantomHelp CSV without OSD.latitude/OSD.longitude")
        return "phantomhelp_csv", _phantomhelp_row
    units = {unit for _, unit in keys.values()}
    if table.has("latitude", "longitude"):
        if "degrees" in units or table.first(
            "height_above_takeoff", "altitude_above_sealevel", "compass_heading", "isvideo"
        ):
            return "airdata_csv", _airdata_row
        if "deg" in units or table.first("gimbalpitchraw", "istakingvideo"):
            return "litchi_csv", _litchi_row
        if table.has("time") and table.unit("time") == "millisecond":
            return "airdata_csv", _airdata_row
    if table.first("lat", "latitude") and table.first("lon", "longitude"):
        if not table.has("time"):
            raise InputError(
                f"{table.name}: the CSV has positions but no 'time' column (a generic CSV "
                "needs time, lat, lon, alt; see the documented schema)"
            )
        return "generic_csv", _generic_row
    raise InputError(f"{table.name}: CSV columns not recognised as a flight log")


def parse_datetime(text: str, name: str, line: int) -> tuple[datetime, str | None]:
    """A date-time in the shapes flight logs use; returns (naive time, zone or None).

    With a zone (`Z`, `+02:00`) the time is converted to UTC and the zone is "UTC".
    """
    s = text.strip()
    if not s:
        raise RecordError(name, line, "empty date-time")
    s2 = s.replace("/", "-")
    am_pm = re.search(r"\s*([AaPp][Mm])$", s2)
    if am_pm:
        s2 = s2[: am_pm.start()]
    if re.match(r"^\d{1,2}-\d{1,2}-\d{4}", s2):  # US month/day/year
        m, d, rest = s2.split("-", 2)
        s2 = f"{rest[:4]}-{int(m):02d}-{int(d):02d}{rest[4:]}"
    s2 = re.sub(
        r"^(\d{4})-(\d{1,2})-(\d{1,2})", lambda g: f"{g[1]}-{int(g[2]):02d}-{int(g[3]):02d}", s2
    )
    s2 = re.sub(r"[ T](\d):", r" 0\1:", s2)
    s2 = s2.replace("Z", "+00:00").replace("z", "+00:00")
    try:
        dt = datetime.fromisoformat(s2)
    except ValueError:
        raise RecordError(name, line, f"unreadable date-time {s!r}") from None
    if am_pm:
        hour = dt.hour % 12 + (12 if am_pm.group(1).lower() == "pm" else 0)
        dt = dt.replace(hour=hour)
    if dt.tzinfo is not None:
        return dt.astimezone(UTC).replace(tzinfo=None), "UTC"
    return dt, None


def _zone_from_header(table: _Table, key: str, default: str | None) -> str | None:
    unit = table.unit(key)
    if unit in ("utc", "gmt"):
        return "UTC"
    if unit == "local":
        return "local"
    if "utc" in key:
        return "UTC"
    return default


def _recording(table: _Table, row: list[str], *keys: str) -> bool | None:
    key = table.first(*keys)
    if key is None:
        return None
    value = table.text(row, key).strip().lower()
    if value in ("", "nan"):
        return None
    return value in ("1", "true", "yes", "y", "recording")


def _airdata_row(table, row, line, zone, warnings) -> dict[str, Any]:
    out: dict[str, Any] = {"line": line}
    name = table.name
    if table.has("time"):
        ms = table.number(row, "time", line)
        out["t"] = None if ms is None else ms / 1000.0
    if table.has("datetime"):
        text = table.text(row, "datetime")
        if text.strip():
            dt, z = parse_datetime(text, name, line)
            out["datetime"] = dt
            zone["zone"] = z or _zone_from_header(table, "datetime", "UTC")
    out["lat"] = table.number(row, "latitude", line)
    out["lon"] = table.number(row, "longitude", line)
    out["alt"] = table.number(row, table.first("altitude_above_sealevel"), line, "length")
    out["rel_alt"] = table.number(
        row, table.first("height_above_takeoff", "altitude"), line, "length"
    )
    out["speed"] = table.number(row, table.first("speed"), line, "speed")
    out["yaw"] = table.number(row, table.first("compass_heading", "heading"), line)
    out["pitch"] = table.number(row, table.first("pitch"), line)
    out["roll"] = table.number(row, table.first("roll"), line)
    out["gimbal_pitch"] = table.number(row, table.first("gimbal_pitch"), line)
    out["gimbal_roll"] = table.number(row, table.first("gimbal_roll"), line)
    out["gimbal_yaw"] = table.number(row, table.first("gimbal_heading", "gimbal_yaw"), line)
    out["recording"] = _recording(table, row, "isvideo")
    return out


def _phantomhelp_row(table, row, line, zone, warnings) -> dict[str, Any]:
    out: dict[str, Any] = {"line": line}
    name = table.name
    key = table.first("custom.updatetime", "custom.datetime")
    text = table.text(row, key).strip()
    if text:
        if not re.match(r"^\d{1,4}[-/]", text):  # time only: take the date column
            date_key = table.first("custom.date")
            text = f"{table.text(row, date_key).strip()} {text}"
        dt, z = parse_datetime(text, name, line)
        out["datetime"] = dt
        zone["zone"] = z or _zone_from_header(table, key, "local")
        if zone["zone"] == "local":
            warnings.append(f"{name}: CUSTOM.updateTime is local time; kept as local")
    elif table.has("osd.flytime"):
        out["t"] = table.number(row, "osd.flytime", line)
    out["lat"] = table.number(row, "osd.latitude", line)
    out["lon"] = table.number(row, "osd.longitude", line)
    out["alt"] = table.number(row, table.first("osd.altitude"), line, "length")
    out["rel_alt"] = table.number(row, table.first("osd.height"), line, "length")
    out["speed"] = table.number(row, table.first("osd.hspeed"), line, "speed")
    out["pitch"] = table.number(row, table.first("osd.pitch"), line)
    out["roll"] = table.number(row, table.first("osd.roll"), line)
    out["yaw"] = table.number(row, table.first("osd.yaw"), line)
    out["gimbal_pitch"] = table.number(row, table.first("gimbal.pitch"), line)
    out["gimbal_roll"] = table.number(row, table.first("gimbal.roll"), line)
    out["gimbal_yaw"] = table.number(row, table.first("gimbal.yaw"), line)
    out["recording"] = _recording(table, row, "camera.isvideo", "camera.isrecording")
    return out


def _litchi_row(table, row, line, zone, warnings) -> dict[str, Any]:
    out: dict[str, Any] = {"line": line}
    name = table.name
    if table.has("time") and table.unit("time") == "millisecond":
        ms = table.number(row, "time", line)
        out["t"] = None if ms is None else ms / 1000.0
    key = table.first("datetime(utc)", "datetime")
    if key:
        text = table.text(row, key)
        if text.strip():
            dt, z = parse_datetime(text, name, line)
            out["datetime"] = dt
            zone["zone"] = z or _zone_from_header(table, key, "UTC")
    out["lat"] = table.number(row, "latitude", line)
    out["lon"] = table.number(row, "longitude", line)
    # Litchi's altitude is the height above the take-off point.
    out["rel_alt"] = table.number(row, table.first("altitude"), line, "length")
    out["speed"] = table.number(row, table.first("speed"), line, "speed")
    out["pitch"] = table.number(row, table.first("pitch"), line)
    out["roll"] = table.number(row, table.first("roll"), line)
    out["yaw"] = table.number(row, table.first("yaw"), line)
    out["gimbal_pitch"] = table.number(row, table.first("gimbalpitchraw", "gimbalpitch"), line)
    out["gimbal_roll"] = table.number(row, table.first("gimbalrollraw", "gimbalroll"), line)
    out["gimbal_yaw"] = table.number(row, table.first("gimbalyawraw", "gimbalyaw"), line)
    out["recording"] = _recording(table, row, "istakingvideo", "isvideo")
    return out


def _litchi_raw_gimbal(rows: list[dict[str, Any]], name: str, warnings: list[str]) -> None:
    """Litchi's `gimbal*Raw` columns are tenths of a degree on some versions (-900)."""

    def max_abs(key: str) -> float:
        values = [abs(r[key]) for r in rows if r.get(key) is not None]
        return max(values) if values else 0.0

    if (
        max_abs("gimbal_pitch") > 90.5
        or max_abs("gimbal_roll") > 90.5
        or max_abs("gimbal_yaw") > 360.5
    ):
        for r in rows:
            for key in ("gimbal_pitch", "gimbal_roll", "gimbal_yaw"):
                if r.get(key) is not None:
                    r[key] /= 10.0
        warnings.append(f"{name}: gimbal angles are in tenths of a degree; divided by 10")


def _generic_row(table, row, line, zone, warnings) -> dict[str, Any]:
    out: dict[str, Any] = {"line": line}
    name = table.name
    text = table.text(row, "time").strip()
    if not text:
        raise RecordError(name, line, "empty time")
    try:
        out["t"] = float(text)
    except ValueError:
        dt, z = parse_datetime(text, name, line)
        out["datetime"] = dt
        if z is None:
            warnings.append(f"{name}: times without a zone are taken as UTC")
        zone["zone"] = "UTC"
    out["lat"] = table.number(row, table.first("lat", "latitude"), line)
    out["lon"] = table.number(row, table.first("lon", "longitude"), line)
    out["alt"] = table.number(row, table.first("alt", "altitude"), line, "length")
    out["rel_alt"] = table.number(row, table.first("rel_alt"), line, "length")
    out["speed"] = table.number(row, table.first("speed"), line, "speed")
    for key in ("roll", "pitch", "yaw", "gimbal_roll", "gimbal_pitch", "gimbal_yaw"):
        out[key] = table.number(row, table.first(key), line)
    out["recording"] = _recording(table, row, "recording")
    return out


__all__ = ["looks_like_csv", "parse_csv_log", "parse_datetime"]
