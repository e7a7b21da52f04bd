"""Camera intrinsics, attitude conventions and projection.

Conventions used everywhere in the simulator:

- World: the local scene frame, x east, y north, z up (metres).
- Camera: OpenCV axes, x right, y down, z forward (optical axis); pixel centres at
  integer coordinates, (0, 0) is the centre of the top-left pixel.
- Attitude: DJI gimbal angles in degrees. ``yaw`` is the heading of the optical axis
  (or of the image top when looking straight down), clockwise from north;
  ``pitch`` is 0 at the horizon and -90 straight down; ``roll`` is positive when the
  right side of the image tilts down.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np

# DJI Phantom 4 Pro camera (FC6310): 1" sensor 13.2 mm x 8.8 mm, 8.8 mm lens (24 mm
# equivalent), 84 deg diagonal field of view for 3:2 stills. 16:9 video is read from
# the full sensor width, so the horizontal field of view is the same.
P4P_SENSOR_WIDTH_MM = 13.2
P4P_FOCAL_MM = 8.8
P4P_FOCAL_35MM = 24


@dataclass(frozen=True)
class CameraModel:
    """A pinhole camera with the OpenCV distortion model (k1, k2, p1, p2, k3)."""

    name: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    focal_length_mm: float = P4P_FOCAL_MM
    focal_length_35mm: int = P4P_FOCAL_35MM
    sensor_width_mm: float = P4P_SENSOR_WIDTH_MM
    make: str = "DJI"
    model: str = "FC6310"

    @classmethod
    def phantom4pro(
        cls,
        width: int = 640,
        height: int = 360,
        distortion: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0),
        kind: str = "video",
    ) -> CameraModel:
        """A Phantom 4 Pro-like camera at the given output resolution."""
        fx = width * P4P_FOCAL_MM / P4P_SENSOR_WIDTH_MM
        return cls(
            name=f"phantom4pro-{kind}-{width}x{height}",
            width=width,
            height=height,
            fx=fx,
            fy=fx,
            cx=(width - 1) / 2.0,
            cy=(height - 1) / 2.0,
            distortion=tuple(float(d) for d in distortion),
        )

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        return any(abs(d) > 0 for d in self.distortion)

    @property
    def hfov_deg(self) -> float:
        return float(np.degrees(2 * np.arctan(self.width / (2 * self.fx))))

    @property
    def vfov_deg(self) -> float:
        return float(np.degrees(2 * np.arctan(self.height / (2 * self.fy))))

    def ground_footprint(self, distance_m: float) -> tuple[float, float]:
        """Width and height in metres of the area seen straight down from `distance_m`."""
        return distance_m * self.width / self.fx, distance_m * self.height / self.fy

    def distort_normalized(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Apply the lens distortion to normalised image coordinates."""
        if not self.has_distortion:
            return x, y
        k1, k2, p1, p2, k3 = self.distortion
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return xd, yd

    def project_camera(self, pc: np.ndarray) -> np.ndarray:
        """Project camera-frame points (..., 3) to pixel coordinates (..., 2)."""
        z = pc[..., 2]
        x, y = self.distort_normalized(pc[..., 0] / z, pc[..., 1] / z)
        return np.stack([self.fx * x + self.cx, self.fy * y + self.cy], axis=-1)

    def pixel_rays(self) -> np.ndarray:
        """Camera-frame ray directions (height, width, 3) through every pixel centre,
        scaled so that their z component is 1."""
        u, v = np.meshgrid(np.arange(self.width, dtype=np.float64), np.arange(self.height))
        if self.has_distortion:
            pts = np.stack([u.ravel(), v.ravel()], axis=-1).reshape(-1, 1, 2)
            und = cv2.undistortPointsIter(
                pts,
                self.K,
                np.asarray(self.distortion),
                None,
                None,
                (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12),
            ).reshape(self.height, self.width, 2)
            x, y = und[..., 0], und[..., 1]
        else:
            x = (u - self.cx) / self.fx
            y = (v - self.cy) / self.fy
        return np.stack([x, y, np.ones_like(x)], axis=-1).astype(np.float32)

    @classmethod
    def from_dict(cls, d: dict) -> CameraModel:
        """Inverse of `to_dict` (extra keys are ignored)."""
        kw = {k: d[k] for k in cls.__dataclass_fields__ if k in d}
        kw["distortion"] = tuple(float(x) for x in kw.get("distortion", (0.0,) * 5))
        return cls(**kw)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["distortion"] = list(self.distortion)
        d["distortion_model"] = "opencv (k1, k2, p1, p2, k3)"
        d["pixel_convention"] = "pixel centres at integer coordinates, (0, 0) top-left"
        d["hfov_deg"] = round(self.hfov_deg, 4)
        d["vfov_deg"] = round(self.vfov_deg, 4)
        return d


def rotation_world_from_camera(yaw_deg, pitch_deg, roll_deg) -> np.ndarray:
    """Rotation matrices (..., 3, 3) whose columns are the camera x, y, z axes in the
    world frame, for DJI-style yaw/pitch/roll in degrees (see the module docstring)."""
    psi = np.radians(np.asarray(yaw_deg, dtype=np.float64))
    th = np.radians(np.asarray(pitch_deg, dtype=np.float64))
    ph = np.radians(np.asarray(roll_deg, dtype=np.float64))
    psi, th, ph = np.broadcast_arrays(psi, th, ph)
    zero = np.zeros_like(psi)
    one = np.ones_like(psi)
    h = np.stack([np.sin(psi), np.cos(psi), zero], axis=-1)
    right = np.stack([np.cos(psi), -np.sin(psi), zero], axis=-1)
    up = np.stack([zero, zero, one], axis=-1)
    fwd = np.cos(th)[..., None] * h + np.sin(th)[..., None] * up
    img_up = -np.sin(th)[..., None] * h + np.cos(th)[..., None] * up
    down = -img_up
    x = np.cos(ph)[..., None] * right + np.sin(ph)[..., None] * down
    y = -np.sin(ph)[..., None] * right + np.cos(ph)[..., None] * down
    return np.stack([x, y, fwd], axis=-1)


def attitude_from_rotation(r_wc: np.ndarray) -> tuple[float, float, float]:
    """Inverse of `rotation_world_from_camera`: (yaw, pitch, roll) in degrees."""
    fwd = r_wc[:, 2]
    x = r_wc[:, 0]
    pitch = np.degrees(np.arcsin(np.clip(fwd[2], -1, 1)))
    if abs(fwd[2]) > 0.999999:
        # Looking straight up or down: the heading is that of the image top.
        img_up = -r_wc[:, 1]
        h = img_up if fwd[2] < 0 else -img_up
        yaw = np.degrees(np.arctan2(h[0], h[1]))
        roll = 0.0
        r = rotation_world_from_camera(yaw, pitch, 0.0)
        roll = np.degrees(np.arctan2(np.dot(x, r[:, 1]), np.dot(x, r[:, 0])))
        return float(yaw), float(pitch), float(roll)
    yaw = np.degrees(np.arctan2(fwd[0], fwd[1]))
    r0 = rotation_world_from_camera(yaw, pitch, 0.0)
    roll = np.degrees(np.arctan2(np.dot(x, r0[:, 1]), np.dot(x, r0[:, 0])))
    return float(yaw), float(pitch), float(roll)


def quaternion_from_rotation(r: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) as (w, x, y, z) with w >= 0 from rotation matrices."""
    r = np.asarray(r, dtype=np.float64)
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    w = np.sqrt(np.maximum(0.0, 1 + m00 + m11 + m22)) / 2
    x = np.sqrt(np.maximum(0.0, 1 + m00 - m11 - m22)) / 2
    y = np.sqrt(np.maximum(0.0, 1 - m00 + m11 - m22)) / 2
    z = np.sqrt(np.maximum(0.0, 1 - m00 - m11 + m22)) / 2
    x = np.copysign(x, r[..., 2, 1] - r[..., 1, 2])
    y = np.copysign(y, r[..., 0, 2] - r[..., 2, 0])
    z = np.copysign(z, r[..., 1, 0] - r[..., 0, 1])
    q = np.stack([w, x, y, z], axis=-1)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def rotation_from_quaternion(q) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from quaternions (..., 4) given as (w, x, y, z)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def project_world(
    camera: CameraModel, position: np.ndarray, r_wc: np.ndarray, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Project world points (N, 3) seen from a camera at `position` with rotation
    `r_wc`: returns pixel coordinates (N, 2) and depths along the optical axis (N,)."""
    pc = (np.asarray(points, dtype=np.float64) - np.asarray(position)) @ np.asarray(r_wc)
    return camera.project_camera(pc), pc[:, 2]
