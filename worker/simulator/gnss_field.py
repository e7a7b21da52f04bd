"""A second, independently built GNSS error generator for photo sets: the "field" model.

Why a second one: the photo georeferencing (worker/pipeline/robust_fit.py) and its
constants were chosen on the "consumer" model of worker/simulator/gnss.py, so figures
on that model are figures on the data the fit was tuned on. This model is built from
other assumptions, with another structure (not a re-parameterisation of that one), and
nothing in the pipeline was tuned on it: it is held-out data for `slidewatch bench
photos` and `slidewatch simulate --gnss field`.

It sums six causes, each drawn from the flight's own random stream, on the receiver's
solution grid (`rate_hz`; the logs interpolate between solutions):

- satellite geometry: the receiver's bias starts at a few metres and STEPS when the
  set of satellites in use changes (a satellite sets or rises, the DOP changes) at
  Poisson times; the receiver's filter takes `geometry_settle_s` to follow each step
  (exponential). The consumer model instead lets a bias drift smoothly (Gauss-Markov).
- altitude: barometric, referenced at the start with an offset, then a random walk
  (pressure noise and wind gusts on the static port; its variance grows linearly with
  time, without the bound a Gauss-Markov drift has) plus a slow ramp of constant rate
  per flight (the sensor warming up in the sun).
- latency: the position written with a photo is that of a fixed `latency` earlier
  (receiver solution and camera trigger are not synchronised): an error along the
  track that changes sign with each flight line, which no similarity can absorb.
- multipath near reflectors: a few zones per flight (a cliff, a building) placed on
  the track; while the aircraft is inside one, each fix is off by that zone's offset
  (tens of metres, one direction per zone: the reflecting wall's), largest at the
  zone's centre and half of it at the edge, with fix-to-fix jitter. The outliers
  therefore cluster in space and come as runs of consecutive photos, on every line
  that crosses the zone, where the consumer model's outlier fixes are isolated events
  at uniform random times.
- time-tag slips: now and then, for a few seconds, the fix carries a time tag a whole
  second or two off (a missed PPS edge), so the position logged is that of another
  second of the flight: an along-track error of the speed times the slip.
- noise: Student-t (heavy tails: `noise_dof` degrees of freedom), not Gaussian.

The gross part (multipath and slips) is `outlier_enu`, what a georeferencing should
flag; the rest moves every photo and no fit without ground control can remove its mean.
`simulate_field_gnss` needs the true position as a function of time (multipath depends
on where the aircraft is, slips and latency on how it moves) and is deterministic given
the numpy Generator.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from worker.simulator.gnss import GnssErrorModel, GnssTrack, error_summary, simulate_gnss

PositionFn = Callable[[np.ndarray], np.ndarray]
"""True position (n, 3) east, north, up in metres at times (n,) in seconds."""


@dataclass(frozen=True)
class FieldGnssModel:
    """Parameters of the field model; lengths in metres, times in seconds."""

    mode: str = "field"
    rate_hz: float = 5.0
    # Satellite geometry: start bias sigma per axis, step events per second, step sigma
    # per axis, and the time constant of the receiver following a step.
    bias_start_m: tuple[float, float, float] = (1.8, 1.8, 4.0)
    geometry_change_rate_hz: float = 1.0 / 45.0
    geometry_step_m: tuple[float, float, float] = (1.2, 1.2, 2.5)
    geometry_settle_s: float = 3.0
    # Barometric altitude: random walk (m per sqrt(s)) and a per-flight ramp rate drawn
    # with this sigma (m/s); the start offset is in bias_start_m's vertical.
    altitude_walk_m_per_sqrt_s: float = 1.5
    altitude_ramp_sigma_m_per_s: float = 0.05
    # Latency of the logged fix behind the photo (uniform between the two values).
    latency_s: tuple[float, float] = (0.0, 0.2)
    # Multipath zones: how many per flight (uniform integer, both ends included), their
    # radius, the largest share of the flight's fixes one zone may hold (a zone never
    # swallows a small survey whole), the offset at the centre (horizontal uniform
    # between the two values, vertical sigma) and the fix-to-fix jitter per axis.
    multipath_zones: tuple[int, int] = (0, 2)
    multipath_radius_m: tuple[float, float] = (10.0, 30.0)
    multipath_max_share: float = 0.1
    multipath_h_m: tuple[float, float] = (15.0, 45.0)
    multipath_v_sigma_m: float = 8.0
    multipath_jitter_m: float = 2.0
    # Time-tag slips: events per second, the slip in whole seconds (either sign, up to
    # this many), how long each lasts (uniform between the two values).
    slip_rate_hz: float = 1.0 / 60.0
    slip_max_s: int = 2
    slip_hold_s: tuple[float, float] = (1.0, 3.0)
    # Student-t noise: degrees of freedom and scale per axis.
    noise_dof: float = 3.0
    noise_scale_m: tuple[float, float, float] = (0.35, 0.35, 0.8)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["note"] = (
            "held-out model (worker/simulator/gnss_field.py): stepped geometry bias, "
            "barometric random walk + ramp, latency, spatially clustered multipath, "
            "time-tag slips, Student-t noise; nothing in the pipeline was tuned on it"
        )
        return d


@dataclass
class FieldGnssTrack:
    """One flight's realisation on the receiver's grid; the same reading interface as
    `GnssTrack` (error_at, outlier_at, summary, bias_enu), plus each cause's part."""

    t: np.ndarray
    error_enu: np.ndarray
    bias_enu: np.ndarray  # the geometry bias at the start
    model: FieldGnssModel
    outlier_enu: np.ndarray  # multipath + slips: the gross part of error_enu
    parts: dict[str, np.ndarray]  # (n, 3) per cause; they sum to error_enu
    zones: list[dict]  # multipath zones: centre (e, n), radius, offset at the centre
    slips: list[dict]  # start, end (s) and the slip (whole seconds)
    latency_s: float

    def _at(self, values: np.ndarray, times: np.ndarray) -> np.ndarray:
        times = np.asarray(times, dtype=np.float64)
        return np.stack([np.interp(times, self.t, values[:, k]) for k in range(3)], -1)

    def error_at(self, times: np.ndarray) -> np.ndarray:
        return self._at(self.error_enu, times)

    def outlier_at(self, times: np.ndarray) -> np.ndarray:
        return self._at(self.outlier_enu, times)

    def summary(self) -> dict:
        return {
            **error_summary(self.model.mode, self.bias_enu, self.error_enu),
            "latency_s": round(self.latency_s, 4),
            "multipath_zones": self.zones,
            "time_tag_slips": self.slips,
        }


def _geometry(model: FieldGnssModel, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Piecewise-constant bias that steps at Poisson times, followed by the receiver's
    filter (first order, `geometry_settle_s`)."""
    span = t[-1] - t[0]
    start = rng.normal(0.0, 1.0, 3) * np.asarray(model.bias_start_m)
    count = rng.poisson(model.geometry_change_rate_hz * span)
    when = np.sort(rng.uniform(t[0], t[-1], count))
    steps = rng.normal(0.0, 1.0, (count, 3)) * np.asarray(model.geometry_step_m)
    out = np.tile(start, (t.size, 1))
    for at, step in zip(when, steps, strict=True):
        after = t >= at
        settle = 1.0 - np.exp(-(t[after] - at) / max(model.geometry_settle_s, 1e-9))
        out[after] += settle[:, None] * step
    return out


def _altitude(model: FieldGnssModel, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(n,) barometric random walk from zero at the start, plus the flight's ramp."""
    dt = np.diff(t, prepend=t[0])
    walk = np.cumsum(rng.normal(0.0, 1.0, t.size) * np.sqrt(dt)) * model.altitude_walk_m_per_sqrt_s
    ramp = rng.normal(0.0, model.altitude_ramp_sigma_m_per_s) * (t - t[0])
    return walk + ramp


def _multipath(
    model: FieldGnssModel, t: np.ndarray, pos: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, list[dict]]:
    """Offsets of the fixes inside reflector zones placed on the track."""
    out = np.zeros((t.size, 3))
    zones = []
    lo, hi = model.multipath_zones
    for _ in range(int(rng.integers(lo, hi + 1))):
        centre = pos[int(rng.integers(0, t.size)), :2]
        dist = np.hypot(*(pos[:, :2] - centre).T)
        radius = float(rng.uniform(*model.multipath_radius_m))
        # A zone holds at most `multipath_max_share` of the fixes: on a small survey a
        # 30 m zone would otherwise be most of the flight, not a reflector beside it.
        cap = float(np.quantile(dist, model.multipath_max_share))
        radius = min(radius, cap) if cap > 0 else radius
        h = rng.uniform(*model.multipath_h_m)
        az = rng.uniform(0.0, 2.0 * np.pi)
        offset = np.array(
            [h * np.sin(az), h * np.cos(az), rng.normal(0, model.multipath_v_sigma_m)]
        )
        jitter = rng.normal(0.0, model.multipath_jitter_m, (t.size, 3))
        inside = dist <= radius
        # Full offset at the centre, half of it at the edge.
        taper = 1.0 - 0.5 * (dist[inside] / max(radius, 1e-9)) ** 2
        out[inside] += taper[:, None] * offset + jitter[inside]
        zones.append(
            {
                "centre_en_m": [round(float(v), 3) for v in centre],
                "radius_m": round(radius, 3),
                "offset_enu_m": [round(float(v), 3) for v in offset],
                "fixes": int(inside.sum()),
            }
        )
    return out, zones


def _slips(
    model: FieldGnssModel,
    t: np.ndarray,
    pos: np.ndarray,
    position_at: PositionFn,
    rng: np.random.Generator,
) -> tuple[np.ndarray, list[dict]]:
    """During a slip the fix is the position of `slip` whole seconds earlier or later."""
    out = np.zeros((t.size, 3))
    events = []
    count = rng.poisson(model.slip_rate_hz * (t[-1] - t[0]))
    for start in np.sort(rng.uniform(t[0], t[-1], count)):
        slip = int(rng.integers(1, model.slip_max_s + 1)) * int(rng.choice([-1, 1]))
        end = start + float(rng.uniform(*model.slip_hold_s))
        sel = (t >= start) & (t < end)
        out[sel] = position_at(t[sel] + slip) - pos[sel]
        events.append(
            {"start_s": round(float(start), 3), "end_s": round(float(end), 3), "slip_s": slip}
        )
    return out, events


def simulate_field_gnss(
    model: FieldGnssModel,
    t_start: float,
    t_end: float,
    position_at: PositionFn,
    rng: np.random.Generator,
) -> FieldGnssTrack:
    """Draw one flight's GNSS error from `t_start` to `t_end` (s) along the true
    positions `position_at`; see the module doc for the causes."""
    dt = 1.0 / model.rate_hz
    t = np.arange(t_start, t_end + dt, dt)
    pos = np.asarray(position_at(t), dtype=np.float64)
    geometry = _geometry(model, t, rng)
    altitude = np.zeros((t.size, 3))
    altitude[:, 2] = _altitude(model, t, rng)
    latency = float(rng.uniform(*model.latency_s))
    lag = np.asarray(position_at(t - latency), dtype=np.float64) - pos
    multipath, zones = _multipath(model, t, pos, rng)
    slip, slips = _slips(model, t, pos, position_at, rng)
    noise = rng.standard_t(model.noise_dof, (t.size, 3)) * np.asarray(model.noise_scale_m)
    parts = {
        "geometry": geometry,
        "altitude": altitude,
        "latency": lag,
        "multipath": multipath,
        "slip": slip,
        "noise": noise,
    }
    return FieldGnssTrack(
        t=t,
        error_enu=sum(parts.values()),
        bias_enu=geometry[0].copy(),
        model=model,
        outlier_enu=multipath + slip,
        parts=parts,
        zones=zones,
        slips=slips,
        latency_s=latency,
    )


GNSS_MODES = ("standalone", "consumer", "field", "rtk", "none")


def named_gnss_model(mode: str) -> GnssErrorModel | FieldGnssModel:
    """The error model of a `--gnss` name: "field" is this module's, the others
    worker/simulator/gnss.py's."""
    return FieldGnssModel() if mode == "field" else GnssErrorModel.named(mode)


def simulate_flight_gnss(
    model: GnssErrorModel | FieldGnssModel,
    t_start: float,
    t_end: float,
    position_at: PositionFn,
    rng: np.random.Generator,
) -> GnssTrack | FieldGnssTrack:
    """One flight's GNSS error under either generator (the first ignores the track)."""
    if isinstance(model, FieldGnssModel):
        return simulate_field_gnss(model, t_start, t_end, position_at, rng)
    return simulate_gnss(model, t_start, t_end, rng)
