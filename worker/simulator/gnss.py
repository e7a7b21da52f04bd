"""Error models of what the aircraft logs: GNSS position and IMU/compass/gimbal attitude.

- Stand-alone GPS (consumer drones, the paper's Phantom 4 Pro): a bias of a few
  metres, fresh for every flight, that drifts slowly during the flight (first-order
  Gauss-Markov), plus white noise; vertical errors about 2.5 times the horizontal.
- RTK (fixed): centimetre bias and noise.
- none: the log carries the true position (for tests).

The receiver delivers solutions at `rate_hz`; between them logs interpolate linearly,
so the SRT (per video frame) and the CSV (10 Hz) of one flight see the same error.
Attitude: compass yaw with a per-flight bias and noise, pitch/roll with IMU-level
noise, gimbal angles with encoder-level noise.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class GnssErrorModel:
    """Standard deviations in metres, per axis (east, north, up)."""

    mode: str = "standalone"
    bias_sigma_m: tuple[float, float, float] = (1.5, 1.5, 3.5)
    drift_sigma_m: tuple[float, float, float] = (0.5, 0.5, 1.2)
    drift_tau_s: float = 240.0
    noise_sigma_m: tuple[float, float, float] = (0.12, 0.12, 0.3)
    rate_hz: float = 10.0

    @classmethod
    def named(cls, mode: str) -> GnssErrorModel:
        if mode == "standalone":
            return cls()
        if mode == "rtk":
            return cls(
                mode="rtk",
                bias_sigma_m=(0.01, 0.01, 0.02),
                drift_sigma_m=(0.005, 0.005, 0.01),
                drift_tau_s=60.0,
                noise_sigma_m=(0.008, 0.008, 0.015),
            )
        if mode == "none":
            return cls(
                mode="none",
                bias_sigma_m=(0.0, 0.0, 0.0),
                drift_sigma_m=(0.0, 0.0, 0.0),
                noise_sigma_m=(0.0, 0.0, 0.0),
            )
        raise ValueError(f"unknown GNSS mode {mode!r}: use standalone, rtk or none")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["note"] = "sigmas per axis east, north, up (m); drift is first-order Gauss-Markov"
        return d


@dataclass(frozen=True)
class ImuErrorModel:
    """Attitude errors of the logged angles (degrees)."""

    yaw_bias_sigma: float = 1.5
    yaw_noise: float = 0.3
    tilt_noise: float = 0.1
    gimbal_noise: float = 0.05

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class GnssTrack:
    """One flight's realisation of the position error, on the receiver's time grid."""

    t: np.ndarray
    error_enu: np.ndarray
    bias_enu: np.ndarray
    model: GnssErrorModel

    def error_at(self, times: np.ndarray) -> np.ndarray:
        times = np.asarray(times, dtype=np.float64)
        return np.stack([np.interp(times, self.t, self.error_enu[:, k]) for k in range(3)], -1)

    def summary(self) -> dict:
        e = self.error_enu
        return {
            "mode": self.model.mode,
            "bias_enu_m": [round(float(v), 4) for v in self.bias_enu],
            "mean_error_enu_m": [round(float(v), 4) for v in e.mean(axis=0)],
            "rms_error_enu_m": [round(float(v), 4) for v in np.sqrt((e * e).mean(axis=0))],
        }


def simulate_gnss(
    model: GnssErrorModel, t_start: float, t_end: float, rng: np.random.Generator
) -> GnssTrack:
    """Draw one flight's GNSS error from `t_start` to `t_end` (s)."""
    dt = 1.0 / model.rate_hz
    t = np.arange(t_start, t_end + dt, dt)
    bias = rng.normal(0.0, 1.0, 3) * np.asarray(model.bias_sigma_m)
    drift = np.zeros((t.size, 3))
    sig = np.asarray(model.drift_sigma_m)
    phi = np.exp(-dt / model.drift_tau_s)
    q = sig * np.sqrt(1 - phi * phi)
    x = rng.normal(0.0, 1.0, 3) * sig
    steps = rng.normal(0.0, 1.0, (t.size, 3)) * q
    for i in range(t.size):
        x = phi * x + steps[i]
        drift[i] = x
    noise = rng.normal(0.0, 1.0, (t.size, 3)) * np.asarray(model.noise_sigma_m)
    return GnssTrack(t=t, error_enu=bias + drift + noise, bias_enu=bias, model=model)


@dataclass
class AttitudeErrors:
    """One flight's attitude error realisation (deg), functions of time."""

    yaw_bias: float
    t: np.ndarray
    aircraft: np.ndarray  # (n, 3) yaw, pitch, roll
    gimbal: np.ndarray  # (n, 3)

    def at(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        times = np.asarray(times, dtype=np.float64)
        a = np.stack([np.interp(times, self.t, self.aircraft[:, k]) for k in range(3)], -1)
        g = np.stack([np.interp(times, self.t, self.gimbal[:, k]) for k in range(3)], -1)
        return a, g


def simulate_attitude_errors(
    model: ImuErrorModel,
    t_start: float,
    t_end: float,
    rng: np.random.Generator,
    rate_hz: float = 10.0,
) -> AttitudeErrors:
    dt = 1.0 / rate_hz
    t = np.arange(t_start, t_end + dt, dt)
    yaw_bias = float(rng.normal(0.0, model.yaw_bias_sigma))
    air = rng.normal(0.0, 1.0, (t.size, 3)) * np.array(
        [model.yaw_noise, model.tilt_noise, model.tilt_noise]
    )
    air[:, 0] += yaw_bias
    gim = rng.normal(0.0, model.gimbal_noise, (t.size, 3))
    # The gimbal heading comes from the same compass.
    gim[:, 0] += yaw_bias
    return AttitudeErrors(yaw_bias=yaw_bias, t=t, aircraft=air, gimbal=gim)
