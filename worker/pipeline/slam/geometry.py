"""Pose and point geometry: world-to-camera poses (R_cw, t_cw), OpenCV camera axes."""

from __future__ import annotations

import numpy as np


def camera_center(r_cw: np.ndarray, t_cw: np.ndarray) -> np.ndarray:
    return -r_cw.T @ t_cw


def project(r_cw: np.ndarray, t_cw: np.ndarray, k: np.ndarray, xyz: np.ndarray):
    """Pixel coordinates (N, 2) and depths (N,) of world points."""
    pc = xyz @ r_cw.T + t_cw
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.column_stack([k[0, 0] * pc[:, 0] / z + k[0, 2], k[1, 1] * pc[:, 1] / z + k[1, 2]])
    return uv, z


def rays_world(r_cw: np.ndarray, k_inv: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Unit world directions of the rays through pixels uv (N, 2)."""
    h = np.column_stack([uv, np.ones(len(uv))]) @ k_inv.T
    d = h @ r_cw  # R_wc @ h  (R_wc = R_cw^T)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def triangulate_midpoint(c1, d1, c2, d2):
    """Midpoints of the closest approach of rays c1 + a d1 and c2 + b d2 (vectorised).

    Returns (points (N, 3), a, b, angle in degrees between the rays)."""
    w = c1 - c2
    a_ = np.einsum("ij,ij->i", d1, d1)
    b_ = np.einsum("ij,ij->i", d1, d2)
    c_ = np.einsum("ij,ij->i", d2, d2)
    d_ = np.einsum("ij,ij->i", d1, w)
    e_ = np.einsum("ij,ij->i", d2, w)
    den = a_ * c_ - b_ * b_
    den = np.where(np.abs(den) < 1e-12, np.nan, den)
    s = (b_ * e_ - c_ * d_) / den
    u = (a_ * e_ - b_ * d_) / den
    p = 0.5 * ((c1 + s[:, None] * d1) + (c2 + u[:, None] * d2))
    angle = np.degrees(np.arccos(np.clip(b_ / np.sqrt(a_ * c_), -1.0, 1.0)))
    return p, s, u, angle


def rotation_z90(k: int) -> np.ndarray:
    """Rotation of the camera frame that matches np.rot90-style image turns by k*90 deg
    clockwise: pixel (u, v) -> (h-1-v, u) for k = 1."""
    c = [(1, 0), (0, 1), (-1, 0), (0, -1)][k % 4]
    return np.array([[c[0], -c[1], 0.0], [c[1], c[0], 0.0], [0.0, 0.0, 1.0]])
