"""Flight logs in the formats real tools read (see shared/notes/drone-formats.md).

- `write_dji_srt`: the current DJI video telemetry (Mavic 3 / Mini 3-4 Pro and newer):
  one subtitle block per video frame::

      1
      00:00:00,000 --> 00:00:00,033
      <font size="28">FrameCnt: 1, DiffTime: 33ms
      2024-05-11 10:00:00.000
      [iso: 100] [shutter: 1/500.0] [fnum: 2.8] [ev: 0] [focal_len: 24.00] \\
      [latitude: 36.081234] [longitude: 140.101234] [rel_alt: 7.012 abs_alt: 32.118] \\
      [ct: 5500] </font>

  (the last line is one line in the file, broken here for width).

  The timestamp is local time without zone; `rel_alt` is the height above the take-off
  point, `abs_alt` the altitude (here above the ellipsoid). Optionally
  ``[gb_yaw: .. gb_pitch: .. gb_roll: ..]`` as enterprise models write.
- `write_airdata_csv`: an AirData-style flight record export at 10 Hz with the real
  column names, units in the header (feet/mph by default, or metres), and the leading
  spaces AirData puts in some names (`` xSpeed(mph)``, `` compass_heading(degrees)``,
  `` pitch(degrees)``, `` roll(degrees)``). ``datetime(utc)`` has whole seconds only;
  ``time(millisecond)`` counts from the start of the log.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np

FEET = 0.3048
MPH = 0.44704


@dataclass(frozen=True)
class SrtOptions:
    font_tags: bool = True
    decimals: int = 6
    gimbal: bool = False
    crlf: bool = False
    iso: int = 100
    shutter: str = "1/500.0"
    fnum: float = 2.8
    ev: int = 0
    focal_len: float = 24.0
    ct: int = 5500


def srt_timecode(ms: int) -> str:
    h, rem = divmod(int(ms), 3_600_000)
    m, rem = divmod(rem, 60_000)
    s, msec = divmod(rem, 1000)
    return f"{h:02d}:{m:02d}:{s:02d},{msec:03d}"


def write_dji_srt(
    path: Path,
    fps: float,
    start_local: datetime,
    lat: np.ndarray,
    lon: np.ndarray,
    rel_alt: np.ndarray,
    abs_alt: np.ndarray,
    gimbal_ypr: np.ndarray | None = None,
    options: SrtOptions | None = None,
) -> int:
    """Write one block per frame; returns the number of blocks."""
    o = options or SrtOptions()
    nl = "\r\n" if o.crlf else "\n"
    n = len(lat)
    lines: list[str] = []
    dec = o.decimals
    for i in range(n):
        t0 = round(i * 1000.0 / fps)
        t1 = round((i + 1) * 1000.0 / fps)
        stamp = start_local + timedelta(milliseconds=t0)
        text = (
            f"[iso: {o.iso}] [shutter: {o.shutter}] [fnum: {o.fnum:.1f}] [ev: {o.ev}] "
            f"[focal_len: {o.focal_len:.2f}] [latitude: {lat[i]:.{dec}f}] "
            f"[longitude: {lon[i]:.{dec}f}] [rel_alt: {rel_alt[i]:.3f} abs_alt: {abs_alt[i]:.3f}]"
        )
        if o.gimbal and gimbal_ypr is not None:
            y, p, r = gimbal_ypr[i]
            text += f" [gb_yaw: {y:.1f} gb_pitch: {p:.1f} gb_roll: {r:.1f}]"
        text += f" [ct: {o.ct}]"
        head = f"FrameCnt: {i + 1}, DiffTime: {t1 - t0}ms"
        if o.font_tags:
            head = '<font size="28">' + head
            text += " </font>"
        lines += [
            str(i + 1),
            f"{srt_timecode(t0)} --> {srt_timecode(t1)}",
            head,
            stamp.strftime("%Y-%m-%d %H:%M:%S.") + f"{stamp.microsecond // 1000:03d}",
            text,
            "",
        ]
    Path(path).write_text(nl.join(lines) + nl, encoding="utf-8", newline="")
    return n


def airdata_columns(units: str) -> list[str]:
    """The AirData export header (leading spaces included) for 'feet' or 'meters'."""
    if units not in ("feet", "meters"):
        raise ValueError("units must be 'feet' or 'meters'")
    ln = "feet" if units == "feet" else "meters"
    sp = "mph" if units == "feet" else "m/s"
    tmp = "f" if units == "feet" else "c"
    return [
        "time(millisecond)",
        "datetime(utc)",
        "latitude",
        "longitude",
        f"height_above_takeoff({ln})",
        f"height_above_ground_at_drone_location({ln})",
        f"ground_elevation_at_drone_location({ln})",
        f"altitude_above_seaLevel({ln})",
        f"height_sonar({ln})",
        f"speed({sp})",
        f"distance({ln})",
        f"mileage({ln})",
        "satellites",
        "gpslevel",
        "voltage(v)",
        f"max_altitude({ln})",
        f"max_ascent({ln})",
        f"max_speed({sp})",
        f"max_distance({ln})",
        f" xSpeed({sp})",
        f" ySpeed({sp})",
        f" zSpeed({sp})",
        " compass_heading(degrees)",
        " pitch(degrees)",
        " roll(degrees)",
        "isPhoto",
        "isVideo",
        "rc_elevator",
        "rc_aileron",
        "rc_throttle",
        "rc_rudder",
        "rc_elevator(percent)",
        "rc_aileron(percent)",
        "rc_throttle(percent)",
        "rc_rudder(percent)",
        "gimbal_heading(degrees)",
        "gimbal_pitch(degrees)",
        "gimbal_roll(degrees)",
        "battery_percent",
        "voltageCell1",
        "voltageCell2",
        "voltageCell3",
        "voltageCell4",
        "voltageCell5",
        "voltageCell6",
        "current(A)",
        f"battery_temperature({tmp})",
        f"altitude({ln})",
        f"ascent({ln})",
        "flycStateRaw",
        "flycState",
        "message",
    ]


@dataclass
class LogRecord:
    """What the aircraft logged at each row (SI units, degrees)."""

    time_ms: np.ndarray
    utc: list[datetime]
    lat: np.ndarray
    lon: np.ndarray
    rel_alt: np.ndarray
    abs_alt: np.ndarray
    ground_z: np.ndarray
    home_z: float
    vel_enu: np.ndarray
    dist_home: np.ndarray
    aircraft_ypr: np.ndarray
    gimbal_ypr: np.ndarray
    is_video: np.ndarray
    is_photo: np.ndarray
    satellites: np.ndarray
    state: list[str]


def write_airdata_csv(path: Path, rec: LogRecord, units: str = "feet") -> int:
    """Write an AirData-style CSV; returns the number of rows."""
    cols = airdata_columns(units)
    kl = 1.0 / FEET if units == "feet" else 1.0
    ks = 1.0 / MPH if units == "feet" else 1.0
    n = rec.time_ms.size
    hs = np.hypot(rec.vel_enu[:, 0], rec.vel_enu[:, 1])
    mileage = np.concatenate(
        [[0.0], np.cumsum(0.5 * (hs[1:] + hs[:-1]) * np.diff(rec.time_ms) / 1000.0)]
    )
    max_alt = np.maximum.accumulate(rec.rel_alt)
    max_speed = np.maximum.accumulate(hs)
    max_dist = np.maximum.accumulate(rec.dist_home)
    dur = max((rec.time_ms[-1] - rec.time_ms[0]) / 1000.0, 1.0)
    frac = (rec.time_ms - rec.time_ms[0]) / 1000.0 / dur
    battery = np.round(97 - 6 * frac).astype(int)
    cell = 4.18 - 0.25 * frac
    flying = np.array([s != "Motors_Off" for s in rec.state])
    current = np.where(flying, 9.0 + 3.0 * hs / max(hs.max(), 1.0), 0.0)
    temp_c = 28.0 + 12.0 * frac
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for i in range(n):
            yaw = rec.aircraft_ypr[i, 0] % 360.0
            gy = rec.gimbal_ypr[i, 0] % 360.0
            row = [
                int(rec.time_ms[i]),
                rec.utc[i].strftime("%Y-%m-%d %H:%M:%S"),
                f"{rec.lat[i]:.8f}",
                f"{rec.lon[i]:.8f}",
                f"{rec.rel_alt[i] * kl:.1f}",
                f"{(rec.rel_alt[i] + rec.home_z - rec.ground_z[i]) * kl:.1f}",
                f"{rec.ground_z[i] * kl:.1f}",
                f"{rec.abs_alt[i] * kl:.1f}",
                "0",
                f"{hs[i] * ks:.1f}",
                f"{rec.dist_home[i] * kl:.1f}",
                f"{mileage[i] * kl:.1f}",
                int(rec.satellites[i]),
                5,
                f"{cell[i] * 4:.2f}",
                f"{max_alt[i] * kl:.1f}",
                f"{max_alt[i] * kl:.1f}",
                f"{max_speed[i] * ks:.1f}",
                f"{max_dist[i] * kl:.1f}",
                f"{rec.vel_enu[i, 1] * ks:.1f}",
                f"{rec.vel_enu[i, 0] * ks:.1f}",
                f"{-rec.vel_enu[i, 2] * ks:.1f}",
                f"{yaw:.1f}",
                f"{rec.aircraft_ypr[i, 1]:.1f}",
                f"{rec.aircraft_ypr[i, 2]:.1f}",
                int(rec.is_photo[i]),
                int(rec.is_video[i]),
                1024,
                1024,
                1024,
                1024,
                0,
                0,
                0,
                0,
                f"{gy:.1f}",
                f"{rec.gimbal_ypr[i, 1]:.1f}",
                f"{rec.gimbal_ypr[i, 2]:.1f}",
                int(battery[i]),
                f"{cell[i]:.3f}",
                f"{cell[i]:.3f}",
                f"{cell[i]:.3f}",
                f"{cell[i]:.3f}",
                "0",
                "0",
                f"{current[i]:.2f}",
                f"{(temp_c[i] * 9 / 5 + 32) if units == 'feet' else temp_c[i]:.1f}",
                f"{rec.rel_alt[i] * kl:.1f}",
                f"{max(rec.rel_alt[i], 0.0) * kl:.1f}",
                {"Motors_Off": 0, "AutoTakeoff": 41, "Waypoint": 14, "AutoLanding": 12}.get(
                    rec.state[i], 6
                ),
                rec.state[i],
                "",
            ]
            w.writerow(row)
    return n
