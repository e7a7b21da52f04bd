"""JPEG image sets: EXIF GPS, time and camera, and DJI's XMP gimbal/flight attitude.

- Position: EXIF `GPSLatitude`/`Ref`, `GPSLongitude`/`Ref`, `GPSAltitude`/`Ref`; when
  EXIF has none, DJI XMP `GpsLatitude`/`GpsLongitude` (or the misspelt `GpsLongtitude`).
- Time: `DateTimeOriginal` + `SubSecTimeOriginal` (+ `OffsetTimeOriginal` when written,
  which makes it UTC); otherwise local time with no zone.
- Camera: `Make`, `Model`, `FocalLength`, `FocalLengthIn35mmFilm`, image size, and the
  sensor width implied by `FocalPlaneXResolution`/`FocalPlaneResolutionUnit` over
  `PixelXDimension` (the image width the camera meant; the JPEG's when absent).
- DJI XMP (`drone-dji:` attributes or child elements, values signed strings like
  "+87.50"): gimbal and flight roll/pitch/yaw, `RelativeAltitude`, `AbsoluteAltitude`,
  `RtkFlag` (50 fixed, 34 float, 16 single point, 0 none) and `RtkStdLon`/`RtkStdLat`/
  `RtkStdHgt`: the position's own 1-sigma, kept as the log's `position_sigma` for the
  photos whose RTK solution is fixed or float (a single-point fix states nothing useful).

`read_image_set` reads a folder (or a list of files) into an `ImageSet`, whose `log` is
a `FlightLog` with one sample per geotagged image, so image sets and videos share the
georeferencing code.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
import piexif

from worker.pipeline.errors import InputError
from worker.pipeline.ingest.camera import focal_plane_sensor_width_mm
from worker.pipeline.ingest.flight_log import ALT_ABSOLUTE, ALT_TAKEOFF, FlightLog

JPEG_SUFFIXES = (".jpg", ".jpeg")
_XMP = re.compile(rb"<x:xmpmeta.*?</x:xmpmeta>", re.DOTALL)
_XMP_ATTR = re.compile(r"drone-dji:(\w+)\s*=\s*\"([^\"]*)\"")
_XMP_ELEM = re.compile(r"<drone-dji:(\w+)>([^<]*)</drone-dji:\1>")
_XMP_KEYS = {
    "gimbalrolldegree": "gimbal_roll",
    "gimbalpitchdegree": "gimbal_pitch",
    "gimbalyawdegree": "gimbal_yaw",
    "flightrolldegree": "roll",
    "flightpitchdegree": "pitch",
    "flightyawdegree": "yaw",
    "relativealtitude": "rel_alt",
    "absolutealtitude": "abs_alt",
    "gpslatitude": "lat",
    "gpslongitude": "lon",
    "gpslongtitude": "lon",
    "rtkstdlon": "rtk_std_lon",
    "rtkstdlat": "rtk_std_lat",
    "rtkstdhgt": "rtk_std_hgt",
    "rtkflag": "rtk_flag",
}
# DJI's RtkFlag values (position solution types).
RTK_FIXED = 50
RTK_FLOAT = 34


@dataclass
class ImageMeta:
    path: str
    width: int
    height: int
    datetime: datetime | None = None
    datetime_zone: str | None = None
    lat: float | None = None
    lon: float | None = None
    alt: float | None = None
    make: str = ""
    model: str = ""
    focal_mm: float | None = None
    focal_35mm: float | None = None
    sensor_width_mm: float | None = None  # from EXIF FocalPlaneXResolution, when written
    xmp: dict[str, float] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return Path(self.path).name

    @property
    def has_gps(self) -> bool:
        return self.lat is not None and self.lon is not None

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "width": self.width,
            "height": self.height,
            "datetime": self.datetime.isoformat() if self.datetime else None,
            "datetime_zone": self.datetime_zone,
            "lat": self.lat,
            "lon": self.lon,
            "alt": self.alt,
            "make": self.make,
            "model": self.model,
            "focal_mm": self.focal_mm,
            "focal_35mm": self.focal_35mm,
            "sensor_width_mm": self.sensor_width_mm,
            "xmp": self.xmp,
        }


def _rational(value: Any) -> float | None:
    if isinstance(value, tuple) and len(value) == 2:
        num, den = value
        return num / den if den else None
    if isinstance(value, int | float):
        return float(value)
    return None


def _dms(value: Any) -> float | None:
    if not isinstance(value, tuple) or len(value) != 3:
        return None
    parts = [_rational(v) for v in value]
    if any(p is None for p in parts):
        return None
    d, m, s = parts
    return d + m / 60.0 + s / 3600.0


def _text(value: Any) -> str:
    if isinstance(value, bytes):
        return value.decode("ascii", "replace").strip("\x00 ").strip()
    return str(value or "").strip()


def _jpeg_size(data: bytes, name: str) -> tuple[int, int]:
    """(width, height) from the JPEG start-of-frame marker."""
    if data[:2] != b"\xff\xd8":
        raise InputError(f"{name}: not a JPEG image")
    i = 2
    while i + 9 < len(data):
        if data[i] != 0xFF:
            i += 1
            continue
        marker = data[i + 1]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7 or marker == 0xFF:
            i += 1 if marker == 0xFF else 2
            continue
        (length,) = struct.unpack(">H", data[i + 2 : i + 4])
        if marker in (0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE):
            height, width = struct.unpack(">HH", data[i + 5 : i + 9])
            return width, height
        i += 2 + length
    raise InputError(f"{name}: damaged JPEG (no image header found)")


def parse_xmp(data: bytes) -> dict[str, float]:
    """DJI `drone-dji:` values from the XMP packet in the file bytes (floats)."""
    match = _XMP.search(data)
    if not match:
        return {}
    text = match.group(0).decode("utf-8", "replace")
    out: dict[str, float] = {}
    for key, value in [*_XMP_ATTR.findall(text), *_XMP_ELEM.findall(text)]:
        common = _XMP_KEYS.get(key.lower())
        if common is None:
            continue
        try:
            out[common] = float(value.strip().replace("\u2212", "-"))
        except ValueError:
            continue
    return out


def read_image_metadata(path: Path | str) -> ImageMeta:
    """EXIF and DJI XMP metadata of one JPEG."""
    path = Path(path)
    name = path.name
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{name}: cannot be read ({exc.strerror})") from None
    width, height = _jpeg_size(data, name)
    try:
        exif = piexif.load(data)
    except Exception as exc:  # piexif raises bare ValueError/struct.error on damage
        raise InputError(f"{name}: damaged EXIF metadata ({exc})") from None
    zeroth, sub, gps = exif.get("0th", {}), exif.get("Exif", {}), exif.get("GPS", {})
    meta = ImageMeta(path=str(path), width=width, height=height)
    meta.make = _text(zeroth.get(piexif.ImageIFD.Make))
    meta.model = _text(zeroth.get(piexif.ImageIFD.Model))
    meta.focal_mm = _rational(sub.get(piexif.ExifIFD.FocalLength))
    f35 = sub.get(piexif.ExifIFD.FocalLengthIn35mmFilm)
    meta.focal_35mm = float(f35) if f35 else None
    unit = sub.get(piexif.ExifIFD.FocalPlaneResolutionUnit)
    meta.sensor_width_mm = focal_plane_sensor_width_mm(
        _rational(sub.get(piexif.ExifIFD.FocalPlaneXResolution)),
        unit if isinstance(unit, int) else None,
        sub.get(piexif.ExifIFD.PixelXDimension) or width,
    )
    stamp = _text(sub.get(piexif.ExifIFD.DateTimeOriginal) or zeroth.get(piexif.ImageIFD.DateTime))
    if stamp:
        try:
            dt = datetime.strptime(stamp[:19], "%Y:%m:%d %H:%M:%S")
        except ValueError:
            raise InputError(f"{name}: unreadable EXIF date-time {stamp!r}") from None
        subsec = _text(sub.get(piexif.ExifIFD.SubSecTimeOriginal))
        if subsec.isdigit():
            dt += timedelta(seconds=float("0." + subsec))
        offset = _text(sub.get(piexif.ExifIFD.OffsetTimeOriginal))
        zone = "local"
        if re.fullmatch(r"[+-]\d{2}:\d{2}", offset):
            aware = datetime.fromisoformat(dt.isoformat() + offset)
            dt, zone = aware.astimezone(UTC).replace(tzinfo=None), "UTC"
        meta.datetime, meta.datetime_zone = dt, zone
    lat = _dms(gps.get(piexif.GPSIFD.GPSLatitude))
    lon = _dms(gps.get(piexif.GPSIFD.GPSLongitude))
    if lat is not None and lon is not None:
        if _text(gps.get(piexif.GPSIFD.GPSLatitudeRef)).upper() == "S":
            lat = -lat
        if _text(gps.get(piexif.GPSIFD.GPSLongitudeRef)).upper() == "W":
            lon = -lon
        if lat != 0 or lon != 0:
            meta.lat, meta.lon = lat, lon
    alt = _rational(gps.get(piexif.GPSIFD.GPSAltitude))
    if alt is not None:
        if gps.get(piexif.GPSIFD.GPSAltitudeRef) in (1, b"\x01"):
            alt = -alt
        meta.alt = alt
    meta.xmp = parse_xmp(data)
    xmp_fix = meta.xmp.get("lat", 0.0) != 0 or meta.xmp.get("lon", 0.0) != 0
    if not meta.has_gps and "lat" in meta.xmp and "lon" in meta.xmp and xmp_fix:
        meta.lat, meta.lon = meta.xmp["lat"], meta.xmp["lon"]
    if meta.alt is None and "abs_alt" in meta.xmp:
        meta.alt = meta.xmp["abs_alt"]
    return meta


@dataclass
class ImageSet:
    images: list[ImageMeta]  # in capture order
    log: FlightLog  # one sample per geotagged image, in the same order
    image_times: np.ndarray  # seconds on the log clock, one per image (NaN without time)
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        first = self.images[0]
        return {
            "images": len(self.images),
            "geotagged": int(sum(m.has_gps for m in self.images)),
            "size": [first.width, first.height],
            "make": first.make,
            "model": first.model,
            "log": self.log.to_dict(),
            "warnings": self.warnings,
        }


def list_images(source: Path | str | list[Path]) -> list[Path]:
    if isinstance(source, list):
        return sorted(Path(p) for p in source)
    folder = Path(source)
    if not folder.is_dir():
        raise InputError(f"{folder.name}: image folder not found")
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in JPEG_SUFFIXES)


def read_image_set(source: Path | str | list[Path], min_geotagged: int = 3) -> ImageSet:
    """Read every JPEG of a folder; fails when fewer than `min_geotagged` carry GPS."""
    paths = list_images(source)
    where = source if not isinstance(source, list) else "the upload"
    if not paths:
        raise InputError(f"{Path(str(where)).name}: no JPEG images found")
    metas = [read_image_metadata(p) for p in paths]
    warnings: list[str] = []
    missing = [m.name for m in metas if not m.has_gps]
    geotagged = len(metas) - len(missing)
    if geotagged < min_geotagged:
        listed = ", ".join(missing[:5]) + (" ..." if len(missing) > 5 else "")
        raise InputError(
            f"{len(missing)} of {len(metas)} images have no GPS position in their EXIF or "
            f"XMP ({listed}); georeferencing without ground control points needs the "
            "drone's positions: enable geotagging or give a flight log"
        )
    if missing:
        warnings.append(
            f"{len(missing)} images have no GPS position and are used without one: "
            + ", ".join(missing[:5])
        )
    sizes = {(m.width, m.height) for m in metas}
    if len(sizes) > 1:
        warnings.append(f"images have {len(sizes)} different sizes: {sorted(sizes)}")
    timed = all(m.datetime is not None for m in metas)
    if timed:
        metas.sort(key=lambda m: (m.datetime, m.name))
        t0 = metas[0].datetime
        times = np.array([(m.datetime - t0).total_seconds() for m in metas])
        # Whole-second stamps of a burst: spread equal times by a millisecond each.
        for i in range(1, len(times)):
            if times[i] <= times[i - 1]:
                times[i] = times[i - 1] + 1e-3
    else:
        warnings.append("some images have no capture time; image order is the file order")
        times = np.arange(len(metas), dtype=float)
    log = _log_from_images(metas, times, timed, warnings)
    return ImageSet(images=metas, log=log, image_times=times, warnings=warnings)


def _log_from_images(
    metas: list[ImageMeta], times: np.ndarray, timed: bool, warnings: list[str]
) -> FlightLog:
    keep = [i for i, m in enumerate(metas) if m.has_gps]
    sel = [metas[i] for i in keep]
    alt = np.array([np.nan if m.alt is None else m.alt for m in sel])
    rel = np.array([m.xmp.get("rel_alt", np.nan) for m in sel])
    alt_ref = ALT_ABSOLUTE
    if not np.isfinite(alt).any() and np.isfinite(rel).any():
        alt, alt_ref = rel, ALT_TAKEOFF
    attitude = {}
    for key in ("roll", "pitch", "yaw", "gimbal_roll", "gimbal_pitch", "gimbal_yaw"):
        values = np.array([m.xmp.get(key, np.nan) for m in sel])
        if np.isfinite(values).any():
            attitude[key] = values
    position_sigma = _stated_sigmas(sel, warnings)
    zones = {m.datetime_zone for m in sel}
    datetimes = None
    if timed:
        datetimes = np.array([np.datetime64(m.datetime, "us") for m in sel])
    return FlightLog(
        path=str(Path(metas[0].path).parent),
        source_format="image_exif",
        t=times[keep],
        lat=np.array([m.lat for m in sel], dtype=float),
        lon=np.array([m.lon for m in sel], dtype=float),
        alt=alt,
        alt_ref=alt_ref,
        rel_alt=rel if np.isfinite(rel).any() else None,
        attitude=attitude,
        datetime=datetimes,
        datetime_zone=(zones.pop() if len(zones) == 1 else "local") if timed else None,
        lines=np.array(keep),
        time_base="log",
        variant=f"{metas[0].make} {metas[0].model}".strip(),
        warnings=list(warnings),
        meta={"images": len(metas), **_rtk_counts(sel)},
        position_sigma=position_sigma,
    )


def _rtk_counts(metas: list[ImageMeta]) -> dict[str, Any]:
    flags = [m.xmp.get("rtk_flag") for m in metas]
    if all(f is None for f in flags):
        return {}
    return {
        "rtk": {
            "fixed": sum(f == RTK_FIXED for f in flags),
            "float": sum(f == RTK_FLOAT for f in flags),
            "other": sum(f is not None and f not in (RTK_FIXED, RTK_FLOAT) for f in flags),
            "none": sum(f is None for f in flags),
        }
    }


def _stated_sigmas(metas: list[ImageMeta], warnings: list[str]) -> np.ndarray | None:
    """(N, 3) RtkStdLon/Lat/Hgt (east, north, up) of the photos whose RTK solution is
    fixed or float (or that state a sigma without a flag); NaN for the others."""
    out = np.full((len(metas), 3), np.nan)
    for i, m in enumerate(metas):
        std = [m.xmp.get(k) for k in ("rtk_std_lon", "rtk_std_lat", "rtk_std_hgt")]
        flag = m.xmp.get("rtk_flag")
        if any(v is None or not np.isfinite(v) or v <= 0 for v in std):
            continue
        if flag is None or flag in (RTK_FIXED, RTK_FLOAT):
            out[i] = std
    stated = np.isfinite(out).all(axis=1)
    if not stated.any():
        return None
    counts = _rtk_counts(metas).get("rtk")
    if counts and counts["fixed"] < len(metas):
        warnings.append(
            f"RTK: {counts['fixed']} of {len(metas)} photos have a fixed solution, "
            f"{counts['float']} a float one and {len(metas) - counts['fixed'] - counts['float']}"
            " none or single-point: those are weighted by their stated accuracy or, "
            "stating none, checked as stand-alone GPS"
        )
    return out
