"""Error models of what the aircraft logs: GNSS position and IMU/compass/gimbal attitude.

- Stand-alone GPS (consumer drones, the paper's Phantom 4 Pro): a bias of a few
  metres, fresh for every flight, that drifts slowly during the flight (first-order
  Gauss-Markov), plus white noise; vertical errors about 2.5 times the horizontal.
- consumer (phones, cameras, small drones writing GPS into each photo): a bias of a
  few metres, an altitude that wanders by tens of metres within a minute (vertical
  Gauss-Markov drift, sigma 15 m, tau 60 s) and now and then a fix tens of metres off
  (multipath, re-acquisition: `outlier_rate_hz` events, each held `outlier_hold_s`).
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
    # Outlier fixes (consumer): events per second, horizontal offset (uniform between the
    # two values, any direction), vertical offset sigma, how long each lasts.
    outlier_rate_hz: float = 0.0
    outlier_h_m: tuple[float, float] = (20.0, 50.0)
    outlier_v_sigma_m: float = 10.0
    outlier_hold_s: float = 1.0

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
        if mode == "consumer":
            return cls(
                mode="consumer",
                bias_sigma_m=(1.5, 1.5, 3.0),
                drift_sigma_m=(0.6, 0.6, 15.0),
                drift_tau_s=60.0,
                noise_sigma_m=(0.3, 0.3, 1.0),
                outlier_rate_hz=0.04,
            )
        if mode == "none":
            return cls(
                mode="none",
                bias_sigma_m=(0.0, 0.0, 0.0),
                drift_sigma_m=(0.0, 0.0, 0.0),
                noise_sigma_m=(0.0, 0.0, 0.0),
            )
        raise ValueError(f"unknown GNSS mode {mode!r}: use standalone, consumer, rtk or none")

    def to_dict(self) -> dict:
        d = asdict(self)
        if not self.outlier_rate_hz:
            # Models without outliers keep the manifests they always wrote.
            for key in ("outlier_rate_hz", "outlier_h_m", "outlier_v_sigma_m", "outlier_hold_s"):
                d.pop(key)
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
    outlier_enu: np.ndarray | None = None  # the outlier fixes' part of error_enu

    def error_at(self, times: np.ndarray) -> np.ndarray:
        times = np.asarray(times, dtype=np.float64)
        return np.stack([np.interp(times, self.t, self.error_enu[:, k]) for k in range(3)], -1)

    def outlier_at(self, times: np.ndarray) -> np.ndarray:
        """(n, 3) the outlier part of the error at `times` (zeros without outliers)."""
        times = np.asarray(times, dtype=np.float64)
        if self.outlier_enu is None:
            return np.zeros((times.size, 3))
        return np.stack([np.interp(times, self.t, self.outlier_enu[:, k]) for k in range(3)], -1)

    def summary(self) -> dict:
        return error_summary(self.model.mode, self.bias_enu, self.error_enu)


def error_summary(mode: str, bias_enu: np.ndarray, error_enu: np.ndarray) -> dict:
    """A drawn GNSS error's figures for the manifest: its bias, mean and RMS (ENU, m)."""
    e = error_enu
    return {
        "mode": mode,
        "bias_enu_m": [round(float(v), 4) for v in bias_enu],
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
    error = bias + drift + noise
    outliers = None
    if model.outlier_rate_hz > 0:
        # Drawn after everything else: the other modes' random streams stay as they were.
        outliers = np.zeros((t.size, 3))
        count = rng.poisson(model.outlier_rate_hz * (t[-1] - t[0]))
        for start in rng.uniform(t[0], t[-1], count):
            h = rng.uniform(*model.outlier_h_m)
            az = rng.uniform(0.0, 2.0 * np.pi)
            offset = [h * np.sin(az), h * np.cos(az), rng.normal(0.0, model.outlier_v_sigma_m)]
            outliers[(t >= start) & (t < start + model.outlier_hold_s)] = offset
        error = error + outliers
    return GnssTrack(t=t, error_enu=error, bias_enu=bias, model=model, outlier_enu=outliers)


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
