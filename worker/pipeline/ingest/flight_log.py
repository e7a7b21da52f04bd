"""The common flight log every reader produces (read_log.py reads any of them into it).

A `FlightLog` is a time series of GNSS positions and (optionally) attitudes:

- `t`: seconds, strictly increasing, on the log's own clock. For DJI SRT files the clock
  is the video's (`time_base == "video"`: t = 0 at the first video frame); for CSV
  exports and image sets it starts at the first record (`time_base == "log"`).
- `datetime`: the wall-clock time of each sample where the log has one (naive
  `datetime64[us]`); `datetime_zone` says whether it is "UTC" or "local" (DJI SRT
  files write local time with no zone).
- `lat`, `lon`: WGS84 degrees, NaN where the aircraft had no fix (DJI writes 0, 0).
- `alt`: metres; `alt_ref` says what it is measured from: "absolute" (above sea level or
  the ellipsoid, as the aircraft logged it) or "takeoff" (height above the take-off
  point, when the log has nothing better). `rel_alt` keeps the height above take-off
  when it was logged as well.
- `attitude`: degrees, DJI conventions (yaw clockwise from north, pitch -90 = straight
  down, roll positive right side down), keys among `roll`, `pitch`, `yaw` (aircraft) and
  `gimbal_roll`, `gimbal_pitch`, `gimbal_yaw`; NaN where a sample lacks the value.
- `lines`: the line of the source file each sample came from, for messages.
- `warnings`: what the reader had to guess or drop, in plain words (skipped unreadable
  records with their line numbers among them; see `skipped`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np

from worker.pipeline.errors import InputError
from worker.pipeline.ingest.skipped import RecordError

ALT_ABSOLUTE = "absolute"
ALT_TAKEOFF = "takeoff"
ANGLE_KEYS = ("roll", "pitch", "yaw", "gimbal_roll", "gimbal_pitch", "gimbal_yaw")
_ROW_KEYS = ("lat", "lon", "alt", "rel_alt", "speed", *ANGLE_KEYS)


@dataclass
class FlightLog:
    path: str
    source_format: str
    t: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    alt: np.ndarray
    alt_ref: str
    lines: np.ndarray
    time_base: str = "log"
    variant: str = ""
    rel_alt: np.ndarray | None = None
    speed: np.ndarray | None = None
    attitude: dict[str, np.ndarray] = field(default_factory=dict)
    recording: np.ndarray | None = None
    datetime: np.ndarray | None = None
    datetime_zone: str | None = None
    warnings: list[str] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)
    # (N, 3) the position's own stated 1-sigma, east/north/up in metres (DJI RTK photos'
    # RtkStdLon/Lat/Hgt), NaN where the record states none: what a georeference's
    # residuals are checked against.
    position_sigma: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.t.size)

    @property
    def valid(self) -> np.ndarray:
        """Samples with a position fix."""
        return np.isfinite(self.lat) & np.isfinite(self.lon)

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self) else 0.0

    def median_ground_speed(self) -> float:
        """Median horizontal speed (m/s) between consecutive fixes (NaN without two);
        metres from degrees on a sphere, plenty for a speed."""
        ok = self.valid
        t, lat, lon = self.t[ok], np.radians(self.lat[ok]), np.radians(self.lon[ok])
        dt = np.diff(t)
        step = dt > 0
        if not step.any():
            return float("nan")
        north = np.diff(lat) * 6_371_000.0
        east = np.diff(lon) * np.cos(lat[1:]) * 6_371_000.0
        return float(np.median(np.hypot(east, north)[step] / dt[step]))

    @property
    def epoch(self) -> datetime | None:
        """Wall-clock time (naive, in `datetime_zone`) of t = 0, or None.

        With whole-second datetimes beside a finer relative clock (AirData), the epoch is
        the largest `datetime - t`, the tightest bound the truncated seconds allow.
        """
        if self.datetime is None:
            return None
        ok = ~np.isnat(self.datetime)
        if not ok.any():
            return None
        dt_us = self.datetime[ok].astype("datetime64[us]").astype(np.int64)
        t_us = np.round(self.t[ok] * 1e6).astype(np.int64)
        whole_seconds = np.all(dt_us % 1_000_000 == 0) and ok.sum() > 1
        offsets = dt_us - t_us
        epoch_us = int(offsets.max()) if whole_seconds else int(np.median(offsets))
        return datetime(1970, 1, 1) + timedelta(microseconds=epoch_us)

    @property
    def utc_epoch(self) -> datetime | None:
        return self.epoch if self.datetime_zone == "UTC" else None

    def has_attitude(self, *keys: str) -> bool:
        return all(k in self.attitude and np.isfinite(self.attitude[k]).any() for k in keys)

    def stated_sigma_at(self, times: np.ndarray) -> np.ndarray | None:
        """(M, 3) the stated position sigma of the record nearest each time (NaN where
        none is stated, or beyond the log), or None when the log states none at all."""
        if self.position_sigma is None or not np.isfinite(self.position_sigma).any():
            return None
        times = np.asarray(times, dtype=np.float64)
        idx = np.clip(np.searchsorted(self.t, times), 1, max(len(self) - 1, 1))
        left = np.clip(idx - 1, 0, len(self) - 1)
        right = np.clip(idx, 0, len(self) - 1)
        nearest = np.where(
            np.abs(self.t[left] - times) <= np.abs(self.t[right] - times), left, right
        )
        out = self.position_sigma[nearest].astype(np.float64)
        out[(times < self.t[0] - 1e-6) | (times > self.t[-1] + 1e-6)] = np.nan
        return out

    def stated_sigma_m(self) -> list[float] | None:
        """The median stated sigma (east, north, up) over the records that state one."""
        if self.position_sigma is None:
            return None
        ok = np.isfinite(self.position_sigma).all(axis=1)
        if not ok.any():
            return None
        return [round(float(v), 4) for v in np.median(self.position_sigma[ok], axis=0)]

    def interpolate(self, times: np.ndarray) -> dict[str, np.ndarray]:
        """Linear interpolation of position, altitude and attitude at `times` (seconds on
        the log clock). Angles are interpolated on the circle. Outside the span of valid
        samples, values are NaN."""
        times = np.asarray(times, dtype=np.float64)
        out: dict[str, np.ndarray] = {}
        ok = self.valid
        for key, values, mask in (
            ("lat", self.lat, ok),
            ("lon", self.lon, ok),
            ("alt", self.alt, ok & np.isfinite(self.alt)),
        ):
            out[key] = _interp(times, self.t[mask], values[mask])
        for key, values in self.attitude.items():
            m = np.isfinite(values)
            rad = np.radians(values[m])
            s = _interp(times, self.t[m], np.sin(rad))
            c = _interp(times, self.t[m], np.cos(rad))
            out[key] = np.degrees(np.arctan2(s, c))
        return out

    def recording_segments(self) -> list[tuple[float, float]]:
        """(start, end) seconds of each span where the log says the camera recorded."""
        if self.recording is None:
            return []
        rec = self.recording.astype(bool)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], rec.astype(np.int8), [0]])))
        return [
            (float(self.t[a]), float(self.t[min(b, len(self) - 1)]))
            for a, b in zip(edges[::2], edges[1::2], strict=True)
        ]

    def to_dict(self) -> dict[str, Any]:
        """A JSON-friendly summary (no per-sample arrays)."""
        valid = self.valid
        epoch = self.epoch
        return {
            "path": self.path,
            "source_format": self.source_format,
            "variant": self.variant,
            "samples": len(self),
            "samples_with_fix": int(valid.sum()),
            "duration_s": round(self.duration_s, 3),
            "rate_hz": round((len(self) - 1) / self.duration_s, 3) if self.duration_s else None,
            "time_base": self.time_base,
            "epoch": epoch.isoformat() if epoch else None,
            "datetime_zone": self.datetime_zone,
            "alt_ref": self.alt_ref,
            "attitude": sorted(k for k in self.attitude if np.isfinite(self.attitude[k]).any()),
            "recording_segments": [
                [round(a, 3), round(b, 3)] for a, b in self.recording_segments()
            ],
            "bounds_lonlat": (
                [
                    float(np.nanmin(self.lon)),
                    float(np.nanmin(self.lat)),
                    float(np.nanmax(self.lon)),
                    float(np.nanmax(self.lat)),
                ]
                if valid.any()
                else None
            ),
            "stated_sigma_m": self.stated_sigma_m(),
            "warnings": list(self.warnings),
            "meta": self.meta,
        }


def _interp(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    if xp.size == 0:
        return np.full(x.shape, np.nan)
    if xp.size == 1:
        return np.where(np.abs(x - xp[0]) < 1e-9, fp[0], np.nan)
    return np.interp(x, xp, fp, left=np.nan, right=np.nan)


def build_flight_log(
    path: Path | str,
    source_format: str,
    rows: list[dict[str, Any]],
    *,
    time_base: str = "log",
    variant: str = "",
    datetime_zone: str | None = None,
    warnings: list[str] | None = None,
    meta: dict[str, Any] | None = None,
) -> FlightLog:
    """Turn parsed rows into a `FlightLog`: the common checks every reader needs.

    Each row is a dict with `line` and any of `t` (seconds), `datetime` (naive
    datetime), `lat`, `lon`, `alt` (absolute), `rel_alt`, `speed`, the angle keys and
    `recording`. Rows without `t` get it from `datetime`. Positions of exactly 0, 0 are
    taken as "no fix". Rows are sorted by time; duplicate times keep the first row.
    """
    name = Path(path).name
    warnings = list(warnings or [])
    if not rows:
        raise InputError(f"{name}: no flight records found")
    dts = [r.get("datetime") for r in rows]
    has_t = all(r.get("t") is not None for r in rows)
    if not has_t:
        if any(d is None for d in dts):
            line = next(r["line"] for r in rows if r.get("t") is None and r.get("datetime") is None)
            raise InputError(f"{name}, line {line}: the record has no time")
        t0 = min(dts)
        t = np.array([(d - t0).total_seconds() for d in dts])
    else:
        t = np.array([float(r["t"]) for r in rows])
    lines = np.array([int(r["line"]) for r in rows])
    order = np.argsort(t, kind="stable")
    if np.any(np.diff(order) != 1):
        warnings.append(f"{name}: records were not in time order; sorted")
    t = t[order]
    keep = np.concatenate([[True], np.diff(t) > 0])
    if not keep.all():
        warnings.append(f"{name}: {int((~keep).sum())} records repeat an earlier time; dropped")
    idx = order[keep]
    t = t[keep]
    rows = [rows[i] for i in idx]
    lines = lines[idx]

    def column(key: str) -> np.ndarray | None:
        values = [r.get(key) for r in rows]
        if all(v is None for v in values):
            return None
        return np.array([np.nan if v is None else float(v) for v in values])

    cols = {k: column(k) for k in _ROW_KEYS}
    lat, lon = cols["lat"], cols["lon"]
    if lat is None or lon is None:
        raise InputError(f"{name}: the log has no latitude/longitude")
    no_fix = (lat == 0) & (lon == 0)
    no_fix |= ~np.isfinite(lat) | ~np.isfinite(lon)
    if no_fix.all():
        raise InputError(
            f"{name}: no record has a GPS position (latitude/longitude are 0 or missing "
            "everywhere): the aircraft had no fix"
        )
    if no_fix.any():
        warnings.append(
            f"{name}: {int(no_fix.sum())} of {len(rows)} records have no GPS fix "
            "(latitude/longitude 0 or missing); treated as missing"
        )
    lat = np.where(no_fix, np.nan, lat)
    lon = np.where(no_fix, np.nan, lon)
    bad = np.flatnonzero((np.abs(lat) > 90) | (np.abs(lon) > 180))
    if bad.size:
        i = bad[0]
        raise InputError(
            f"{name}, line {lines[i]}: latitude {lat[i]} / longitude {lon[i]} is not a "
            "position on Earth"
        )
    alt, rel_alt = cols["alt"], cols["rel_alt"]
    if alt is not None and np.isfinite(alt[~no_fix]).any():
        alt_ref = ALT_ABSOLUTE
    elif rel_alt is not None and np.isfinite(rel_alt[~no_fix]).any():
        alt, alt_ref = rel_alt.copy(), ALT_TAKEOFF
        warnings.append(
            f"{name}: only the height above the take-off point is logged; heights of "
            "the reconstruction will be relative to the take-off point"
        )
    else:
        alt, alt_ref = np.full(t.shape, np.nan), ALT_TAKEOFF
        warnings.append(f"{name}: the log has no altitude")
    attitude = {k: cols[k] for k in ANGLE_KEYS if cols[k] is not None}
    rec_values = [r.get("recording") for r in rows]
    recording = (
        None
        if all(v is None for v in rec_values)
        else np.array([bool(v) for v in rec_values], dtype=bool)
    )
    datetimes = None
    kept_dts = [r.get("datetime") for r in rows]
    if any(d is not None for d in kept_dts):
        datetimes = np.array(
            [np.datetime64(d, "us") if d is not None else np.datetime64("NaT") for d in kept_dts],
            dtype="datetime64[us]",
        )
    return FlightLog(
        path=str(path),
        source_format=source_format,
        variant=variant,
        t=t,
        lat=lat,
        lon=lon,
        alt=alt,
        alt_ref=alt_ref,
        rel_alt=rel_alt,
        speed=cols["speed"],
        attitude=attitude,
        recording=recording,
        datetime=datetimes,
        datetime_zone=datetime_zone if datetimes is not None else None,
        lines=lines,
        time_base=time_base,
        warnings=warnings,
        meta=meta or {},
    )


def parse_float(text: str, name: str, line: int, what: str) -> float | None:
    """A number from a log field; empty means missing; anything else fails clearly
    (`RecordError`: the reader may skip the record and go on)."""
    s = text.strip().replace("\u2212", "-")
    if s == "" or s.lower() in ("nan", "n/a", "na", "null", "none", "-"):
        return None
    try:
        value = float(s)
    except ValueError:
        raise RecordError(name, line, f"{what} {text.strip()!r} is not a number") from None
    if not math.isfinite(value):
        return None
    return value
