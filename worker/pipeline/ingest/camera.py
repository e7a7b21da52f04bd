"""Camera intrinsics: user override, a sensor table, EXIF, SRT hints, or a marked guess.

Order of preference (the first that applies wins; `Intrinsics.source` says which and
why, in words a user can check):

1. `CameraOverride` given by the user: fx (pixels at the image's size), a horizontal
   field of view, or focal length + sensor width in mm; principal point and
   distortion optional. The user knows their camera better than any metadata.
2. The camera table, looked up by EXIF `Model` (DJI writes a code such as `FC6310`,
   compacts their name, `Canon PowerShot SX260 HS`) or by the name the user gives
   (`phantom4pro`): fx = focal / sensor width * image width, the sensor width being the
   published width of the camera's sensor and the focal length EXIF `FocalLength` (the
   real focal length at capture, which zoom lenses change), else the table's fixed lens.
   First because both numbers are physical lengths known to well under 1 %.
3. EXIF `FocalLength` with `FocalPlaneXResolution` / `FocalPlaneResolutionUnit`: the
   sensor width is the EXIF image width (`PixelXDimension`, else the JPEG's) divided by
   the camera's own pixels per mm. Exact when right, but only some cameras write it and
   some firmware writes it for another readout size than the saved image, so it comes
   after the table we have checked, and values giving a sensor outside 2-60 mm are
   ignored.
4. EXIF `FocalLengthIn35mmFilm` (or the SRT's `focal_len`, a 35 mm equivalent):
   fx = f35 / 36 * image width. Last of the measured sources because cameras round it to
   whole millimetres (24 for 24.4: up to 2 % at wide angles) and it is defined on the
   diagonal, so for a 4:3 sensor 36 mm is not the equivalent width (fx ~4 % low).
5. A guess, the paper's Phantom 4 Pro field of view (74 degrees), with a warning that
   says what is missing, and `Intrinsics.focal_guess` set (the SfM method can refine
   it on request, `SfmOptions.refine_guessed_focal`; on drone surveys the refinement
   moved a right guess by 15 % or more, so neither method does by default).

Video is taken to be read out over the full sensor width (DJI's 16:9 modes crop the
height), so the same fx / width ratio holds for stills and video; modes that crop the
width need an override. Distortion is zero unless given: drone firmware corrects most
of it in video, and SfM can refine it for stills.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from worker.pipeline.errors import InputError

# Published active-area widths (mm) of the common sensor formats. The inch names are
# vidicon-era sizes, not a length: look them up, never compute them.
SENSOR_FORMATS: dict[str, float] = {
    '1/2.3"': 6.17,
    '1/2"': 6.4,
    '1/1.7"': 7.6,
    '1/1.3"': 9.7,
    '1"': 13.2,
    "4/3": 17.3,
    "APS-C": 23.5,  # Nikon, Sony, Fujifilm; Canon's APS-C is 22.3 mm, listed per model
    "full frame": 36.0,
}


@dataclass(frozen=True)
class DroneCamera:
    """A camera of the table: drones with their fixed lens, or compacts and system
    cameras (zoom or interchangeable lenses: no focal length, EXIF must give it)."""

    name: str
    sensor_width_mm: float
    focal_mm: float | None
    focal_35mm: float | None

    @property
    def sensor(self) -> str:
        """The format's name when the width is a standard one (for messages)."""
        for name, width in SENSOR_FORMATS.items():
            if abs(width - self.sensor_width_mm) < 0.05:
                return f"{name} sensor {width:g} mm wide"
        return f"sensor {self.sensor_width_mm:g} mm wide"


# EXIF Model codes (upper case) and friendly names -> camera. Values from DJI's
# specifications (sensor width of the active area, real focal length, 35 mm equivalent).
DRONE_CAMERAS: dict[str, DroneCamera] = {}
_TABLE = [
    (("FC6310", "FC6310S", "PHANTOM4PRO", "P4P"), "Phantom 4 Pro / Pro V2", 13.2, 8.8, 24),
    (("FC6310R", "PHANTOM4RTK", "P4RTK"), "Phantom 4 RTK", 13.2, 8.8, 24),
    (("FC330", "FC300X", "PHANTOM4"), "Phantom 4 / Phantom 3 Pro", 6.17, 3.61, 20),
    (("FC220", "MAVICPRO"), "Mavic Pro", 6.17, 4.73, 26),
    (("L1D-20C", "MAVIC2PRO"), "Mavic 2 Pro (Hasselblad L1D-20c)", 13.2, 10.26, 28),
    (("FC2204", "MAVIC2ZOOM"), "Mavic 2 Zoom (wide end)", 6.17, 4.3, 24),
    (("L2D-20C", "MAVIC3"), "Mavic 3 (Hasselblad L2D-20c)", 17.3, 12.29, 24),
    (("M3E", "MAVIC3E"), "Mavic 3 Enterprise", 17.3, 12.29, 24),
    (("M3T", "MAVIC3T"), "Mavic 3 Thermal (wide)", 6.4, 4.4, 24),
    (("FC3411", "AIR2S"), "Air 2S", 13.2, 8.38, 22),
    (("FC3170", "MAVICAIR2"), "Mavic Air 2", 6.4, 4.49, 24),
    (("FC7303", "MINI2"), "Mini 2", 6.17, 4.49, 24),
    (("FC3582", "MINI3PRO"), "Mini 3 Pro", 9.7, 6.72, 24),
    (("FC8482", "MINI4PRO"), "Mini 4 Pro", 9.7, 6.72, 24),
    (("ZH20", "ZH20T", "H20", "H20T"), "Zenmuse H20/H20T wide (Matrice 300)", 6.17, 4.5, 24),
    (("ZENMUSEP1", "P1"), "Zenmuse P1 35 mm (Matrice 300/350)", 35.9, 35.0, 35),
    (("M30", "M30T"), "Matrice 30 wide", 6.4, 4.5, 24),
    (("M4E", "MATRICE4E"), "Matrice 4E wide", 17.3, 12.29, 24),
    (("FC6510", "X4S"), "Zenmuse X4S", 13.2, 8.8, 24),
    (("FC6520", "X5S"), "Zenmuse X5S 15 mm", 17.3, 15.0, 30),
]
for _keys, _name, _sw, _f, _f35 in _TABLE:
    for _key in _keys:
        DRONE_CAMERAS[_key] = DroneCamera(_name, _sw, _f, _f35)
DEFAULT_CAMERA = "FC6310"

# Cameras that are not drones (compacts with built-in GPS, system cameras on survey
# rigs), by EXIF Model as the maker writes it: the sensor width from the maker's
# published format; the focal length always comes from EXIF (zooms, lenses change).
_S = SENSOR_FORMATS
_CONSUMER = [
    (("Canon PowerShot SX260 HS", "Canon PowerShot SX280 HS"), _S['1/2.3"']),
    (("Canon PowerShot SX730 HS", "Canon PowerShot SX740 HS"), _S['1/2.3"']),
    (("Canon PowerShot S100", "Canon PowerShot S110", "Canon PowerShot S120"), _S['1/1.7"']),
    (("Canon PowerShot G9 X", "Canon PowerShot G7 X Mark II"), _S['1"']),
    (("Canon EOS 5D Mark IV", "Canon EOS R5"), _S["full frame"]),
    (("Canon EOS 80D", "Canon EOS M50"), 22.3),
    (("DSC-RX100", "DSC-RX100M2", "DSC-RX100M3", "DSC-RX100M4", "DSC-RX100M5"), _S['1"']),
    (("DSC-RX100M6", "DSC-RX100M7"), _S['1"']),
    (("ILCE-6000", "ILCE-6400", "ILCE-6600"), _S["APS-C"]),
    (("ILCE-7RM2", "ILCE-7RM3", "ILCE-7RM4", "ILCE-7M3"), _S["full frame"]),
    (("NIKON D850", "NIKON D750", "NIKON Z 7"), _S["full frame"]),
    (("COOLPIX P900", "COOLPIX AW130", "COOLPIX W300"), _S['1/2.3"']),
    (("TG-5", "TG-6"), _S['1/2.3"']),
    (("E-M10MarkII", "E-M10MarkIII", "E-M5MarkII"), _S["4/3"]),
    (("DMC-GX80", "DMC-GX85", "DC-GX9", "DMC-GH4", "DC-GH5"), _S["4/3"]),
    (("DMC-TZ70", "DMC-ZS50", "DC-TZ90"), _S['1/2.3"']),
    (("X-T2", "X-T3", "X-T30"), _S["APS-C"]),
]
for _models, _sw in _CONSUMER:
    for _model in _models:
        _key = _model.upper().replace(" ", "").replace("_", "")
        DRONE_CAMERAS.setdefault(_key, DroneCamera(_model, _sw, None, None))

# FocalPlaneResolutionUnit: 2 inch (the EXIF default), 3 cm; 4 mm and 5 um are not in
# the standard but some makers write them (as exiftool documents).
_FOCAL_PLANE_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}


def focal_plane_sensor_width_mm(
    resolution: float | None, unit: int | None, pixels: int | None
) -> float | None:
    """Sensor width from EXIF FocalPlaneXResolution (pixels per unit), its unit and the
    image width the camera meant (PixelXDimension); None when any is missing."""
    if not resolution or not pixels or resolution <= 0:
        return None
    per_unit = _FOCAL_PLANE_MM.get(unit or 2)
    if per_unit is None:
        return None
    return pixels / (resolution / per_unit)


def lookup_camera(model: str) -> DroneCamera | None:
    key = model.upper().replace(" ", "").replace("_", "")
    return DRONE_CAMERAS.get(key) or DRONE_CAMERAS.get(key.replace("-", ""))


@dataclass
class CameraOverride:
    """What the user knows better than the metadata. Pixel values refer to `width`
    (the image or video width the values were measured at) when given."""

    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    width: int | None = None
    hfov_deg: float | None = None
    focal_mm: float | None = None
    sensor_width_mm: float | None = None
    model: str | None = None
    distortion: tuple[float, ...] | None = None
    # Video: the time over which a frame's rows are read (rolling shutter, top to
    # bottom); 0 or None: a global shutter.
    readout_ms: float | None = None


@dataclass
class Intrinsics:
    """A pinhole camera (+ OpenCV k1, k2, p1, p2, k3) for images `width` x `height`."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    source: str = ""
    warnings: list[str] = field(default_factory=list)
    # Nothing identified the camera: fx is an assumption that SfM should refine.
    focal_guess: bool = False
    # Seconds over which a video frame's rows are read, top to bottom (0: a global
    # shutter); the SLAM method moves what it measures to a global shutter's view.
    readout_s: float = 0.0

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist(self) -> np.ndarray:
        return np.asarray(self.distortion, dtype=np.float64)

    @property
    def hfov_deg(self) -> float:
        return float(np.degrees(2 * np.arctan(self.width / (2 * self.fx))))

    def scaled(self, width: int, height: int) -> Intrinsics:
        """The same camera for images resized to width x height (pixel centres at
        integers: x' = (x + 0.5) * s - 0.5)."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(
            width=width,
            height=height,
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
            distortion=self.distortion,
            source=self.source,
            warnings=list(self.warnings),
            focal_guess=self.focal_guess,
            readout_s=self.readout_s,
        )

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["distortion"] = list(self.distortion)
        d["hfov_deg"] = round(self.hfov_deg, 3)
        return d

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Intrinsics:
        """Inverse of `to_dict` (derived values are ignored)."""
        return cls(
            width=int(data["width"]),
            height=int(data["height"]),
            fx=float(data["fx"]),
            fy=float(data["fy"]),
            cx=float(data["cx"]),
            cy=float(data["cy"]),
            distortion=tuple(data.get("distortion") or (0.0,) * 5),
            source=data.get("source", ""),
            warnings=list(data.get("warnings", [])),
            focal_guess=bool(data.get("focal_guess", False)),
            readout_s=float(data.get("readout_s", 0.0)),
        )


def resolve_intrinsics(
    width: int,
    height: int,
    *,
    override: CameraOverride | None = None,
    exif_model: str = "",
    exif_focal_mm: float | None = None,
    focal_35mm: float | None = None,
    exif_sensor_width_mm: float | None = None,
) -> Intrinsics:
    """Intrinsics for images of `width` x `height` by the order in the module doc.

    `exif_sensor_width_mm` is the width implied by EXIF FocalPlaneXResolution (see
    `focal_plane_sensor_width_mm`)."""
    if width <= 0 or height <= 0:
        raise InputError(f"invalid image size {width} x {height}")
    override = override or CameraOverride()
    warnings: list[str] = []
    dist = tuple(override.distortion) if override.distortion else (0.0,) * 5
    cx = (width - 1) / 2.0
    cy = (height - 1) / 2.0
    fx: float | None = None
    source = ""
    guess = False
    if override.fx is not None:
        scale = width / override.width if override.width else 1.0
        fx = override.fx * scale
        fy = (override.fy or override.fx) * scale
        if override.cx is not None:
            cx = override.cx * scale
        if override.cy is not None:
            cy = override.cy * scale
        source = "override: fx"
    elif override.hfov_deg is not None:
        if not 1.0 < override.hfov_deg < 179.0:
            raise InputError(f"horizontal field of view {override.hfov_deg} deg is not valid")
        fx = fy = width / (2 * np.tan(np.radians(override.hfov_deg) / 2))
        source = "override: hfov"
    elif override.focal_mm is not None and override.sensor_width_mm is not None:
        fx = fy = override.focal_mm / override.sensor_width_mm * width
        source = "override: focal and sensor width"
    if fx is None:
        fx, source, guess = _from_metadata(
            width, override, exif_model, exif_focal_mm, focal_35mm, exif_sensor_width_mm, warnings
        )
        fy = fx
    readout_ms = override.readout_ms or 0.0
    if not 0.0 <= readout_ms < 1000.0:
        raise InputError(
            f"the camera's readout_ms (a video frame's readout time) must be at least 0 and "
            f"under 1000, not {readout_ms}"
        )
    return Intrinsics(
        width=width,
        height=height,
        fx=float(fx),
        fy=float(fy),
        cx=float(cx),
        cy=float(cy),
        distortion=dist,
        source=source,
        warnings=warnings,
        focal_guess=guess,
        readout_s=readout_ms / 1000.0,
    )


def _from_metadata(
    width: int,
    override: CameraOverride,
    exif_model: str,
    exif_focal_mm: float | None,
    focal_35mm: float | None,
    exif_sensor_width_mm: float | None,
    warnings: list[str],
) -> tuple[float, str, bool]:
    """(fx, source, is a guess) from the camera table, EXIF or SRT: steps 2-5."""
    model = override.model or exif_model
    camera = lookup_camera(model) if model else None
    if model and camera is None and override.model:
        known = sorted({k for k in DRONE_CAMERAS if k.isalpha()})
        raise InputError(
            f"camera {override.model!r} is not in the table; give fx or hfov instead, "
            f"or one of: {', '.join(known)}"
        )
    exif_focal = exif_focal_mm if exif_focal_mm and exif_focal_mm > 0 else None
    if camera is not None and (exif_focal or camera.focal_mm):
        focal = exif_focal or camera.focal_mm
        assert focal is not None  # one of the two, by the condition above
        fx = focal / camera.sensor_width_mm * width
        said = "from EXIF" if exif_focal else "from the camera table (none in EXIF)"
        return (
            fx,
            f"table: {camera.name}: {camera.sensor} from the camera table, "
            f"focal {focal:g} mm {said}: fx = {fx:.0f} px",
            False,
        )
    if exif_sensor_width_mm is not None and not 2.0 <= exif_sensor_width_mm <= 60.0:
        warnings.append(
            f"EXIF focal-plane resolution implies a {exif_sensor_width_mm:.3g} mm wide "
            "sensor, which no camera has: ignored"
        )
        exif_sensor_width_mm = None
    named = f"{model}: " if model else ""
    if exif_focal and exif_sensor_width_mm:
        fx = exif_focal / exif_sensor_width_mm * width
        return (
            fx,
            f"focal plane: {named}sensor {exif_sensor_width_mm:.3g} mm wide from EXIF "
            f"FocalPlaneXResolution, focal {exif_focal:g} mm from EXIF: fx = {fx:.0f} px",
            False,
        )
    if focal_35mm:
        fx = focal_35mm / 36.0 * width
        return (
            fx,
            f"35 mm equivalent focal length {focal_35mm:g} mm"
            f"{' of ' + model if model else ''} (sensor width unknown): "
            f"fx = {focal_35mm:g} / 36 * {width} = {fx:.0f} px",
            False,
        )
    # Nothing identifies the lens and sensor: say what is missing, assume the paper's
    # camera, and let SfM refine the focal length.
    if camera is not None:
        why = f"{camera.name} is in the camera table ({camera.sensor}) but EXIF has no focal length"
    elif model:
        why = f"camera {model!r} is not in the camera table"
        why += (
            f" and EXIF has its focal length ({exif_focal:g} mm) but neither a 35 mm "
            "equivalent nor a usable focal-plane resolution, so the sensor width is unknown"
            if exif_focal
            else " and EXIF has no focal length"
        )
    elif exif_focal:
        why = (
            f"no EXIF camera model; EXIF focal length {exif_focal:g} mm but no 35 mm "
            "equivalent or usable focal-plane resolution, so the sensor width is unknown"
        )
    else:
        why = "camera unknown: no EXIF camera model, no focal length"
    default = DRONE_CAMERAS[DEFAULT_CAMERA]
    assert default.focal_mm is not None  # a drone entry: fixed lens
    fx = default.focal_mm / default.sensor_width_mm * width
    hfov = 2 * np.degrees(np.arctan(default.sensor_width_mm / 2 / default.focal_mm))
    warnings.append(
        f"{why}: assumed a Phantom 4 Pro ({hfov:.0f} deg horizontal field of view, "
        f"fx = {fx:.0f} px) as a guess, which a drone survey cannot correct (a wrong focal "
        "length scales the heights); give the camera (model, fx or field of view) to be sure"
    )
    return fx, f"guess: {why}; assumed {default.name}", True
