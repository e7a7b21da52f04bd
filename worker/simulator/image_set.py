"""Still images as a DJI drone writes them: JPEG with EXIF (camera, time, GPS) and the
DJI XMP packet (gimbal and flight attitude, relative and absolute altitude).

EXIF GPS uses degree/minute/second rationals with hemisphere references; the altitude
is `GPSAltitude` above sea level (here: the ellipsoid). XMP values are signed strings
(``"+87.50"``) written as attributes of ``rdf:Description`` in the
``http://www.dji.com/drone-dji/1.0/`` namespace, as DJI firmware does; RTK flights add
``RtkFlag`` and ``RtkStdLon/Lat/Hgt``.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import cv2
import numpy as np
import piexif

XMP_HEADER = b"http://ns.adobe.com/xap/1.0/\x00"


@dataclass
class ImageMeta:
    """What goes into one image's metadata (angles in degrees, heights in metres)."""

    time_local: datetime
    lat: float
    lon: float
    abs_alt: float
    rel_alt: float
    gimbal_yaw: float
    gimbal_pitch: float
    gimbal_roll: float
    flight_yaw: float
    flight_pitch: float
    flight_roll: float
    make: str = "DJI"
    model: str = "FC6310"
    focal_length_mm: float = 8.8
    focal_length_35mm: int = 24
    rtk_std: tuple[float, float, float] | None = None


def _dms(value: float) -> tuple[tuple[int, int], tuple[int, int], tuple[int, int]]:
    v = abs(value)
    d = int(v)
    m = int((v - d) * 60)
    s = (v - d - m / 60.0) * 3600.0
    return ((d, 1), (m, 1), (round(s * 10000), 10000))


def _signed(v: float, digits: int = 2) -> str:
    return f"{v:+.{digits}f}"


def dji_xmp(meta: ImageMeta) -> bytes:
    """The XMP packet (UTF-8 bytes, without the APP1 header)."""
    attrs = {
        "tiff:Make": meta.make,
        "tiff:Model": meta.model,
        "dc:format": "image/jpg",
        "drone-dji:GpsLatitude": f"{meta.lat:.8f}",
        "drone-dji:GpsLongitude": f"{meta.lon:.8f}",
        "drone-dji:AbsoluteAltitude": _signed(meta.abs_alt),
        "drone-dji:RelativeAltitude": _signed(meta.rel_alt),
        "drone-dji:GimbalRollDegree": _signed(meta.gimbal_roll),
        "drone-dji:GimbalYawDegree": _signed(meta.gimbal_yaw),
        "drone-dji:GimbalPitchDegree": _signed(meta.gimbal_pitch),
        "drone-dji:FlightRollDegree": _signed(meta.flight_roll),
        "drone-dji:FlightYawDegree": _signed(meta.flight_yaw),
        "drone-dji:FlightPitchDegree": _signed(meta.flight_pitch),
        "drone-dji:CamReverse": "0",
        "drone-dji:GimbalReverse": "0",
    }
    if meta.rtk_std is not None:
        attrs["drone-dji:RtkFlag"] = "50"
        attrs["drone-dji:RtkStdLon"] = f"{meta.rtk_std[0]:.5f}"
        attrs["drone-dji:RtkStdLat"] = f"{meta.rtk_std[1]:.5f}"
        attrs["drone-dji:RtkStdHgt"] = f"{meta.rtk_std[2]:.5f}"
    body = "\n".join(f'   {k}="{v}"' for k, v in attrs.items())
    date = meta.time_local.strftime("%Y-%m-%d")
    xml = (
        '<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>\n'
        '<x:xmpmeta xmlns:x="adobe:ns:meta/">\n'
        ' <rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">\n'
        '  <rdf:Description rdf:about="DJI Meta Data"\n'
        '    xmlns:tiff="http://ns.adobe.com/tiff/1.0/"\n'
        '    xmlns:exif="http://ns.adobe.com/exif/1.0/"\n'
        '    xmlns:xmp="http://ns.adobe.com/xap/1.0/"\n'
        '    xmlns:xmpMM="http://ns.adobe.com/xap/1.0/mm/"\n'
        '    xmlns:dc="http://purl.org/dc/elements/1.1/"\n'
        '    xmlns:crs="http://ns.adobe.com/camera-raw-settings/1.0/"\n'
        '    xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/"\n'
        f'   xmp:ModifyDate="{date}"\n'
        f'   xmp:CreateDate="{date}"\n'
        f"{body}>\n"
        "  </rdf:Description>\n"
        " </rdf:RDF>\n"
        "</x:xmpmeta>\n"
        '<?xpacket end="w"?>'
    )
    return xml.encode("utf-8")


def exif_bytes(meta: ImageMeta, width: int, height: int) -> bytes:
    stamp = meta.time_local.strftime("%Y:%m:%d %H:%M:%S")
    sub = f"{meta.time_local.microsecond // 1000:03d}"
    zeroth = {
        piexif.ImageIFD.Make: meta.make,
        piexif.ImageIFD.Model: meta.model,
        piexif.ImageIFD.Orientation: 1,
        piexif.ImageIFD.XResolution: (72, 1),
        piexif.ImageIFD.YResolution: (72, 1),
        piexif.ImageIFD.ResolutionUnit: 2,
        piexif.ImageIFD.Software: "slidewatch-simulator",
        piexif.ImageIFD.DateTime: stamp,
    }
    exif = {
        piexif.ExifIFD.ExposureTime: (1, 500),
        piexif.ExifIFD.FNumber: (28, 10),
        piexif.ExifIFD.ExposureProgram: 2,
        piexif.ExifIFD.ISOSpeedRatings: 100,
        piexif.ExifIFD.ExifVersion: b"0230",
        piexif.ExifIFD.DateTimeOriginal: stamp,
        piexif.ExifIFD.DateTimeDigitized: stamp,
        piexif.ExifIFD.SubSecTimeOriginal: sub,
        piexif.ExifIFD.ExposureBiasValue: (0, 1),
        piexif.ExifIFD.MeteringMode: 2,
        piexif.ExifIFD.FocalLength: (round(meta.focal_length_mm * 100), 100),
        piexif.ExifIFD.FocalLengthIn35mmFilm: meta.focal_length_35mm,
        piexif.ExifIFD.ColorSpace: 1,
        piexif.ExifIFD.PixelXDimension: width,
        piexif.ExifIFD.PixelYDimension: height,
    }
    gps = {
        piexif.GPSIFD.GPSVersionID: (2, 3, 0, 0),
        piexif.GPSIFD.GPSLatitudeRef: "N" if meta.lat >= 0 else "S",
        piexif.GPSIFD.GPSLatitude: _dms(meta.lat),
        piexif.GPSIFD.GPSLongitudeRef: "E" if meta.lon >= 0 else "W",
        piexif.GPSIFD.GPSLongitude: _dms(meta.lon),
        piexif.GPSIFD.GPSAltitudeRef: 0 if meta.abs_alt >= 0 else 1,
        piexif.GPSIFD.GPSAltitude: (round(abs(meta.abs_alt) * 1000), 1000),
        piexif.GPSIFD.GPSMapDatum: "WGS-84",
    }
    return piexif.dump({"0th": zeroth, "Exif": exif, "GPS": gps, "1st": {}, "thumbnail": None})


def insert_app1_after_exif(jpeg: bytes, payload: bytes) -> bytes:
    """Insert an APP1 segment (XMP) right after the EXIF APP1 (or after SOI)."""
    if jpeg[:2] != b"\xff\xd8":
        raise ValueError("not a JPEG")
    pos = 2
    # Skip APP0 (JFIF) and the EXIF APP1 if present.
    while jpeg[pos : pos + 2] in (b"\xff\xe0", b"\xff\xe1"):
        length = int.from_bytes(jpeg[pos + 2 : pos + 4], "big")
        pos += 2 + length
    seg_len = len(payload) + 2
    if seg_len > 0xFFFF:
        raise ValueError("XMP packet too large for one APP1 segment")
    seg = b"\xff\xe1" + seg_len.to_bytes(2, "big") + payload
    return jpeg[:pos] + seg + jpeg[pos:]


def write_dji_jpeg(path: Path, rgb: np.ndarray, meta: ImageMeta, quality: int = 92) -> int:
    """Write the image with EXIF and DJI XMP; returns the file size in bytes."""
    ok, buf = cv2.imencode(".jpg", rgb[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    h, w = rgb.shape[:2]
    out = io.BytesIO()
    piexif.insert(exif_bytes(meta, w, h), buf.tobytes(), out)
    data = insert_app1_after_exif(out.getvalue(), XMP_HEADER + dji_xmp(meta))
    Path(path).write_bytes(data)
    return len(data)
