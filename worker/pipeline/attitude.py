"""Camera attitude conventions shared by georeferencing and reconstruction.

- World frames are east-north-up (x east, y north, z up), e.g. UTM easting, northing,
  altitude.
- Camera frames are OpenCV's: x right, y down, z forward along the optical axis.
- DJI angles in degrees: yaw is the heading of the optical axis (of the image top when
  looking straight down), clockwise from north; pitch 0 at the horizon, -90 straight
  down; roll positive when the right side of the image tilts down.

`rotation_world_from_camera` returns matrices whose columns are the camera axes in the
world frame (R_wc: x_world = R_wc @ x_cam + C).
"""

from __future__ import annotations

from enum import StrEnum

import numpy as np

from worker.pipeline.ingest.flight_log import FlightLog


class AttitudeSource(StrEnum):
    """Which logged angles gave the cameras' attitude (kept in georeference.json)."""

    gimbal = "gimbal"
    aircraft_yaw_nadir = "aircraft_yaw_nadir"  # aircraft heading, camera assumed nadir
    none = "none"


def rotation_world_from_camera(yaw_deg, pitch_deg, roll_deg) -> np.ndarray:
    """(..., 3, 3) camera-to-world rotations for DJI yaw/pitch/roll in degrees."""
    psi = np.radians(np.asarray(yaw_deg, dtype=np.float64))
    th = np.radians(np.asarray(pitch_deg, dtype=np.float64))
    ph = np.radians(np.asarray(roll_deg, dtype=np.float64))
    psi, th, ph = np.broadcast_arrays(psi, th, ph)
    zero, one = np.zeros_like(psi), np.ones_like(psi)
    heading = np.stack([np.sin(psi), np.cos(psi), zero], axis=-1)
    right = np.stack([np.cos(psi), -np.sin(psi), zero], axis=-1)
    up = np.stack([zero, zero, one], axis=-1)
    forward = np.cos(th)[..., None] * heading + np.sin(th)[..., None] * up
    down_in_image = np.sin(th)[..., None] * heading - np.cos(th)[..., None] * up
    x = np.cos(ph)[..., None] * right + np.sin(ph)[..., None] * down_in_image
    y = -np.sin(ph)[..., None] * right + np.cos(ph)[..., None] * down_in_image
    return np.stack([x, y, forward], axis=-1)


def camera_attitude_at(
    log: FlightLog, log_times: np.ndarray, assume_nadir: bool = True
) -> tuple[np.ndarray | None, AttitudeSource]:
    """Camera rotations (world ENU from camera) at log times, from the logged angles.

    Gimbal angles are used when the log has them (DJI gimbal yaw is absolute); else the
    aircraft yaw with a camera looking straight down (`assume_nadir`). Returns
    (rotations or None, the source used).
    """
    values = log.interpolate(log_times)
    if log.has_attitude("gimbal_pitch", "gimbal_yaw"):
        roll = values.get("gimbal_roll")
        if roll is None or not np.isfinite(roll).any():
            roll = np.zeros_like(values["gimbal_yaw"])
        rot = rotation_world_from_camera(
            values["gimbal_yaw"], values["gimbal_pitch"], np.nan_to_num(roll)
        )
        return rot, AttitudeSource.gimbal
    if assume_nadir and log.has_attitude("yaw"):
        yaw = values["yaw"]
        rot = rotation_world_from_camera(yaw, np.full_like(yaw, -90.0), 0.0 * yaw)
        return rot, AttitudeSource.aircraft_yaw_nadir
    return None, AttitudeSource.none


def rotation_angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (degrees) of the rotation between matrices a and b (..., 3, 3)."""
    rel = np.einsum("...ji,...jk->...ik", a, b)
    cos = (np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def project_to_rotation(m: np.ndarray) -> np.ndarray:
    """The rotation matrix nearest to m (SVD)."""
    u, _, vt = np.linalg.svd(m)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt
