"""Camera intrinsics: user override, a table of common drone cameras, EXIF, SRT hints.

Order of precedence (the first that applies wins; `Intrinsics.source` says which):

1. `CameraOverride` given by the user: fx (pixels at the image's size), a horizontal
   field of view, or focal length + sensor width in mm; principal point and
   distortion optional.
2. The table below, looked up by EXIF `Model` (DJI writes a code such as `FC6310`) or
   by the name the user gives (`phantom4pro`): fx = focal / sensor width * image width.
   The focal length from EXIF is used when present (zoom lenses), else the table's.
3. EXIF `FocalLengthIn35mmFilm` (or the SRT's `focal_len`, a 35 mm equivalent):
   fx = f35 / 36 * image width.
4. A default, the paper's Phantom 4 Pro, with a warning.

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


@dataclass(frozen=True)
class DroneCamera:
    name: str
    sensor_width_mm: float
    focal_mm: float
    focal_35mm: float


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
        )


def resolve_intrinsics(
    width: int,
    height: int,
    *,
    override: CameraOverride | None = None,
    exif_model: str = "",
    exif_focal_mm: float | None = None,
    focal_35mm: float | None = None,
) -> Intrinsics:
    """Intrinsics for images of `width` x `height` by the precedence in the module doc."""
    if width <= 0 or height <= 0:
        raise InputError(f"invalid image size {width} x {height}")
    override = override or CameraOverride()
    warnings: list[str] = []
    dist = tuple(override.distortion) if override.distortion else (0.0,) * 5
    cx = (width - 1) / 2.0
    cy = (height - 1) / 2.0
    fx: float | None = None
    source = ""
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
        model = override.model or exif_model
        camera = lookup_camera(model) if model else None
        if model and camera is None and override.model:
            known = sorted({k for k in DRONE_CAMERAS if k.isalpha()})
            raise InputError(
                f"camera {override.model!r} is not in the table; give fx or hfov instead, "
                f"or one of: {', '.join(known)}"
            )
        if camera is not None:
            focal = exif_focal_mm or camera.focal_mm
            fx = focal / camera.sensor_width_mm * width
            source = f"table: {camera.name}"
        elif focal_35mm:
            fx = focal_35mm / 36.0 * width
            source = f"35 mm equivalent focal length {focal_35mm:g} mm"
        else:
            camera = DRONE_CAMERAS[DEFAULT_CAMERA]
            fx = camera.focal_mm / camera.sensor_width_mm * width
            source = f"default: {camera.name}"
            warnings.append(
                "camera unknown (no EXIF model, no focal length): assumed a Phantom 4 Pro "
                f"({2 * np.degrees(np.arctan(camera.sensor_width_mm / 2 / camera.focal_mm)):.0f}"
                " deg horizontal field of view); give the camera to be sure"
            )
        fy = fx
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
    )
