"""A robust similarity fit of photo camera centres to the photos' GPS positions.

Consumer drones and cameras write a GPS position into every photo whose altitude is
several times worse than its horizontal position (it drifts by tens of metres within a
minute) and whose fixes are now and then tens of metres off (multipath, a fix taken
while the receiver re-acquires). A least-squares fit spreads such errors over every
photo; this one does not:

1. a start free of outliers: similarities from random triples of cameras (Umeyama),
   the one with the least median normalised residual (LMedS, robust up to half the
   photos being wrong);
2. iteratively reweighted least squares with Tukey's biweight on the normalised
   residual r_i = |(dE, dN) / sigma_h, dU / sigma_v|, where sigma_h is the robust
   spread (MAD) of the horizontal residuals and sigma_v that of the vertical ones but
   at least `vertical_ratio` times sigma_h: the vertical counts for less, so a drifting
   altitude cannot pull the horizontal fit;
3. photos with r_i above `outlier_threshold` (and more than `min_outlier_m` off) are
   outliers: excluded, and the similarity refitted on the others by weighted least
   squares (same sigmas, no robust weights).

With the vertical down-weighted, the tilt of a flat survey would still follow the
altitude drift; a prior on the cameras' mean optical axis (`ViewPrior`: the logged
gimbal's, else straight down, as in `georef`) holds it: on simulated consumer-GPS sets
the heights beyond the flight's mean GPS error went from 4.4 to 0.11 m RMS (median).

Stand-alone GPS also drifts, by decimetres within a minute: over a lawnmower flown line
after line that drift stretches the GPS track across the lines, and a similarity takes
it as scale (-0.7 % from the GPS alone on a simulated 26 m photo set). Without RTK the
drift is fitted with the similarity as a line in time (`photo_fit`, `DriftPrior`, within
`GeorefOptions.photo_drift_sigma_m` over the flight, so that a single straight line, where
drift and scale cannot be told apart, keeps the plain fit), where the residuals show it
and no fix is an outlier: the residuals, the bundle adjustment's priors and the photo
table are then after it, and the result states the drift (`gnss_drift`). Over 40
simulated GPS tracks per error model (`benchmarks/gnss_drift.py`), the cameras' position
error after the common offset fell from 4.7 to 2.8 cm (median; p90 7.9 to 5.0, worst 10.2
to 8.4) with the stand-alone model, likewise with drift time constants of 60 s and 1000 s
and a 1 m drift; consumer GPS 21.3 to 18.5 cm (p90 and worst equal); the field model
(multipath, geometry steps) unchanged; stand-alone with 0.3 m noise 6.0 to 4.7 cm, but its
worst track 12.9 to 13.7 cm. (The criterion and the free vertical were chosen on these
models: fitted figures; docs/reconstruction.md gives the unfitted ones.)

Photos that state their own position accuracy (DJI RTK: `RtkStdLon/Lat/Hgt`, the log's
`position_sigma`) add it to the fit's sigma per photo, so a photo stating none among RTK
ones counts as stand-alone GPS (`GeorefOptions.standalone_sigma_m`): weighed down
rather than pulling the fit, and an outlier only beyond its own accuracy. Such a set's
outlier floor is `photo_rtk_min_outlier_m` instead of metres, and the fit's residuals
are checked against the stated sigma (`georef.check_stated_accuracy`).

`georeference_photos` is the photo-set counterpart of `georef.georeference`. Residuals
are model minus GPS, per photo: what the survey report lists.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from itertools import combinations
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from worker.pipeline.errors import InputError
from worker.pipeline.georef import (
    GeoreferenceError,
    GeorefOptions,
    GeorefResult,
    GnssDrift,
    MatchedPairs,
    Similarity,
    check_stated_accuracy,
    match_pairs,
    residual_stats,
    straightness,
    umeyama,
)
from worker.pipeline.ingest.flight_log import FlightLog
from worker.pipeline.trajectory import Trajectory


@dataclass
class RobustFitOptions:
    # Consumer GPS: the vertical error is several times the horizontal one.
    vertical_ratio: float = 4.0
    # Normalised residual beyond which a photo is an outlier: well above the 99.9 % point
    # of |N(0, I_3)| (3.7), as GNSS errors drift and are not Gaussian (at 4.0 a good
    # photo at the end of a drifting flight was flagged in 1 of 10 simulated sets).
    outlier_threshold: float = 5.0
    # A photo closer than this (horizontal-equivalent metres) is never an outlier: with
    # an excellent fit the normalised residuals of good photos grow large too.
    min_outlier_m: float = 5.0
    tukey_c: float = 4.685
    triples: int = 400
    iterations: int = 20
    min_sigma_m: float = 0.05
    seed: int = 0


@dataclass
class RobustFit:
    similarity: Similarity
    residuals: np.ndarray  # (N, 3) model minus GPS, east/north/up (m)
    normalised: np.ndarray  # (N,) r_i of the final fit
    used: np.ndarray  # (N,) bool: in the final fit
    sigmas: np.ndarray  # (3,) east, north, up sigmas of the final fit (m)
    start_median: float  # LMedS score of the start (horizontal-equivalent m)
    drift: GnssDrift | None = None  # the GNSS drift fitted with it (`DriftPrior`)

    @property
    def outliers(self) -> np.ndarray:
        return np.flatnonzero(~self.used)


def _normalised(d: np.ndarray, sigmas: np.ndarray) -> np.ndarray:
    return np.linalg.norm(d / sigmas, axis=1)


def _sigmas(d: np.ndarray, weights: np.ndarray, options: RobustFitOptions) -> np.ndarray:
    """Robust per-axis spread of the residuals of the photos with weight > 0."""
    sel = d[weights > 0] if (weights > 0).sum() >= 3 else d
    mad = 1.4826 * np.median(np.abs(sel - np.median(sel, axis=0)), axis=0)
    h = max(float(np.hypot(mad[0], mad[1]) / np.sqrt(2)), options.min_sigma_m)
    v = max(float(mad[2]), options.vertical_ratio * h)
    return np.array([h, h, v])


def _lmeds_start(
    local: np.ndarray, world: np.ndarray, options: RobustFitOptions, rng: np.random.Generator
) -> tuple[Similarity, float]:
    """The triple-sampled similarity with the least median residual (vertical
    down-weighted by `vertical_ratio`)."""
    n = len(local)
    scale = np.array([1.0, 1.0, 1.0 / options.vertical_ratio])
    total = n * (n - 1) * (n - 2) // 6
    if total <= options.triples:
        samples = [np.array(c) for c in combinations(range(n), 3)]
    else:
        samples = [rng.choice(n, 3, replace=False) for _ in range(options.triples)]
    extent = float(np.linalg.norm(np.ptp(local, axis=0))) or 1.0
    best, best_score = umeyama(local, world), np.inf
    for idx in samples:
        a, b, c = local[idx]
        # Nearly collinear triples leave the rotation about their line free.
        if np.linalg.norm(np.cross(b - a, c - a)) < 1e-3 * extent * extent:
            continue
        model = umeyama(local[idx], world[idx])
        if not np.isfinite(model.scale) or model.scale <= 0:
            continue
        score = float(np.median(np.linalg.norm((model.apply(local) - world) * scale, axis=1)))
        if score < best_score:
            best, best_score = model, score
    return best, best_score


@dataclass
class ViewPrior:
    """The cameras' mean optical axis: in the reconstruction frame, where it should
    point in the world (straight down for a mapping flight, or the logged gimbal's mean
    axis) and how sure that is (radians, for the mean)."""

    local_axis: np.ndarray
    world_axis: np.ndarray
    sigma_rad: float


@dataclass
class DriftPrior:
    """Fit the GNSS drift as a line in time with the similarity: camera times `t` and the
    1-sigma of the drift over the whole flight (east, north, up; m), which keeps it small
    where the geometry cannot tell it from scale (a single straight line)."""

    t: np.ndarray
    sigma_m: np.ndarray

    def drift(self, rate: np.ndarray) -> GnssDrift:
        t_ref = float(self.t.mean())
        return GnssDrift(np.asarray(rate, dtype=np.float64), t_ref, float(np.ptp(self.t)))


def _weighted_fit(
    local: np.ndarray,
    world: np.ndarray,
    init: Similarity,
    weights: np.ndarray,
    sigmas: np.ndarray,
    view: ViewPrior | None = None,
    drift: DriftPrior | None = None,
) -> tuple[Similarity, GnssDrift | None]:
    """Similarity minimising sum_i w_i |(model(x_i) + drift(t_i) - y_i) / sigmas|^2
    (per-axis sigmas: Umeyama cannot weigh the axes differently), plus the view prior:
    with the vertical down-weighted, a drifting altitude would otherwise tilt the whole
    fit; and with `drift`, the GNSS drift's rate and its prior."""
    sel = weights > 0
    x, y = local[sel], world[sel]
    if sigmas.ndim == 2:  # per photo
        sigmas = sigmas[sel]
    sw = np.sqrt(weights[sel])[:, None]
    centre = y.mean(axis=0)
    r0 = init.rotation
    # Around the photos' centre: UTM coordinates are too large for a well-scaled problem.
    t0 = init.translation - centre
    if drift is not None:
        t_ref = float(drift.t.mean())
        dt = (drift.t[sel] - t_ref)[:, None]
        span = max(float(np.ptp(drift.t)), 1e-3)

    def residuals(p: np.ndarray) -> np.ndarray:
        rot = Rotation.from_rotvec(p[:3]).as_matrix() @ r0
        s = init.scale * np.exp(p[3])
        predicted = s * x @ rot.T + p[4:7]
        parts = []
        if drift is not None:
            predicted = predicted + dt * p[7:10]
            parts.append(p[7:10] * span / drift.sigma_m)
        parts.insert(0, (sw * (predicted - (y - centre)) / sigmas).ravel())
        if view is not None:
            parts.append((rot @ view.local_axis - view.world_axis) / view.sigma_rad)
        return np.concatenate(parts)

    p0 = np.concatenate([np.zeros(4), t0, np.zeros(3 if drift is not None else 0)])
    p = least_squares(residuals, p0, method="lm").x
    model = Similarity(
        float(init.scale * np.exp(p[3])),
        Rotation.from_rotvec(p[:3]).as_matrix() @ r0,
        p[4:7] + centre,
    )
    return model, None if drift is None else drift.drift(p[7:10])


def robust_similarity(
    local: np.ndarray,
    world: np.ndarray,
    options: RobustFitOptions | None = None,
    view: ViewPrior | None = None,
    stated: np.ndarray | None = None,
    drift: DriftPrior | None = None,
) -> RobustFit:
    """Fit world ≈ s R local + t robustly; see the module doc. Needs >= 3 photos.
    `view`: a prior on where the cameras looked (holds the tilt against altitude drift).
    `stated`: (N, 3) each photo's own position sigma (E, N, U), added in quadrature to
    the fit's sigmas (the returned `sigmas` are the fit's alone). `drift`: fit the GNSS
    drift as a line in time too (the residuals are then after it)."""
    options = options or RobustFitOptions()
    local = np.asarray(local, dtype=np.float64)
    world = np.asarray(world, dtype=np.float64)
    n = len(local)
    if n < 3:
        raise ValueError("a similarity needs at least three camera positions")
    rng = np.random.default_rng(options.seed)
    model, start = _lmeds_start(local, world, options, rng)
    extra = np.zeros((n, 3)) if stated is None else np.nan_to_num(np.asarray(stated))

    def per_photo(sigmas: np.ndarray) -> np.ndarray:
        return np.sqrt(sigmas**2 + extra**2)

    weights = np.ones(n)
    gnss_drift: GnssDrift | None = None

    def residual(model: Similarity, gnss_drift: GnssDrift | None) -> np.ndarray:
        d = model.apply(local) - world
        return d if gnss_drift is None else d + gnss_drift.at(drift.t)

    d = residual(model, gnss_drift)
    sigmas = _sigmas(d, weights, options)
    for _ in range(options.iterations):
        r = _normalised(d, per_photo(sigmas))
        weights = np.where(r < options.tukey_c, (1.0 - (r / options.tukey_c) ** 2) ** 2, 0.0)
        if (weights > 0).sum() < 3:
            break
        new, new_drift = _weighted_fit(local, world, model, weights, per_photo(sigmas), view, drift)
        d_new = residual(new, new_drift)
        moved = float(np.abs(d_new - d).max())
        model, gnss_drift, d = new, new_drift, d_new
        sigmas = _sigmas(d, weights, options)
        if moved < 1e-4:
            break
    r = _normalised(d, per_photo(sigmas))
    # A photo is an outlier only beyond its own stated accuracy too (in metres).
    size = np.linalg.norm(d * np.array([1.0, 1.0, sigmas[0] / sigmas[2]]), axis=1)
    size = size - 3.0 * np.hypot(extra[:, 0], extra[:, 1])
    used = ~((r > options.outlier_threshold) & (size > options.min_outlier_m))
    if used.sum() >= 3:
        model, gnss_drift = _weighted_fit(
            local, world, model, used.astype(float), per_photo(sigmas), view, drift
        )
        d = residual(model, gnss_drift)
        sigmas = _sigmas(d, used.astype(float), options)
    return RobustFit(
        similarity=model,
        residuals=d,
        normalised=_normalised(d, per_photo(sigmas)),
        used=used,
        sigmas=sigmas,
        start_median=start,
        drift=gnss_drift,
    )


def photo_fit(
    local: np.ndarray,
    world: np.ndarray,
    t: np.ndarray,
    options: RobustFitOptions,
    view: ViewPrior | None = None,
    stated: np.ndarray | None = None,
    drift_sigma_m: float | None = None,
) -> RobustFit:
    """The robust fit of a photo set (`robust_similarity`), then, with `drift_sigma_m`
    (the horizontal drift's 1-sigma over the flight) and no outlier, again with the GNSS
    drift fitted (`DriftPrior`). Fixes metres off (multipath, re-acquisition) are no smooth
    drift: a set with such outliers keeps the plain fit (with them, the drift made it worse
    on the field GNSS model: benchmarks/gnss_drift.py). The vertical drift is left free:
    stand-alone altitudes wander by metres and not along a line, and the view prior holds
    the tilt. The drift is kept only where it explains the residuals: their chi-square
    (in the plain fit's sigmas) falls by more than 2 ln n, the Bayesian information
    criterion's price of its two horizontal rates; otherwise it only spent the noise."""
    fit = robust_similarity(local, world, options, view, stated)
    if drift_sigma_m is None or not fit.used.all():
        return fit
    drift = DriftPrior(t, np.array([drift_sigma_m, drift_sigma_m, np.inf]))
    drifting = robust_similarity(local, world, options, view, stated, drift)
    plain_chi2 = float(((fit.residuals / fit.sigmas) ** 2).sum())
    drift_chi2 = float(((drifting.residuals / fit.sigmas) ** 2).sum())
    return drifting if plain_chi2 - drift_chi2 > 2.0 * np.log(len(local)) else fit


def shape_uncertainty(
    world: np.ndarray,
    t: np.ndarray,
    sigma_h: float,
    drift_sigma_m: float | None,
) -> dict[str, float]:
    """How well horizontal positions of accuracy `sigma_h` (m, per axis) fix a fit's scale
    and rotation: the linearised least squares of shift, scale, rotation (and, with
    `drift_sigma_m`, the drift's two rates and their prior) over the positions `world` at
    camera times `t`. `at_edge_m`: twice the resulting position error at the camera
    farthest from the centre (scale and rotation together)."""
    xy = world[:, :2] - world[:, :2].mean(axis=0)
    n = len(xy)
    tau = t - t.mean()
    one, zero = np.ones(n), np.zeros(n)
    # Columns: east shift, north shift, relative scale, rotation (rad), drift rates.
    east = np.column_stack([one, zero, xy[:, 0], -xy[:, 1]])
    north = np.column_stack([zero, one, xy[:, 1], xy[:, 0]])
    if drift_sigma_m is not None:
        east = np.column_stack([east, tau, zero])
        north = np.column_stack([north, zero, tau])
    design = np.vstack([east, north]) / sigma_h
    normal = design.T @ design
    if drift_sigma_m is not None:
        span = max(float(np.ptp(t)), 1e-3)
        normal[4:, 4:] += np.eye(2) * (span / drift_sigma_m) ** 2
    covariance = np.linalg.pinv(normal)
    scale, rotation = np.sqrt(np.diag(covariance)[2:4])
    radius = float(np.hypot(xy[:, 0], xy[:, 1]).max())
    return {
        "scale": float(scale),
        "rotation_deg": float(np.degrees(rotation)),
        "at_edge_m": float(2.0 * radius * np.hypot(scale, rotation)),
    }


def photo_table(
    names: list[str], residuals: np.ndarray, used: np.ndarray, normalised: np.ndarray | None
) -> list[dict[str, Any]]:
    """One row per photo: name, residual east/north/up and horizontal (m), status."""
    rows = []
    for i, name in enumerate(names):
        d = residuals[i]
        row: dict[str, Any] = {
            "name": name,
            "east_m": round(float(d[0]), 3),
            "north_m": round(float(d[1]), 3),
            "up_m": round(float(d[2]), 3),
            "horizontal_m": round(float(np.hypot(d[0], d[1])), 3),
            "status": "used" if used[i] else "outlier",
        }
        if normalised is not None:
            row["normalised"] = round(float(normalised[i]), 3)
        rows.append(row)
    return rows


def outlier_warning(rows: list[dict[str, Any]]) -> str | None:
    bad = [r for r in rows if r["status"] == "outlier"]
    if not bad:
        return None
    listed = ", ".join(
        f"{r['name']} ({r['horizontal_m']:.1f} m horizontally, {r['up_m']:+.1f} m up)" for r in bad
    )
    return f"{len(bad)} photo(s) left out of the georeference as GPS outliers: {listed}"


def _view_prior(pairs: MatchedPairs, options: GeorefOptions) -> ViewPrior | None:
    """The logged gimbal's mean optical axis (within `sigma_tilt_deg`) when the photos
    carry it, else straight down (within `sigma_nadir_deg`; None: no prior, for oblique
    sets); as if each photo's axis were known within sigma, their mean within
    sigma / sqrt(n)."""
    if pairs.local_rot is None:
        return None
    local_axis = pairs.local_rot[:, :, 2].mean(axis=0)
    if pairs.world_rot is not None:
        world_axis, sigma_deg = pairs.world_rot[:, :, 2].mean(axis=0), options.sigma_tilt_deg
    elif options.sigma_nadir_deg is not None:
        world_axis, sigma_deg = np.array([0.0, 0.0, -1.0]), options.sigma_nadir_deg
    else:
        return None
    if np.linalg.norm(local_axis) < 0.5 or np.linalg.norm(world_axis) < 0.5:
        # The cameras looked every which way: their mean axis says little.
        return None
    return ViewPrior(
        local_axis / np.linalg.norm(local_axis),
        world_axis / np.linalg.norm(world_axis),
        float(np.radians(sigma_deg) / np.sqrt(len(pairs))),
    )


def georeference_photos(
    trajectory: Trajectory,
    names: list[str],
    log: FlightLog,
    offset_s: float,
    options: GeorefOptions | None = None,
) -> GeorefResult:
    """Georeference a photo set's cameras (`names[i]` is the photo of camera i) by the
    robust fit; the result names the outlier photos and lists every photo's residual."""
    start = time.perf_counter()
    options = options or GeorefOptions()
    pairs = match_pairs(trajectory, log, offset_s)
    if len(pairs) < max(options.min_pairs, 3):
        raise InputError(
            f"only {len(pairs)} photos have a GPS position at their time: too few to "
            "georeference without ground control points"
        )
    extent = np.ptp(pairs.world, axis=0)
    if np.hypot(extent[0], extent[1]) < 3.0:
        raise GeoreferenceError(
            f"the photos were taken within {np.hypot(extent[0], extent[1]):.1f} m: too "
            "little to georeference without ground control points"
        )
    view = _view_prior(pairs, options)
    name_of = dict(zip(trajectory.t.tolist(), names, strict=True))
    pair_names = [name_of[t] for t in pairs.t.tolist()]
    stated = _stated_accuracy(log, pairs.t + offset_s, options)
    fit_options = RobustFitOptions(
        vertical_ratio=options.photo_vertical_ratio,
        outlier_threshold=options.photo_outlier_threshold,
        min_outlier_m=options.photo_min_outlier_m,
        seed=options.seed,
    )
    if stated is not None:
        fit_options.min_outlier_m = options.photo_rtk_min_outlier_m
        # The fit's own sigma (the reconstruction's error) is no longer dwarfed by the
        # GPS's: the vertical is as good as the stated sigmas say.
        fit_options.vertical_ratio = max(1.0, float(stated.median[2] / stated.median[0]))
        fit_options.min_sigma_m = 0.01
    fit = photo_fit(
        pairs.local,
        pairs.world,
        pairs.t,
        fit_options,
        view,
        None if stated is None else stated.per_photo,
        options.photo_drift_sigma_m if stated is None else None,
    )
    rows = photo_table(pair_names, fit.residuals, fit.used, fit.normalised)
    warnings = [w for w in [outlier_warning(rows)] if w]
    used = fit.used
    shape = shape_uncertainty(
        pairs.world[used],
        pairs.t[used],
        float(fit.sigmas[0]) if stated is None else float(stated.median[0]),
        None if fit.drift is None else options.photo_drift_sigma_m,
    )
    # The log's positions less the drift fitted with them: the residuals are the rest.
    world = pairs.world if fit.drift is None else pairs.world - fit.drift.at(pairs.t)
    residuals = residual_stats(fit.similarity.apply(pairs.local[used]), world[used])
    within = None
    if stated is not None:
        # Checked over the photos that state their accuracy (the others are stand-alone).
        sel = used & stated.stating
        checked = residual_stats(fit.similarity.apply(pairs.local[sel]), world[sel])
        miss = check_stated_accuracy(checked, stated.median, options)
        within = miss is None
        warnings += [miss] if miss else []
    return GeorefResult(
        method="robust_photos",
        crs=f"EPSG:{pairs.epsg}",
        matrix=fit.similarity.matrix,
        similarity=fit.similarity,
        pairs=len(pairs),
        inliers=int(used.sum()),
        straightness=straightness(pairs.local),
        attitude_used=view is not None and pairs.world_rot is not None,
        attitude_source=pairs.attitude_source,
        attitude_disagreement_deg=None,
        residuals=residuals,
        time_offset_s=offset_s,
        warnings=warnings,
        seconds=time.perf_counter() - start,
        sigmas=fit.sigmas,
        photos=rows,
        stated_sigma=None if stated is None else stated.median,
        within_stated_accuracy=within,
        gnss_drift=fit.drift,
        shape_sigma=shape,
    )


@dataclass
class StatedAccuracy:
    """The photos' own position sigmas (an RTK set)."""

    per_photo: np.ndarray  # (M, 3) E, N, U; stand-alone sigmas for photos stating none
    median: np.ndarray  # (3,) over the photos that state one
    stating: np.ndarray  # (M,) bool


def _stated_accuracy(
    log: FlightLog, log_t: np.ndarray, options: GeorefOptions
) -> StatedAccuracy | None:
    """The photos' stated sigmas when at least half of them state one (an RTK set);
    else None: every photo alike, the fit's sigmas from its residuals."""
    stated = log.stated_sigma_at(log_t)
    if stated is None:
        return None
    ok = np.isfinite(stated).all(axis=1)
    if ok.sum() < 3 or ok.sum() * 2 < len(ok):
        return None
    h, v = options.standalone_sigma_m
    per_photo = stated.copy()
    per_photo[~ok] = (h, h, v)
    return StatedAccuracy(per_photo, np.median(stated[ok], axis=0), ok)
