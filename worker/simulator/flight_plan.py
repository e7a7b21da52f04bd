"""Flight plans and the true trajectory of the aircraft and its camera.

Two plans, as in the paper:

- `lawnmower`: parallel lines at a given height above the take-off point (or following
  the terrain), spaced for a given side overlap of the camera footprint, joined by
  half-circle turns; the gimbal looks straight down and the image top points along
  the flight direction, so the image width spans the line spacing.
- `paper-3d`: the paper's registration flight: the same pattern with the height
  varying smoothly between 7 and 20 m (one-tenth scale).

Either may be flown as a cross pattern (`cross`): after the last line, the aircraft
flies straight to the start of a second lawnmower over the same rectangle with its lines
perpendicular to the first, as surveyors fly for stronger geometry (two viewing
directions on every point). The video length then covers both grids.

`build_flight` turns a plan into a `Flight`: the aircraft takes off at the home
point, climbs, flies to the start of the plan, turns to face its first line, flies
the plan (the video records exactly that part, t = 0 .. duration: starting from rest,
at cruise speed on the lines, slower in the turns so that the lateral acceleration
stays under 4 m/s^2, stopping at the end), hovers and lands in place. With a video
length instead of a speed, the cruise speed is solved for; if even 20 m/s is too slow,
the video ends before the plan does (`truncated_by_max_speed`). The state is sampled
at 100 Hz and smoothed, so velocity and attitude are continuous: the aircraft pitches
forward with speed and acceleration and banks in turns; the gimbal holds the camera
attitude with small vibrations.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace

import numpy as np
from scipy.ndimage import gaussian_filter1d

from worker.simulator.camera import CameraModel, rotation_world_from_camera

RATE_HZ = 100.0


@dataclass(frozen=True)
class FlightPlan:
    """A survey pattern over a rectangle (local metres).

    The lines run along `line_azimuth_deg` (clockwise from north) over `length_m`,
    stacked across over `width_m`, centred on `center_xy`."""

    kind: str = "lawnmower"
    center_xy: tuple[float, float] = (0.0, 0.0)
    length_m: float = 22.0
    width_m: float = 22.0
    line_azimuth_deg: float = 0.0
    altitude_m: float = 7.0
    """Height above the take-off point, or above the terrain if `terrain_following`."""
    altitude_max_m: float | None = None
    """paper-3d: the height varies between `altitude_m` and this."""
    side_overlap: float = 0.6
    speed_m_s: float | None = 4.0
    duration_s: float | None = None
    """If set, the speed is chosen so that the plan takes this long."""
    gimbal_pitch_deg: float = -90.0
    accel_m_s2: float = 3.0
    lateral_accel_m_s2: float = 4.0
    terrain_following: bool = False
    max_speed_m_s: float = 20.0
    cross: bool = False
    """Fly a second lawnmower perpendicular to the first after it (see the module doc)."""

    def to_dict(self) -> dict:
        d = asdict(self)
        d["center_xy"] = list(self.center_xy)
        return d


@dataclass
class Flight:
    """True state of one flight, sampled at 100 Hz on the video clock (t = 0 is the first
    video frame; negative times are before recording started)."""

    t: np.ndarray
    position: np.ndarray  # (n, 3) local x, y, z
    velocity: np.ndarray  # (n, 3)
    aircraft_ypr: np.ndarray  # (n, 3) yaw, pitch, roll (deg)
    gimbal_ypr: np.ndarray  # (n, 3) camera yaw, pitch, roll (deg), absolute
    home: np.ndarray  # (3,) take-off point
    video_start: float
    video_end: float
    plan: FlightPlan
    speed_m_s: float
    path_length_m: float
    line_spacing_m: float
    n_lines: int
    info: dict = field(default_factory=dict)

    @property
    def duration(self) -> float:
        return self.video_end - self.video_start

    def sample(self, times: np.ndarray) -> dict[str, np.ndarray]:
        """Interpolated true state at `times` (s, video clock)."""
        times = np.asarray(times, dtype=np.float64)
        out = {}
        for name in ("position", "velocity"):
            arr = getattr(self, name)
            out[name] = np.stack([np.interp(times, self.t, arr[:, k]) for k in range(3)], -1)
        for name in ("aircraft_ypr", "gimbal_ypr"):
            arr = getattr(self, name)
            cols = []
            for k in range(3):
                # Angles are stored unwrapped; wrap yaw to (-180, 180] on output.
                cols.append(np.interp(times, self.t, arr[:, k]))
            a = np.stack(cols, -1)
            a[..., 0] = (a[..., 0] + 180.0) % 360.0 - 180.0
            out[name] = a
        return out

    def camera_pose(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Camera centres (n, 3) and world-from-camera rotations (n, 3, 3)."""
        s = self.sample(times)
        ypr = s["gimbal_ypr"]
        return s["position"], rotation_world_from_camera(ypr[:, 0], ypr[:, 1], ypr[:, 2])


def _densify(points: np.ndarray, step: float) -> np.ndarray:
    out = [points[:1]]
    for p0, p1 in itertools.pairwise(points):
        d = np.linalg.norm(p1 - p0)
        n = max(1, int(np.ceil(d / step)))
        f = (np.arange(1, n + 1) / n)[:, None]
        out.append(p0[None, :] + f * (p1 - p0)[None, :])
    return np.concatenate(out)


def _lawnmower_xy(plan: FlightPlan, spacing: float, n_lines: int, step: float) -> np.ndarray:
    """Horizontal path (m, 2) of the pattern with half-circle turns."""
    az = np.radians(plan.line_azimuth_deg)
    along = np.array([np.sin(az), np.cos(az)])
    across = np.array([np.cos(az), -np.sin(az)])  # to the right of the line direction
    c = np.asarray(plan.center_xy, float)
    half = plan.length_m / 2.0
    offsets = (np.arange(n_lines) - (n_lines - 1) / 2.0) * spacing
    pts = []
    for i, off in enumerate(offsets):
        sgn = 1.0 if i % 2 == 0 else -1.0
        a = c + off * across - sgn * half * along
        b = c + off * across + sgn * half * along
        seg = _densify(np.array([a, b]), step)
        pts.append(seg if not pts else seg[1:])
        if i < n_lines - 1:
            # Half circle to the next line, bulging beyond the end of this one.
            r = spacing / 2.0
            centre = b + r * across
            n = max(8, int(np.ceil(np.pi * r / step)))
            th = np.linspace(0, np.pi, n + 1)[1:]
            start = -across
            turn = centre[None, :] + r * (
                np.cos(th)[:, None] * start[None, :] + np.sin(th)[:, None] * sgn * along[None, :]
            )
            pts.append(turn[:-1])
    return np.concatenate(pts)


def _with_cross_grid(
    xy: np.ndarray, plan: FlightPlan, footprint_across: float, spacing: float, step: float
) -> tuple[np.ndarray, int]:
    """`xy` followed by a straight leg to a second lawnmower over the same rectangle
    with lines turned by 90 degrees (its lines span `width_m`, stacked over `length_m`),
    and the index in it where the second lawnmower starts."""
    turned = replace(
        plan,
        line_azimuth_deg=plan.line_azimuth_deg + 90.0,
        length_m=plan.width_m,
        width_m=plan.length_m,
    )
    n_lines = max(1, int(np.ceil(max(turned.width_m - footprint_across, 0.0) / spacing)) + 1)
    second = _lawnmower_xy(turned, spacing, n_lines, step)
    leg = _densify(np.array([xy[-1], second[0]]), step)[1:-1]
    return np.concatenate([xy, leg, second]), len(xy) + len(leg)


def build_flight(
    plan: FlightPlan,
    camera: CameraModel,
    ground_height: Callable[[np.ndarray, np.ndarray], np.ndarray],
    home_xy: tuple[float, float],
    rng: np.random.Generator,
) -> Flight:
    """Fly `plan` with `camera` over terrain `ground_height(x, y)`, taking off at home."""
    home_z = float(ground_height(np.array([home_xy[0]]), np.array([home_xy[1]]))[0])
    lo_alt = plan.altitude_m
    hi_alt = plan.altitude_max_m if plan.kind == "paper-3d" and plan.altitude_max_m else lo_alt
    # Line spacing from the footprint across the lines at the lowest height.
    footprint_across, footprint_along = camera.ground_footprint(lo_alt)
    spacing = (1.0 - plan.side_overlap) * footprint_across
    n_lines = max(1, int(np.ceil(max(plan.width_m - footprint_across, 0.0) / spacing)) + 1)
    step = max(0.02, min(0.5, spacing / 40.0))
    xy = _lawnmower_xy(plan, spacing, n_lines, step)
    if plan.cross:
        xy, second_start = _with_cross_grid(xy, plan, footprint_across, spacing, step)
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    length = float(s[-1])
    if plan.kind == "paper-3d":
        period = plan.length_m * 1.3
        z_rel = lo_alt + (hi_alt - lo_alt) * 0.5 * (1 - np.cos(2 * np.pi * s / period))
    else:
        z_rel = np.full(s.size, lo_alt)
    if plan.terrain_following:
        g = ground_height(xy[:, 0], xy[:, 1])
        sigma = max(1.0, 15.0 / step)  # smooth the terrain over ~15 m of track
        g = gaussian_filter1d(g, sigma, mode="nearest")
        z = g + z_rel
    else:
        z = home_z + z_rel
    path = np.column_stack([xy, z])

    # Speed profile: cruise speed, slower in turns (lateral acceleration at most
    # `lateral_accel_m_s2`), accelerating from rest at the first point of the plan
    # and braking to rest at the last at `accel_m_s2`.
    heading = np.unwrap(np.arctan2(np.diff(xy[:, 0]), np.diff(xy[:, 1])))
    heading = np.concatenate([heading[:1], heading])
    k = max(1, round(0.5 / step))  # curvature over ~1 m of path
    kappa = np.zeros(s.size)
    kappa[k:-k] = np.abs(heading[2 * k :] - heading[: -2 * k]) / np.maximum(
        s[2 * k :] - s[: -2 * k], 1e-9
    )
    truncated = False
    if plan.duration_s:
        target = float(plan.duration_s)
        lo_v, hi_v = 0.05, plan.max_speed_m_s
        if _profile(s, kappa, hi_v, plan)[0][-1] > target:
            speed = hi_v
            truncated = True
        else:
            for _ in range(60):
                mid = 0.5 * (lo_v + hi_v)
                if _profile(s, kappa, mid, plan)[0][-1] > target:
                    lo_v = mid
                else:
                    hi_v = mid
            speed = hi_v
        duration = target
    else:
        speed = min(float(plan.speed_m_s or 4.0), plan.max_speed_m_s)
        duration = None
    t_of_s, v_of_s = _profile(s, kappa, speed, plan)
    if duration is None:
        duration = float(t_of_s[-1])

    def s_of_t(tt: np.ndarray) -> np.ndarray:
        return np.interp(tt, t_of_s, s)

    # Pre-roll: take off, climb, fly to the start. Post-roll: hover 2 s, land.
    climb_rate, transit = 3.0, min(max(speed, 3.0), 8.0)
    start = path[0]
    home = np.array([home_xy[0], home_xy[1], home_z])
    top = np.array([home_xy[0], home_xy[1], start[2]])
    t_climb = (start[2] - home_z) / climb_rate
    t_transit = np.linalg.norm(start[:2] - top[:2]) / transit
    t_pre = 3.0 + t_climb + t_transit + 2.0
    dt = 1.0 / RATE_HZ
    t = np.arange(-t_pre, duration + 2.0 + 6.0, dt)
    pos = np.empty((t.size, 3))
    # Before recording.
    t0 = -t_pre
    on_ground = t < t0 + 3.0
    climbing = (t >= t0 + 3.0) & (t < t0 + 3.0 + t_climb)
    moving = (t >= t0 + 3.0 + t_climb) & (t < t0 + 3.0 + t_climb + t_transit)
    waiting = (t >= t0 + 3.0 + t_climb + t_transit) & (t < 0)
    pos[on_ground] = home
    f = (t[climbing] - (t0 + 3.0)) / max(t_climb, 1e-9)
    pos[climbing] = home[None, :] + f[:, None] * (top - home)[None, :]
    f = (t[moving] - (t0 + 3.0 + t_climb)) / max(t_transit, 1e-9)
    pos[moving] = top[None, :] + f[:, None] * (start - top)[None, :]
    pos[waiting] = start
    # The plan.
    rec = (t >= 0) & (t <= duration)
    s_t = s_of_t(t[rec])
    for k in range(3):
        pos[rec, k] = np.interp(s_t, s, path[:, k])
    s_end = float(s_of_t(np.array([duration]))[0])
    if plan.cross:
        s_second = float(s[second_start])
        cross_flown = (s_end - s_second) / max(length - s_second, 1e-9)
    end = np.array([np.interp(s_end, s, path[:, k]) for k in range(3)])
    after = t > duration
    t_land = t[after] - duration
    land_z = float(ground_height(np.array([end[0]]), np.array([end[1]]))[0])
    z_after = np.where(t_land < 2.0, end[2], np.maximum(land_z, end[2] - 3.0 * (t_land - 2.0)))
    pos[after] = end
    pos[after, 2] = z_after
    # Smooth so that velocity is continuous (straight lines are unchanged).
    smooth = np.stack(
        [gaussian_filter1d(pos[:, k], 0.25 * RATE_HZ, mode="nearest") for k in range(3)], -1
    )
    pos = smooth
    vel = np.gradient(pos, dt, axis=0)
    acc = np.gradient(vel, dt, axis=0)

    # Heading follows the horizontal velocity, held when hovering; smoothed.
    hs = np.hypot(vel[:, 0], vel[:, 1])
    yaw = np.degrees(np.arctan2(vel[:, 0], vel[:, 1]))
    first_dir = start[:2] - home[:2]
    first_yaw = (
        float(np.degrees(np.arctan2(first_dir[0], first_dir[1])))
        if np.linalg.norm(first_dir) > 0.5
        else plan.line_azimuth_deg
    )
    valid = hs > 0.3
    d0 = path[min(5, len(path) - 1), :2] - path[0, :2]
    plan_yaw = float(np.degrees(np.arctan2(d0[0], d0[1])))
    yaw = np.where(valid, yaw, np.nan)
    # Hovering at the start of the plan, the aircraft turns to face its first line.
    yaw[waiting | (rec & ~valid)] = plan_yaw
    idx = np.where(valid, np.arange(t.size), 0)
    np.maximum.accumulate(idx, out=idx)
    yaw = np.where(np.isnan(yaw), yaw[idx], yaw)
    yaw = np.where(np.isnan(yaw), first_yaw, yaw)
    yaw = np.degrees(np.unwrap(np.radians(yaw)))
    yaw = gaussian_filter1d(yaw, 0.3 * RATE_HZ, mode="nearest")
    # Attitude from motion: forward tilt with speed and acceleration, bank in turns.
    yr = np.radians(yaw)
    fwd = np.stack([np.sin(yr), np.cos(yr)], -1)
    right = np.stack([np.cos(yr), -np.sin(yr)], -1)
    v_f = (vel[:, :2] * fwd).sum(-1)
    a_f = (acc[:, :2] * fwd).sum(-1)
    a_r = (acc[:, :2] * right).sum(-1)
    pitch = -(1.1 * v_f + np.degrees(np.arctan(a_f / 9.81)))
    roll = np.degrees(np.arctan(a_r / 9.81))
    jitter = _vibration(t, rng, 0.15)
    aircraft = np.stack([yaw + jitter[0] * 2, pitch + jitter[1], roll + jitter[2]], -1)
    # Gimbal: holds the commanded pitch, follows the aircraft heading, small vibration.
    gj = _vibration(t, rng, 0.04)
    gimbal = np.stack([yaw + gj[0], np.full(t.size, plan.gimbal_pitch_deg) + gj[1], gj[2]], -1)
    return Flight(
        t=t,
        position=pos,
        velocity=vel,
        aircraft_ypr=aircraft,
        gimbal_ypr=gimbal,
        home=home,
        video_start=0.0,
        video_end=float(duration),
        plan=plan,
        speed_m_s=float(speed),
        path_length_m=length,
        line_spacing_m=float(spacing),
        n_lines=n_lines,
        info={
            "footprint_across_m": round(float(footprint_across), 3),
            "footprint_along_m": round(float(footprint_along), 3),
            "truncated_by_max_speed": truncated,
            "covered_path_m": round(s_end, 3),
            "speed_in_turns_m_s": round(float(v_of_s[kappa > 0.5 * kappa.max()].min()), 3)
            if kappa.max() > 0
            else None,
            "altitude_range_m": [round(float(z_rel.min()), 3), round(float(z_rel.max()), 3)],
            # The share of the cross pattern's second grid the video covers (a plan
            # longer than the video allows at the top speed ends before it).
            **(
                {"cross_grid_flown": round(float(np.clip(cross_flown, 0.0, 1.0)), 3)}
                if plan.cross
                else {}
            ),
        },
    )


def _profile(s: np.ndarray, kappa: np.ndarray, cruise: float, plan: FlightPlan):
    """Times at the path points (and speeds) for a cruise speed, limited by lateral
    acceleration in turns and by longitudinal acceleration from and to rest."""
    vmax = np.minimum(cruise, np.sqrt(plan.lateral_accel_m_s2 / np.maximum(kappa, 1e-9)))
    ds = np.diff(s)
    a2 = 2.0 * plan.accel_m_s2
    v = vmax.copy()
    v[0] = 0.0
    for i in range(1, v.size):
        v[i] = min(v[i], np.sqrt(v[i - 1] ** 2 + a2 * ds[i - 1]))
    v[-1] = 0.0
    for i in range(v.size - 2, -1, -1):
        v[i] = min(v[i], np.sqrt(v[i + 1] ** 2 + a2 * ds[i]))
    dt = 2.0 * ds / np.maximum(v[1:] + v[:-1], 1e-9)
    return np.concatenate([[0.0], np.cumsum(dt)]), v


def _vibration(t: np.ndarray, rng: np.random.Generator, amp_deg: float) -> np.ndarray:
    """Three smooth random angle perturbations (deg): sums of random sinusoids."""
    out = np.zeros((3, t.size))
    for k in range(3):
        for _ in range(4):
            f = rng.uniform(0.2, 3.0)
            ph = rng.uniform(0, 2 * np.pi)
            out[k] += rng.normal(0, amp_deg / 2.0) * np.sin(2 * np.pi * f * t + ph)
    return out
