"""Georeferencing without ground control points: fuse the camera trajectory with the log.

Camera positions from the reconstruction (its own frame, arbitrary scale) are paired
with log positions by timestamp (`log_time = video_time + offset`), the log positions
projected to the UTM zone of the survey (`geo.utm_epsg_for_lonlat`; heights as logged).

Methods:

- `paper4`, the paper's Eq. 2: four timestamp-matched pairs (chosen to span the largest
  tetrahedron) give an exact 4 x 4 transform T = W S^-1. Kept as the reference; it
  needs four pairs not on one plane and passes every GNSS error into the model.
- `similarity` (default): a 7-parameter similarity over all matched pairs. RANSAC on
  4-pair samples (Umeyama) finds the consistent pairs, then a robust (soft-L1)
  least-squares fit weighs horizontal and vertical GNSS errors by their own sigmas
  (given, or estimated from the residuals and their correlation time) and,
  when the log has the camera attitude (gimbal, else aircraft yaw with a nadir camera),
  adds per-camera rotation residuals: tilt with `sigma_tilt_deg` (gravity-referenced,
  good), heading with `sigma_yaw_deg` (compass, biased). On a near-straight track
  (second/first singular value of the centred camera positions below
  `straight_ratio`) positions cannot fix the rotation about the track and the
  attitude is what does. `attitude`: "auto" uses it whenever the log has it (on
  simulated surveys it cut the error beyond the GNSS bias 2.4x on a lawnmower pattern
  too: 0.65 -> 0.27 m median over 10 flights), "straight" only on near-straight tracks,
  "never". A log without any attitude (most DJI SRT files) gets a soft prior instead:
  the cameras looked straight down on average (`sigma_nadir_deg`; None for oblique
  surveys); on a 12 s straight pass over the paper's mounds it took the DSM NMAD from
  46 cm (a 7 degree roll about the track) to the level of a log with gimbal angles.
  An attitude that disagrees with the positions by more than
  `max_attitude_disagreement_deg` (ignoring the unobservable axis) is dropped with a
  warning.
- A pose-prior bundle adjustment refines the reconstruction afterwards when a
  `refine` function is given (the SLAM and SfM maps provide one); it removes the
  scale drift a single similarity cannot.

Residuals (fitted model minus log position, per matched pair) are reported per survey
as RMS east/north/up and 3D median and 95th percentile: they measure how well the
trajectories agree, including GNSS noise; they cannot see the flight's common GNSS bias.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pyproj import CRS, Transformer
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from worker.pipeline.attitude import (
    AttitudeSource,
    camera_attitude_at,
    project_to_rotation,
)
from worker.pipeline.errors import InputError, PipelineError
from worker.pipeline.geo import utm_epsg_for_lonlat
from worker.pipeline.ingest.flight_log import FlightLog
from worker.pipeline.trajectory import Trajectory

METHODS = ("similarity", "paper4")
ATTITUDE_MODES = ("auto", "straight", "never")


class GeoreferenceError(PipelineError):
    """The trajectories cannot be fused (degenerate geometry for the chosen method)."""


@dataclass
class GeorefOptions:
    method: str = "similarity"
    attitude: str = "auto"
    straight_ratio: float = 0.1
    ransac_threshold_m: float = 6.0
    ransac_iterations: int = 200
    sigma_h_m: float | None = None  # None: from the residuals of a position-only fit
    sigma_v_m: float | None = None
    sigma_tilt_deg: float = 1.0  # logged camera tilt (gravity-referenced: good)
    sigma_yaw_deg: float = 5.0  # logged heading (compass: biased by degrees)
    max_attitude_disagreement_deg: float = 15.0
    # The least movement (horizontal, or vertical with the camera's logged attitude) of
    # the logged positions a trajectory is georeferenced on: below it GNSS noise rules.
    min_motion_m: float = 3.0
    # Without any logged attitude: assume the survey camera looked straight down on
    # average (mapping flights do), within this many degrees; None for oblique surveys.
    sigma_nadir_deg: float | None = 1.0
    min_pairs: int = 4
    max_pairs: int = 2000  # longer trajectories are subsampled evenly
    seed: int = 0
    # Photo sets (robust_fit.georeference_photos): vertical sigma at least this times the
    # horizontal; outliers beyond this normalised residual and this many metres.
    photo_vertical_ratio: float = 4.0
    photo_outlier_threshold: float = 5.0
    photo_min_outlier_m: float = 5.0
    # Photos whose positions state their own accuracy (RTK): an outlier needs only be
    # this far off, and a photo stating none is weighed as stand-alone GPS of this sigma.
    photo_rtk_min_outlier_m: float = 0.5
    standalone_sigma_m: tuple[float, float] = (2.5, 5.0)
    # Photo sets with stand-alone GPS: the GPS drift over the flight is fitted as a line in
    # time along with the similarity, within this 1-sigma of its horizontal change over the
    # whole flight (robust_fit.photo_fit). Without it, the drift across a lawnmower's lines
    # is taken as scale (-0.7 % from GPS alone on a simulated 26 m set, +0.15 % with it).
    # None: not fitted. Sets stating their accuracy (RTK) drift by millimetres and fit none.
    photo_drift_sigma_m: float | None = 1.0
    # A fit whose horizontal (vertical) RMS residual exceeds this times the positions'
    # stated sigma, plus the allowance for the reconstruction's own error, misses the
    # accuracy the log promises: reported, as the cameras or the log are then wrong.
    stated_accuracy_factor: float = 3.0
    reconstruction_allowance_m: float = 0.05
    # Logs stating no accuracy (stand-alone GPS): the fit absorbs the GNSS bias, and what
    # is left is the drift within the flight, about 0.5-1 m; residuals of several metres
    # mean a distorted reconstruction or a wrong log rather than GPS noise.
    max_standalone_residual_m: float = 5.0
    # The log's position accuracy (1-sigma east, north, up, m) when the log states none
    # itself, as the user declares it: (0.02, 0.02, 0.04) for an RTK drone. None: only
    # what the log states (RTK photos) is checked.
    position_sigma_m: tuple[float, float, float] | None = None
    # A video segment whose residuals after the adjustment exceed this many times the
    # accuracy bound is broken (tracking lost and resumed wrongly): left out, with the
    # reason, when another segment is within its bound.
    broken_segment_factor: float = 10.0


_DOWN = np.array([0.0, 0.0, -1.0])


@dataclass
class Similarity:
    scale: float
    rotation: np.ndarray
    translation: np.ndarray

    @property
    def matrix(self) -> np.ndarray:
        m = np.eye(4)
        m[:3, :3] = self.scale * self.rotation
        m[:3, 3] = self.translation
        return m

    def apply(self, points: np.ndarray) -> np.ndarray:
        return self.scale * np.asarray(points) @ self.rotation.T + self.translation

    @classmethod
    def identity(cls) -> Similarity:
        return cls(1.0, np.eye(3), np.zeros(3))


@dataclass
class MatchedPairs:
    t: np.ndarray  # video seconds
    local: np.ndarray  # (M, 3) camera centres in the reconstruction frame
    world: np.ndarray  # (M, 3) log positions: UTM easting, northing, height
    local_rot: np.ndarray | None  # (M, 3, 3) world-from-camera, reconstruction frame
    world_rot: np.ndarray | None  # (M, 3, 3) from the logged attitude, ENU
    attitude_source: AttitudeSource
    epsg: int

    def __len__(self) -> int:
        return int(self.t.size)


@dataclass(frozen=True)
class GnssDrift:
    """The log's position error drifting linearly over the flight, as the fit estimated it:
    `rate` (m/s east, north, up) about camera time `t_ref`. Stand-alone GNSS wanders by
    decimetres within a minute; over a short flight that is a line in time, which a
    similarity would otherwise take as scale (a lawnmower's lines are flown one after the
    other, so the drift stretches the track across them)."""

    rate: np.ndarray
    t_ref: float
    span_s: float

    def at(self, t: np.ndarray) -> np.ndarray:
        """(N, 3) the drift at camera times `t` (what to take off the log's positions)."""
        return (np.asarray(t, dtype=np.float64) - self.t_ref)[:, None] * self.rate

    def to_dict(self) -> dict[str, Any]:
        return {
            "over_flight_m": [round(float(v), 4) for v in self.rate * self.span_s],
            "flight_s": round(self.span_s, 2),
        }


@dataclass
class GeorefResult:
    method: str
    crs: str
    matrix: np.ndarray  # 4 x 4, reconstruction frame -> UTM
    similarity: Similarity | None  # None for paper4 (a general 4 x 4)
    pairs: int
    inliers: int
    straightness: float
    attitude_used: bool
    attitude_source: AttitudeSource
    attitude_disagreement_deg: float | None
    residuals: dict[str, float]
    time_offset_s: float
    warnings: list[str] = field(default_factory=list)
    seconds: float = 0.0
    refinement: dict[str, Any] | None = None
    sigmas: np.ndarray | None = None  # GNSS sigmas (E, N, U) the fit used
    # Photo sets: per photo name, residual east/north/up (m), used or outlier.
    photos: list[dict[str, Any]] | None = None
    # The positions' own stated sigma (E, N, U; median), when the log states one (RTK),
    # and whether the fit's residuals stay within it (see `check_stated_accuracy`).
    stated_sigma: np.ndarray | None = None
    within_stated_accuracy: bool | None = None
    # The GNSS drift fitted with the similarity (photo sets with stand-alone GPS); the
    # residuals above are after it.
    gnss_drift: GnssDrift | None = None
    # Photo sets: how well the positions fix the fit's scale and rotation
    # (robust_fit.shape_uncertainty): 1-sigma scale and rotation, 2-sigma at the edge.
    shape_sigma: dict[str, float] | None = None

    @property
    def outliers(self) -> list[dict[str, Any]]:
        return [p for p in self.photos or [] if p["status"] == "outlier"]

    def apply(self, points: np.ndarray) -> np.ndarray:
        points = np.asarray(points, dtype=np.float64)
        return points @ self.matrix[:3, :3].T + self.matrix[:3, 3]

    def to_dict(self) -> dict[str, Any]:
        out = self._base_dict()
        if self.photos is not None:
            # Only photo sets: the video results keep the keys they always had.
            out["outliers"] = [p["name"] for p in self.outliers]
            out["photos"] = self.photos
        if self.gnss_drift is not None:
            out["gnss_drift"] = self.gnss_drift.to_dict()
        if self.shape_sigma is not None:
            out["shape_sigma"] = {k: round(v, 6) for k, v in self.shape_sigma.items()}
        return out

    def _base_dict(self) -> dict[str, Any]:
        sim = None
        if self.similarity is not None:
            angles = Rotation.from_matrix(self.similarity.rotation).as_rotvec(degrees=True)
            sim = {
                "scale": self.similarity.scale,
                "rotation_vector_deg": [round(float(a), 4) for a in angles],
                "translation": [round(float(v), 4) for v in self.similarity.translation],
            }
        return {
            "method": self.method,
            "crs": self.crs,
            "matrix": [[float(v) for v in row] for row in self.matrix],
            "similarity": sim,
            "pairs": self.pairs,
            "inliers": self.inliers,
            "straightness": round(self.straightness, 5),
            "attitude_used": self.attitude_used,
            "attitude_source": self.attitude_source,
            "attitude_disagreement_deg": (
                None
                if self.attitude_disagreement_deg is None
                else round(self.attitude_disagreement_deg, 3)
            ),
            "residuals_m": {k: round(v, 4) for k, v in self.residuals.items()},
            "time_offset_s": round(self.time_offset_s, 4),
            "warnings": self.warnings,
            "seconds": round(self.seconds, 3),
            "refinement": self.refinement,
            "gnss_sigmas_m": None
            if self.sigmas is None
            else [round(float(v), 4) for v in self.sigmas],
            "stated_sigma_m": None
            if self.stated_sigma is None
            else [round(float(v), 4) for v in self.stated_sigma],
            "within_stated_accuracy": self.within_stated_accuracy,
        }


def survey_epsg(log: FlightLog) -> int:
    """The UTM zone of the survey: that of the median logged position."""
    ok = log.valid
    if not ok.any():
        raise InputError(f"{log.path}: no GPS position to place the survey")
    return utm_epsg_for_lonlat(float(np.median(log.lon[ok])), float(np.median(log.lat[ok])))


def log_to_utm(lon: np.ndarray, lat: np.ndarray, alt: np.ndarray, epsg: int) -> np.ndarray:
    transformer = Transformer.from_crs(CRS.from_epsg(4326), CRS.from_epsg(epsg), always_xy=True)
    e, n = transformer.transform(np.asarray(lon), np.asarray(lat))
    return np.column_stack([e, n, np.asarray(alt, dtype=np.float64)])


def match_pairs(
    trajectory: Trajectory, log: FlightLog, offset_s: float, epsg: int | None = None
) -> MatchedPairs:
    """Pair each camera with the log position at its time (linear interpolation)."""
    epsg = epsg or survey_epsg(log)
    log_t = trajectory.t + offset_s
    values = log.interpolate(log_t)
    alt = values["alt"]
    if not np.isfinite(alt).any():
        alt = np.zeros_like(alt)
    ok = np.isfinite(values["lat"]) & np.isfinite(values["lon"]) & np.isfinite(alt)
    world = log_to_utm(values["lon"][ok], values["lat"][ok], alt[ok], epsg)
    world_rot, source = camera_attitude_at(log, log_t[ok])
    if world_rot is not None:
        finite = np.isfinite(world_rot).all(axis=(1, 2))
        if not finite.all():
            world_rot = None if not finite.any() else world_rot
    return MatchedPairs(
        t=trajectory.t[ok],
        local=trajectory.positions[ok],
        world=world,
        local_rot=trajectory.rotations[ok],
        world_rot=world_rot,
        attitude_source=source if world_rot is not None else AttitudeSource.none,
        epsg=epsg,
    )


def umeyama(src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None) -> Similarity:
    """Least-squares similarity dst ≈ s R src + t (Umeyama 1991), optionally weighted."""
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    mu_s = w @ src
    mu_d = w @ dst
    xs = src - mu_s
    xd = dst - mu_d
    cov = (xd * w[:, None]).T @ xs
    u, d, vt = np.linalg.svd(cov)
    sign = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2] = -1.0
    rotation = u @ np.diag(sign) @ vt
    var_s = float(w @ (xs * xs).sum(axis=1))
    scale = float((d * sign).sum() / var_s) if var_s > 0 else 1.0
    return Similarity(scale, rotation, mu_d - scale * rotation @ mu_s)


def straightness(points: np.ndarray) -> float:
    """Second / first singular value of the centred points (0 = a straight line)."""
    centred = points - points.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    if s[0] <= 0:
        return 0.0
    return float(s[1] / s[0])


def fit_paper4(pairs: MatchedPairs) -> tuple[np.ndarray, np.ndarray]:
    """The paper's Eq. 2 on four well-spread pairs: (4 x 4 matrix, indices used)."""
    x = pairs.local
    if len(x) < 4:
        raise GeoreferenceError("paper4 needs four timestamp-matched positions")
    i0 = int(np.argmax(np.linalg.norm(x - x.mean(axis=0), axis=1)))
    i1 = int(np.argmax(np.linalg.norm(x - x[i0], axis=1)))
    axis = (x[i1] - x[i0]) / max(np.linalg.norm(x[i1] - x[i0]), 1e-12)
    rel = x - x[i0]
    i2 = int(np.argmax(np.linalg.norm(rel - np.outer(rel @ axis, axis), axis=1)))
    normal = np.cross(x[i1] - x[i0], x[i2] - x[i0])
    norm = np.linalg.norm(normal)
    if norm < 1e-12:
        raise GeoreferenceError("paper4: the camera track is a straight line")
    normal /= norm
    i3 = int(np.argmax(np.abs(rel @ normal)))
    idx = np.array([i0, i1, i2, i3])
    extent = np.linalg.norm(x[i1] - x[i0])
    if abs(rel[i3] @ normal) < 1e-6 * extent or len(set(idx.tolist())) < 4:
        raise GeoreferenceError(
            "paper4 needs four matched points that are not on one plane; this track is "
            "planar: use the default method"
        )
    s = np.vstack([x[idx].T, np.ones(4)])
    w = np.vstack([pairs.world[idx].T, np.ones(4)])
    return w @ np.linalg.inv(s), idx


def _ransac(pairs: MatchedPairs, options: GeorefOptions, rng: np.random.Generator) -> np.ndarray:
    """Inlier mask of the best 4-sample Umeyama hypothesis."""
    n = len(pairs)
    best = np.ones(n, dtype=bool)
    best_count = -1
    if n < 8:
        return best
    for _ in range(options.ransac_iterations):
        sample = rng.choice(n, 4, replace=False)
        if straightness(pairs.local[sample]) < 1e-3:
            continue
        model = umeyama(pairs.local[sample], pairs.world[sample])
        if not np.isfinite(model.scale) or model.scale <= 0:
            continue
        err = np.linalg.norm(model.apply(pairs.local) - pairs.world, axis=1)
        inliers = err < options.ransac_threshold_m
        count = int(inliers.sum())
        if count > best_count:
            best, best_count = inliers, count
    if best_count < max(options.min_pairs, 0.2 * n):
        return np.ones(n, dtype=bool)
    return best


def _mean_rotation(pairs: MatchedPairs, mask: np.ndarray) -> np.ndarray:
    """Chordal mean of world_rot_i @ local_rot_i^T: the rotation the attitude implies."""
    m = np.einsum("nij,nkj->ik", pairs.world_rot[mask], pairs.local_rot[mask])
    return project_to_rotation(m)


def _attitude_disagreement(
    pairs: MatchedPairs,
    positional: Similarity,
    mask: np.ndarray,
    straight: float,
    options: GeorefOptions,
) -> float:
    """Angle (deg) between the rotation the attitude implies and the one positions give,
    counting only what positions determine: on a near-straight track, the rotation
    about the track axis is left out."""
    rel = _mean_rotation(pairs, mask) @ positional.rotation.T
    omega = Rotation.from_matrix(rel).as_rotvec()
    if straight < options.straight_ratio:
        centred = pairs.world[mask] - pairs.world[mask].mean(axis=0)
        axis = np.linalg.svd(centred, full_matrices=False)[2][0]
        omega = omega - (omega @ axis) * axis
    return float(np.degrees(np.linalg.norm(omega)))


def _gnss_sigmas(
    pairs: MatchedPairs, model: Similarity, mask: np.ndarray, options: GeorefOptions
) -> np.ndarray:
    """Position sigmas (east, north, up) for the fit.

    The options' values when given; else the robust spread (NMAD) of a position-only
    fit's residuals, inflated by sqrt(n / n_eff) because GNSS errors are correlated in
    time (a slowly drifting bias): n_eff is the number of residual correlation times
    in the flight. At least 1 cm; vertical at least the horizontal.
    """
    d = model.apply(pairs.local[mask]) - pairs.world[mask]
    nmad = 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    inflation = np.sqrt(len(d) / _effective_samples(pairs.t[mask], d))
    h = options.sigma_h_m or max(float(np.hypot(nmad[0], nmad[1]) / np.sqrt(2)) * inflation, 0.01)
    v = options.sigma_v_m or max(float(nmad[2]) * inflation, h)
    return np.array([h, h, v])


def _effective_samples(t: np.ndarray, residuals: np.ndarray) -> float:
    """Flight duration over the residuals' correlation time (lag where the mean
    autocorrelation of the three axes first falls below 1/2), at least 1."""
    n = len(t)
    if n < 8:
        return float(n)
    r = residuals - residuals.mean(axis=0)
    var = (r * r).sum(axis=0)
    var[var == 0] = 1.0
    dt = float(np.median(np.diff(t))) or 1.0
    for lag in range(1, n // 2):
        acf = float(np.mean((r[lag:] * r[:-lag]).sum(axis=0) / var))
        if acf < 0.5:
            return float(np.clip((t[-1] - t[0]) / (lag * dt), 1.0, n))
    return 1.0


def _refine(
    pairs: MatchedPairs,
    init: Similarity,
    mask: np.ndarray,
    sig: np.ndarray,
    options: GeorefOptions,
    use_attitude: bool,
    use_nadir: bool = False,
) -> Similarity:
    """Robust least squares over position (and attitude) residuals, scaled by sigmas."""
    x, y = pairs.local[mask], pairs.world[mask]
    r0 = init.rotation
    if use_nadir:
        # Mean optical axis (camera z) in the reconstruction frame; it should map to down.
        axis = pairs.local_rot[mask][:, :, 2].mean(axis=0)
        axis /= np.linalg.norm(axis)
        # As if each camera's axis were known within sigma: their mean within sigma/sqrt(n).
        sig_nadir = np.radians(options.sigma_nadir_deg) / np.sqrt(len(x))
    if use_attitude:
        rw, rl = pairs.world_rot[mask], pairs.local_rot[mask]
        # Camera-frame rotation residual: x, y tilt the optical axis, z turns about it
        # (the heading, for a camera looking down).
        sig_att = np.radians(
            [options.sigma_tilt_deg, options.sigma_tilt_deg, options.sigma_yaw_deg]
        )

    def residuals(p: np.ndarray) -> np.ndarray:
        rot = Rotation.from_rotvec(p[:3]).as_matrix() @ r0
        s = init.scale * np.exp(p[3])
        res = ((s * x @ rot.T + p[4:7]) - y) / sig
        if use_nadir:
            view = rot @ axis  # unit vector; (0, 0, -1) when the camera looks straight down
            return np.concatenate([res.ravel(), (view - _DOWN) / sig_nadir])
        if not use_attitude:
            return res.ravel()
        rel = np.einsum("nji,jk,nkl->nil", rw, rot, rl)
        att = Rotation.from_matrix(rel).as_rotvec() / sig_att
        return np.concatenate([res.ravel(), att.ravel()])

    p0 = np.concatenate([np.zeros(4), init.translation])
    # Plain least squares first (converges from far), then the robust loss from there.
    p = least_squares(residuals, p0, method="lm").x
    p = least_squares(residuals, p, loss="soft_l1", f_scale=2.0, method="trf").x
    return Similarity(
        float(init.scale * np.exp(p[3])), Rotation.from_rotvec(p[:3]).as_matrix() @ r0, p[4:7]
    )


def _facing_down(init: Similarity, pairs: MatchedPairs, mask: np.ndarray) -> Similarity:
    """On a line, positions fit equally well with the cameras looking up or down: turn
    the fit half a turn about the track when it has them looking up."""
    view = init.rotation @ pairs.local_rot[mask][:, :, 2].mean(axis=0)
    if view[2] <= 0:
        return init
    centred = pairs.world[mask] - pairs.world[mask].mean(axis=0)
    track = np.linalg.svd(centred, full_matrices=False)[2][0]
    half_turn = Rotation.from_rotvec(np.pi * track).as_matrix()
    centre = pairs.world[mask].mean(axis=0)
    # x' = H (s R x + t - c) + c keeps the positions on the line where they were.
    return Similarity(
        init.scale, half_turn @ init.rotation, half_turn @ (init.translation - centre) + centre
    )


def fit_similarity(
    pairs: MatchedPairs, options: GeorefOptions | None = None
) -> tuple[Similarity, dict[str, Any]]:
    """The default method (see the module doc). Returns the similarity and what it did."""
    options = options or GeorefOptions()
    rng = np.random.default_rng(options.seed)
    warnings: list[str] = []
    straight = straightness(pairs.local)
    has_att = pairs.world_rot is not None and pairs.local_rot is not None
    want_att = options.attitude == "auto" or (
        options.attitude == "straight" and straight < options.straight_ratio
    )
    # A soft prior: where positions fix the rotation (a lawnmower of many lines) it has
    # no say; where they cannot (a line, a narrow strip) it holds the roll about the track.
    use_nadir = not has_att and options.sigma_nadir_deg is not None and pairs.local_rot is not None
    if use_nadir and straight < options.straight_ratio:
        warnings.append(
            "the track is near-straight and the log has no camera attitude: the rotation "
            "about the track was set by assuming the camera looked straight down"
        )
    use_att = want_att and has_att
    inliers = _ransac(pairs, options, rng)
    init = umeyama(pairs.local[inliers], pairs.world[inliers])
    sigmas = _gnss_sigmas(pairs, init, inliers, options)
    disagreement = None
    if has_att:
        disagreement = _attitude_disagreement(pairs, init, inliers, straight, options)
        if use_att and disagreement > options.max_attitude_disagreement_deg:
            warnings.append(
                f"the logged camera attitude disagrees with the trajectory by "
                f"{disagreement:.1f} deg; it was ignored"
            )
            use_att = False
    if use_att:
        # Rotation from the attitude, then scale and translation from positions.
        rot = _mean_rotation(pairs, inliers)
        xs = pairs.local[inliers] @ rot.T
        ys = pairs.world[inliers]
        xc, yc = xs - xs.mean(axis=0), ys - ys.mean(axis=0)
        scale = float((xc * yc).sum() / max((xc * xc).sum(), 1e-12))
        init = Similarity(scale, rot, ys.mean(axis=0) - scale * xs.mean(axis=0))
    if use_nadir:
        init = _facing_down(init, pairs, inliers)
    model = _refine(pairs, init, inliers, sigmas, options, use_att, use_nadir)
    # Second pass: inliers by normalised residual, refit.
    norm = np.linalg.norm((model.apply(pairs.local) - pairs.world) / sigmas, axis=1)
    keep = norm < max(4.0, float(np.median(norm)) * 3.0)
    if keep.sum() >= options.min_pairs and not np.array_equal(keep, inliers):
        inliers = keep
        model = _refine(pairs, model, inliers, sigmas, options, use_att, use_nadir)
    info = {
        "straightness": straight,
        "attitude_used": use_att,
        "nadir_assumed": use_nadir,
        "attitude_disagreement_deg": disagreement,
        "inliers": inliers,
        "warnings": warnings,
        "sigmas": sigmas,
    }
    return model, info


def residual_stats(predicted: np.ndarray, world: np.ndarray) -> dict[str, float]:
    d = predicted - world
    dist = np.linalg.norm(d, axis=1)
    rms = np.sqrt((d * d).mean(axis=0))
    return {
        "rms_east": float(rms[0]),
        "rms_north": float(rms[1]),
        "rms_up": float(rms[2]),
        "median_3d": float(np.median(dist)),
        "p95_3d": float(np.percentile(dist, 95)),
        "max_3d": float(dist.max()),
    }


def check_stated_accuracy(
    residuals: dict[str, float], stated: np.ndarray, options: GeorefOptions
) -> str | None:
    """None when the fit's RMS residuals (`residual_stats`) stay within
    `stated_accuracy_factor` times the stated sigma (E, N, U) plus the reconstruction
    allowance; else a warning naming both."""
    rms_h = float(np.hypot(residuals["rms_east"], residuals["rms_north"]))
    stated_h = float(np.hypot(stated[0], stated[1]))
    bound_h, bound_v = accuracy_bounds(stated, options)
    if rms_h <= bound_h and residuals["rms_up"] <= bound_v:
        return None
    return (
        f"the georeference misses the positions' stated accuracy: RMS residual "
        f"{rms_h:.2f} m horizontally and {residuals['rms_up']:.2f} m vertically where the "
        f"log states {stated_h:.3f} m and {float(stated[2]):.3f} m (allowed "
        f"{bound_h:.2f} m and {bound_v:.2f} m): the reconstruction is distorted or some "
        "positions are wrong"
    )


def position_accuracy(log: FlightLog, options: GeorefOptions) -> np.ndarray | None:
    """The positions' 1-sigma (east, north, up): as the log states it (median), else as
    declared in the options, else None (nothing to check against)."""
    stated = log.stated_sigma_m()
    if stated is not None:
        return np.asarray(stated, dtype=np.float64)
    if options.position_sigma_m is not None:
        return np.asarray(options.position_sigma_m, dtype=np.float64)
    return None


def accuracy_bounds(stated: np.ndarray, options: GeorefOptions) -> tuple[float, float]:
    """The horizontal and vertical RMS residuals a fit may leave against positions of
    this sigma (east, north, up)."""
    factor, allowance = options.stated_accuracy_factor, options.reconstruction_allowance_m
    return (
        factor * float(np.hypot(stated[0], stated[1])) + allowance,
        factor * float(stated[2]) + allowance,
    )


RefineFn = Callable[[GeorefResult, MatchedPairs], dict[str, Any]]


def _check_motion(pairs: MatchedPairs, options: GeorefOptions) -> None:
    """GeoreferenceError when the logged positions moved too little to fix the scale and
    rotation. A climb or descent counts where the log's camera attitude fixes the heading
    (a nadir camera sees the ground change scale: the distance climbed is the scale)."""
    extent = np.ptp(pairs.world, axis=0)
    horizontal, vertical = float(np.hypot(extent[0], extent[1])), float(extent[2])
    least = options.min_motion_m
    if horizontal >= least:
        return
    attitude = pairs.world_rot is not None and options.attitude != "never"
    if vertical >= least and attitude:
        return
    span = f"{pairs.t[0]:.1f}-{pairs.t[-1]:.1f} s of the video" if len(pairs) else "the video"
    if vertical >= least:
        raise GeoreferenceError(
            f"the aircraft moved only {horizontal:.1f} m horizontally during {span}, "
            f"climbing or descending {vertical:.1f} m: a vertical move gives the scale but "
            "not the heading, and the flight log has no camera attitude to give it, so this "
            "part cannot be georeferenced without ground control points"
        )
    raise GeoreferenceError(
        f"the aircraft moved only {horizontal:.1f} m horizontally and {vertical:.1f} m "
        f"vertically during {span}: too little to georeference without ground control "
        "points"
    )


def georeference(
    trajectory: Trajectory,
    log: FlightLog,
    offset_s: float,
    options: GeorefOptions | None = None,
    refine: RefineFn | None = None,
) -> GeorefResult:
    """Fuse the camera trajectory with the log; see the module doc for the methods.

    `refine`, when given, runs the pose-prior bundle adjustment: it receives the result
    and the matched pairs, moves the reconstruction in place and returns a report that
    is stored in `result.refinement`.
    """
    start = time.perf_counter()
    options = options or GeorefOptions()
    if options.method not in METHODS:
        raise InputError(f"unknown georeferencing method {options.method!r}; use {METHODS}")
    if options.attitude not in ATTITUDE_MODES:
        raise InputError(f"unknown attitude mode {options.attitude!r}; use {ATTITUDE_MODES}")
    if len(trajectory) > options.max_pairs:
        step = int(np.ceil(len(trajectory) / options.max_pairs))
        trajectory = trajectory.subset(np.arange(len(trajectory)) % step == 0)
    pairs = match_pairs(trajectory, log, offset_s)
    if len(pairs) < options.min_pairs:
        raise InputError(
            f"only {len(pairs)} camera positions fall within the flight log's time span "
            f"(offset {offset_s:.2f} s); the log and the video do not overlap enough"
        )
    _check_motion(pairs, options)
    crs = f"EPSG:{pairs.epsg}"
    warnings: list[str] = []
    if options.method == "paper4":
        matrix, _ = fit_paper4(pairs)
        inlier_count = 4
        straight = straightness(pairs.local)
        sim = None
        att_used, disagreement = False, None
        predicted = pairs.local @ matrix[:3, :3].T + matrix[:3, 3]
        sigmas = None
    else:
        sim, info = fit_similarity(pairs, options)
        matrix = sim.matrix
        inlier_count = int(info["inliers"].sum())
        straight = info["straightness"]
        att_used = info["attitude_used"]
        disagreement = info["attitude_disagreement_deg"]
        warnings += info["warnings"]
        predicted = sim.apply(pairs.local)
        sigmas = info["sigmas"]
    result = GeorefResult(
        method=options.method,
        crs=crs,
        matrix=matrix,
        similarity=sim,
        pairs=len(pairs),
        inliers=inlier_count,
        straightness=straight,
        attitude_used=att_used,
        attitude_source=pairs.attitude_source,
        attitude_disagreement_deg=disagreement,
        residuals=residual_stats(predicted, pairs.world),
        time_offset_s=offset_s,
        warnings=warnings,
        sigmas=sigmas,
    )
    if refine is not None and options.method == "similarity":
        result.refinement = refine(result, pairs)
    result.seconds = time.perf_counter() - start
    return result


def offset_residual_fn(
    trajectory: Trajectory, log: FlightLog, epsg: int | None = None
) -> Callable[[float], float]:
    """For `time_offset.refine_time_offset`: the median 3D residual of a plain
    similarity fit between cameras and log positions at a given offset."""
    epsg = epsg or survey_epsg(log)

    def residual(offset_s: float) -> float:
        pairs = match_pairs(trajectory, log, offset_s, epsg)
        if len(pairs) < 4 or straightness(pairs.local) < 1e-4:
            return float("nan")
        model = umeyama(pairs.local, pairs.world)
        return float(np.median(np.linalg.norm(model.apply(pairs.local) - pairs.world, axis=1)))

    return residual
