"""Georeference a whole reconstruction: every map segment fused with the log, then a
pose-prior bundle adjustment that lets the GNSS positions correct scale drift.

For each segment of the `SparseMap` (one per tracking loss): its camera trajectory is
fused with the log (`georef.georeference`), the segment is moved by the fitted
transform, and, with `refine`, a bundle adjustment over all its keyframes and points
adds one position prior per keyframe (GNSS at the keyframe's time; sigmas: the robust
spread of the keyframes' residuals after the fit), so that the GNSS positions pull out
the reconstruction's drift (scale drift over a long flight). Reprojection errors cannot
see a similarity of the whole segment, so in that BA the priors alone would set its
rotation, tilting small sites by the GNSS height drift (measured: DSM NMAD 5.5 -> 19 cm
on the paper's mounds); the similarity the BA introduced is therefore undone and only
the bending is kept. Frames follow their keyframes. The `paper4` method is applied as
the paper does, without refinement (its 4 x 4 is not a similarity, so the map is moved
point by point).

By default (`world_adjust`) a video segment is instead adjusted in the world frame
(`georef_world.adjust_segment`): priors on the positions (at their stated sigmas where
the log states them, RTK or `GeorefOptions.position_sigma_m`; else at the spread of the
fit's residuals, its GNSS drift removed), on the logged attitude, which now holds the
rotation the priors alone would tilt, and on the clock offset; nothing undone. With
stated sigmas its frames between keyframes are put on the log's positions. Straight
segments are adjusted too where the log's attitude holds their roll. The pose-prior
adjustment above stays for photo sets and for `world_adjust=False`.

A placed video segment whose cameras still miss the log (by more than its stated
accuracy allows, or 5 m with stand-alone GPS) is looked at for breaks of the
reconstruction's scale against the distances the log flew (scale_breaks.py): cut there,
the pieces that keep one scale long enough are placed again on their own, the stretches
between them left out with the reason.

Photo sets (`photos`: the photo name of each camera time) are fitted by the robust
photo fit (`robust_fit.georeference_photos`): outlier photos are named, left out of the
fit and of the bundle adjustment's priors, and every photo's residual after the
georeference (after the adjustment when it ran) is listed in `photos`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pycolmap

from worker.pipeline.errors import InputError
from worker.pipeline.georef import (
    GeoreferenceError,
    GeorefOptions,
    GeorefResult,
    GnssDrift,
    accuracy_bounds,
    check_stated_accuracy,
    georeference,
    log_to_utm,
    position_accuracy,
    residual_stats,
    survey_epsg,
    umeyama,
)
from worker.pipeline.georef_world import WorldAdjustOptions, adjust_segment
from worker.pipeline.ingest.flight_log import FlightLog
from worker.pipeline.robust_fit import georeference_photos, photo_table
from worker.pipeline.scale_breaks import ScaleBreakOptions, split_at_scale_breaks
from worker.pipeline.slam.bundle import BAProblem, bundle_adjust
from worker.pipeline.slam.result import SparseMap


@dataclass
class MapGeorefOptions:
    georef: GeorefOptions = field(default_factory=GeorefOptions)
    refine: bool = True
    refine_iterations: int = 20
    # A track straighter than this (second / first singular value of its positions) is
    # not adjusted: positions along a line hold neither its roll nor its bending, and the
    # adjustment only bent it along the GNSS noise (one 12-s line over the mounds, RTK:
    # DSM NMAD 0.23 m adjusted, 0.12 m not; a 149-m line over the hillslope: the same).
    refine_min_straightness: float = 0.1
    min_prior_sigma_m: float = 0.02
    prior_sigma_m: tuple[float, float, float] | None = None  # None: from the residuals
    # Where the log states its accuracy (RTK), video segments are adjusted in the world
    # frame against the positions, the attitude and the offset instead (georef_world).
    world: WorldAdjustOptions = field(default_factory=WorldAdjustOptions)
    # Video segments are cut where their scale breaks against the log (scale_breaks.py).
    scale_breaks: ScaleBreakOptions = field(default_factory=ScaleBreakOptions)
    # Video segments are adjusted in the world frame (georef_world): against positions at
    # their stated sigmas (RTK) or at the spread of the fit's residuals (stand-alone GPS,
    # its drift removed). False: the pose-prior adjustment with the similarity undone.
    world_adjust: bool = True


@dataclass
class MapGeorefResult:
    crs: str
    segments: list[dict[str, Any]]
    time_offset_s: float
    seconds: float
    warnings: list[str] = field(default_factory=list)
    # Photo sets: one row per registered photo (photo_table's, plus the segment).
    photos: list[dict[str, Any]] | None = None
    # The offset the world-frame adjustment settled on (every segment's evidence, the
    # longest's first), when it ran with the offset free; None otherwise.
    adjusted_offset_s: float | None = None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "crs": self.crs,
            "segments": self.segments,
            "time_offset_s": round(self.time_offset_s, 4),
            "seconds": round(self.seconds, 3),
            "warnings": self.warnings,
        }
        if self.photos is not None:
            out["photos"] = self.photos
        return out


def photo_names_at(times: np.ndarray, photos: dict[float, str]) -> list[str]:
    """The photo name at each camera time (nearest photo time within 10 ms; a camera
    without one is named by its time)."""
    known = np.array(sorted(photos), dtype=np.float64)
    by_time = [photos[t] for t in sorted(photos)]
    names = []
    for t in np.asarray(times, dtype=np.float64).tolist():
        i = int(np.argmin(np.abs(known - t))) if known.size else -1
        names.append(by_time[i] if i >= 0 and abs(known[i] - t) < 0.01 else f"t={t:.3f}s")
    return names


def georeference_map(
    sparse: SparseMap,
    log: FlightLog,
    offset_s: float,
    options: MapGeorefOptions | None = None,
    photos: dict[float, str] | None = None,
    hold_offset: bool = True,
) -> MapGeorefResult:
    """Move `sparse` (in place) into the UTM zone of the survey; see the module doc.
    `photos` (photo sets): camera time -> photo name. `hold_offset`: the world-frame
    adjustment keeps `offset_s` (the log's clock is the video's, or the user gave it)."""
    start = time.perf_counter()
    options = options or MapGeorefOptions()
    epsg = survey_epsg(log)
    accuracy = position_accuracy(log, options.georef)
    # Segments the world-frame adjustment kept.
    adjusted: set[int] = set()
    # One clock for the whole recording: a loss of tracking does not change the offset
    # between the video's clock and the log's, but a short segment on a straight line
    # cannot tell a shift in time from one along the line (seed 112 of the many-flight
    # benchmark: nine segments settled offsets up to 0.15 s apart, 1 m along their
    # lines). The longest segment is adjusted first under the offset's loose prior; each
    # next one takes the offset settled so far at its standard error as its prior, and
    # what it finds refines it. [offset, sigma]; sigma None: held.
    clock: list[Any] = [offset_s, None if hold_offset else options.world.offset_sigma_s]
    results: list[dict[str, Any]] = []
    warnings: list[str] = []
    table: list[dict[str, Any]] | None = None if photos is None else []

    def place(segment: int, several: bool) -> dict[str, Any] | None:
        """Fit and adjust one segment; its entry, or None where it was left out."""
        traj = sparse.trajectory(segment)
        segment_offset = offset_s if photos is not None else float(clock[0])
        try:
            if photos is None:
                fit = georeference(traj, log, segment_offset, options.georef)
            else:
                names = photo_names_at(traj.t, photos)
                fit = georeference_photos(traj, names, log, offset_s, options.georef)
        except (InputError, GeoreferenceError) as exc:
            # One segment that cannot be placed (too little motion, no log over it) is
            # left out with its reason; the others make the DSM.
            if not several:
                raise
            warnings.append(f"segment {segment} left out: {exc}")
            _drop_segment(sparse, segment)
            return None
        entry = {"segment": segment, "frames": len(traj), "fit": fit.to_dict()}
        # The outlier photos' GPS positions must not pull the adjustment either.
        excluded = _outlier_times(fit, traj.t, photos)
        if fit.similarity is not None:
            s = fit.similarity
            sparse.transform(s.scale, s.rotation, s.translation, segment)
            if options.refine and photos is None and options.world_adjust:
                sigma = accuracy
                if sigma is None:
                    sigma = _spread_sigma(sparse, segment, log, offset_s, epsg, fit, options)
                try:
                    entry["refinement"] = adjust_segment(
                        sparse,
                        segment,
                        log,
                        segment_offset,
                        epsg,
                        sigma,
                        options.world,
                        offset_sigma_s=clock[1],
                        straight=fit.straightness < options.refine_min_straightness,
                        drift=fit.gnss_drift,
                        stated_accuracy=accuracy is not None,
                    )
                except np.linalg.LinAlgError as exc:
                    # The adjustment changes the map only once it has succeeded: the
                    # segment keeps its fit, and the reason goes into the report.
                    entry["refinement"] = {
                        "kept": False,
                        "reason": f"the adjustment against the log broke down ({exc}): "
                        "the segment keeps its fit",
                        "offset_s": segment_offset,
                    }
                segment_offset = entry["refinement"]["offset_s"]
                if entry["refinement"].get("kept"):
                    adjusted.add(segment)
                    sigma_s = entry["refinement"].get("offset_sigma_s")
                    if clock[1] is not None:
                        # Without a stated sigma (a singular system) the next segment
                        # keeps the prior's.
                        floor = options.world.min_offset_sigma_s
                        sigma = clock[1] if sigma_s is None else max(float(sigma_s), floor)
                        clock[:] = [segment_offset, sigma]
            elif options.refine and fit.straightness < options.refine_min_straightness:
                entry["refinement"] = {
                    "skipped": f"a near-straight track (straightness {fit.straightness:.3f}): "
                    "its positions cannot correct its shape"
                }
            elif options.refine:
                entry["refinement"] = _refine_segment(
                    sparse, segment, log, offset_s, fit, options, excluded
                )
        else:
            _apply_matrix(sparse, segment, fit)
        sparse.update_frames_from_keyframes()
        entry["residuals_after_m"] = _residuals(
            sparse, segment, log, segment_offset, epsg, excluded, fit.gnss_drift
        )
        entry["offset_s"] = segment_offset
        if table is not None and photos is not None:
            # The fit's table is superseded by the one after the adjustment, below.
            entry["fit"].pop("photos", None)
            table.extend(
                _photo_rows(sparse, segment, log, offset_s, epsg, photos, excluded, fit.gnss_drift)
            )
        if fit.photos is not None:
            warnings.extend(fit.warnings)
        return entry

    several = len(sparse.segments) > 1
    # The longest segment first: it settles the clock best.
    frames = {s: int((sparse.fr_segment == s).sum()) for s in sparse.segments}
    for segment in sorted(sparse.segments, key=lambda s: (-frames[s], s)):
        if (entry := place(segment, several)) is not None:
            results.append(entry)
    results.sort(key=lambda e: e["segment"])
    if photos is None and options.scale_breaks.enabled and results:
        # Breaks are looked for once the segments are placed and adjusted: with RTK the
        # adjustment mends the scale jumps it can see, and only what it could not mend
        # is cut. The pieces kept are placed again on their own.
        placed = {
            e["segment"]: (e["offset_s"], float(np.hypot(r["rms_east"], r["rms_north"])))
            for e in results
            if "rms_east" in (r := e.get("residuals_after_m") or {})
        }
        bound = (
            options.georef.max_standalone_residual_m
            if accuracy is None
            else accuracy_bounds(accuracy, options.georef)[0]
        )
        cuts = split_at_scale_breaks(sparse, log, placed, epsg, bound, options.scale_breaks)
        for piece in cuts.left_out:
            warnings.append(f"segment {piece.segment} left out: {piece.reason}")
            _drop_segment(sparse, piece.segment)
        if cuts.cut:
            results = [e for e in results if e["segment"] not in cuts.cut]
            adjusted.difference_update(cuts.cut)
            several = len(sparse.segments) > 1
            for segment in cuts.kept:
                if (entry := place(segment, several)) is not None:
                    results.append(entry)
            results.sort(key=lambda e: e["segment"])
    if not results:
        raise InputError(
            "no part of the reconstruction could be georeferenced: " + "; ".join(warnings)
        )
    if photos is None and accuracy is not None:
        results, dropped = _check_segments(sparse, results, accuracy, options.georef, warnings)
        if dropped:
            sparse.update_frames_from_keyframes()
    settled = float(clock[0]) if adjusted and not hold_offset else None
    return MapGeorefResult(
        crs=f"EPSG:{epsg}",
        segments=results,
        time_offset_s=offset_s if settled is None else settled,
        seconds=time.perf_counter() - start,
        warnings=warnings,
        photos=table,
        adjusted_offset_s=settled,
    )


def _check_segments(
    sparse: SparseMap,
    results: list[dict[str, Any]],
    accuracy: np.ndarray,
    options: GeorefOptions,
    warnings: list[str],
) -> tuple[list[dict[str, Any]], int]:
    """Each video segment's residuals after the adjustment against the log's accuracy:
    `within_stated_accuracy` on its entry, a warning when it misses, and a broken segment
    (beyond `broken_segment_factor` times the bound) left out with the reason when
    another segment is not broken. Returns the entries kept and how many were left out."""
    bound, _ = accuracy_bounds(accuracy, options)
    broken = []
    for entry in results:
        after = entry.get("residuals_after_m") or {}
        if "rms_east" not in after:
            continue
        miss = check_stated_accuracy(after, accuracy, options)
        refinement = entry.get("refinement") or {}
        if refinement.get("kept") is False and miss is None:
            miss = refinement["reason"]
        entry["stated_sigma_m"] = [round(float(v), 4) for v in accuracy]
        entry["within_stated_accuracy"] = miss is None
        rms_h = float(np.hypot(after["rms_east"], after["rms_north"]))
        if rms_h > options.broken_segment_factor * bound:
            broken.append((entry, rms_h))
        elif miss:
            warnings.append(f"segment {entry['segment']}: {miss}")
    if not broken or len(broken) == len(results):
        for entry, rms_h in broken:
            warnings.append(
                f"segment {entry['segment']}: the georeference misses the log's accuracy "
                f"by far ({rms_h:.2f} m RMS horizontally where {bound:.2f} m is allowed), "
                "and no other part of the flight does better: the result is unreliable"
            )
        return results, 0
    for entry, rms_h in broken:
        warnings.append(
            f"segment {entry['segment']} left out: after the georeference its cameras are "
            f"{rms_h:.2f} m RMS horizontally from the log's positions, more than "
            f"{options.broken_segment_factor:.0f} times the {bound:.2f} m the log's accuracy "
            "allows (the reconstruction broke there, e.g. after tracking was lost)"
        )
        _drop_segment(sparse, entry["segment"])
    left_out = {id(entry) for entry, _ in broken}
    return [e for e in results if id(e) not in left_out], len(broken)


def _outlier_times(
    fit: GeorefResult, times: np.ndarray, photos: dict[float, str] | None
) -> np.ndarray:
    """Camera times of the photos the fit called outliers."""
    if photos is None or not fit.outliers:
        return np.zeros(0)
    bad = {p["name"] for p in fit.outliers}
    names = photo_names_at(times, photos)
    return np.array([t for t, n in zip(times.tolist(), names, strict=True) if n in bad])


def _photo_rows(
    sparse: SparseMap,
    segment: int,
    log: FlightLog,
    offset_s: float,
    epsg: int,
    photos: dict[float, str],
    excluded: np.ndarray,
    drift: GnssDrift | None,
) -> list[dict[str, Any]]:
    """Each photo's camera centre in the georeferenced map minus its GPS position (less
    the fitted GNSS drift)."""
    kf_idx, world = _keyframe_priors(sparse, segment, log, offset_s, epsg, drift)
    times = sparse.kf_t[kf_idx]
    rows = photo_table(
        photo_names_at(times, photos),
        sparse.kf_centres()[kf_idx] - world,
        ~np.isin(times, excluded),
        None,
    )
    return [{**row, "segment": segment} for row in rows]


def _keyframe_priors(
    sparse: SparseMap,
    segment: int,
    log: FlightLog,
    offset_s: float,
    epsg: int,
    drift: GnssDrift | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(keyframe indices with a GNSS position, positions in UTM), less the GNSS drift the
    fit estimated: the adjustment must not bend the map along it."""
    idx = np.flatnonzero(sparse.kf_segment == segment)
    values = log.interpolate(sparse.kf_t[idx] + offset_s)
    alt = values["alt"]
    ok = np.isfinite(values["lat"]) & np.isfinite(values["lon"]) & np.isfinite(alt)
    world = log_to_utm(values["lon"][ok], values["lat"][ok], alt[ok], epsg)
    if drift is not None:
        world = world - drift.at(sparse.kf_t[idx[ok]])
    return idx[ok], world


def _refine_segment(
    sparse: SparseMap,
    segment: int,
    log: FlightLog,
    offset_s: float,
    fit: GeorefResult,
    options: MapGeorefOptions,
    excluded: np.ndarray,
) -> dict[str, Any]:
    epsg = int(fit.crs.split(":")[1])
    kf_idx, world = _keyframe_priors(sparse, segment, log, offset_s, epsg, fit.gnss_drift)
    keep = ~np.isin(sparse.kf_t[kf_idx], excluded)
    kf_idx, world = kf_idx[keep], world[keep]
    if len(kf_idx) < 4:
        return {"skipped": "fewer than 4 keyframes with a GNSS position"}
    # The similarity the priors would add is undone below.
    sig = _residual_spread(sparse.kf_centres()[kf_idx] - world, options)
    origin = world.mean(axis=0)
    # Work around the origin: UTM coordinates are too large for a well-scaled problem.
    sparse.transform(1.0, np.eye(3), -origin, segment)
    seg_kf = np.flatnonzero(sparse.kf_segment == segment)
    pt_sel = sparse.point_segment == segment
    obs_sel = np.isin(sparse.obs_kf, seg_kf)
    observations = {}
    for k in seg_kf.tolist():
        m = obs_sel & (sparse.obs_kf == k)
        observations[k] = (sparse.obs_point[m], sparse.obs_uv[m].astype(np.float64))
    problem = BAProblem(
        poses={k: (sparse.kf_r[k], sparse.kf_tr[k]) for k in seg_kf.tolist()},
        observations=observations,
        points={
            int(p): x
            for p, x in zip(sparse.point_id[pt_sel], sparse.point_xyz[pt_sel], strict=True)
        },
        priors={int(k): (w - origin, sig) for k, w in zip(kf_idx.tolist(), world, strict=True)},
    )
    # COLMAP's alignment to the priors draws random samples and Ceres sums in thread
    # order: seeded and on one thread, the same survey gives the same DSM every time
    # (otherwise cells moved by up to 8 mm between runs).
    pycolmap.set_random_seed(0)
    poses, points, report = bundle_adjust(
        problem,
        sparse.k,
        sparse.size,
        max_iterations=options.refine_iterations,
        threads=1,
    )
    if report.priors_used:
        depth = _viewing_distance(sparse, seg_kf, pt_sel)
        before = _centres_and_views(sparse, seg_kf, depth)
        for k, (r, t) in poses.items():
            sparse.kf_r[k], sparse.kf_tr[k] = r, t
        index = {int(p): i for i, p in enumerate(sparse.point_id)}
        for p, x in points.items():
            sparse.point_xyz[index[p]] = x
        # The priors also move the whole segment (a similarity the reprojection errors
        # cannot see): undo that part so the attitude-aided fit keeps its rotation, and
        # keep only the bending that corrects drift. The centres alone cannot show it on
        # a straight line (a roll about the line: 8.5 deg, 1.6 m of DSM NMAD on one
        # 8-s line over the mounds), so the points each camera looks at count too.
        back = umeyama(_centres_and_views(sparse, seg_kf, depth), before)
        sparse.transform(back.scale, back.rotation, back.translation, segment)
    sparse.transform(1.0, np.eye(3), origin, segment)
    out = report.to_dict()
    out["prior_sigma_m"] = [round(float(v), 4) for v in sig]
    if not report.priors_used:
        out["skipped"] = "COLMAP could not align the segment to the priors (straight track?)"
    return out


def _spread_sigma(
    sparse: SparseMap,
    segment: int,
    log: FlightLog,
    offset_s: float,
    epsg: int,
    fit: GeorefResult,
    options: MapGeorefOptions,
) -> np.ndarray:
    """Prior sigmas (east, north, up) for positions that state none, from the keyframes'
    residuals after the fit, less its GNSS drift (`_residual_spread`)."""
    kf_idx, world = _keyframe_priors(sparse, segment, log, offset_s, epsg, fit.gnss_drift)
    return _residual_spread(sparse.kf_centres()[kf_idx] - world, options)


def _residual_spread(residuals: np.ndarray, options: MapGeorefOptions) -> np.ndarray:
    """The robust spread (NMAD) of residuals (N, 3) as prior sigmas, at least
    `min_prior_sigma_m` (or `prior_sigma_m` where given): not inflated for correlation
    as in the fit, so that the priors are strong enough to pull out the
    reconstruction's drift."""
    if options.prior_sigma_m is not None:
        return np.asarray(options.prior_sigma_m, dtype=float)
    d = residuals
    nmad = 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    h = max(float(np.hypot(nmad[0], nmad[1]) / np.sqrt(2)), options.min_prior_sigma_m)
    return np.array([h, h, max(float(nmad[2]), h)])


def _viewing_distance(sparse: SparseMap, seg_kf: np.ndarray, pt_sel: np.ndarray) -> float:
    """The segment's typical camera height above its points (at least 1 m): how far
    along its optical axis each camera's viewed point is put."""
    if not pt_sel.any():
        return 1.0
    centres = sparse.kf_centres()[seg_kf]
    height = float(np.median(centres[:, 2]) - np.median(sparse.point_xyz[pt_sel, 2]))
    return max(height, 1.0)


def _centres_and_views(sparse: SparseMap, keyframes: np.ndarray, depth: float) -> np.ndarray:
    """The keyframes' centres, then the points `depth` along their optical axes: a rigid
    motion of the segment moves both, a roll about a straight track moves the views."""
    centres = sparse.kf_centres()[keyframes]
    axes = sparse.kf_r[keyframes, 2, :]  # the camera z axis in world: row 2 of R_cw
    return np.concatenate([centres, centres + depth * axes])


def _apply_matrix(sparse: SparseMap, segment: int, fit: GeorefResult) -> None:
    """paper4: a general 4 x 4; poses follow by their centres (rotation from the
    matrix's nearest rotation), points are mapped directly."""
    m = fit.matrix
    a, b = m[:3, :3], m[:3, 3]
    u, svals, vt = np.linalg.svd(a)
    rot = u @ vt
    if np.linalg.det(rot) < 0:
        u[:, -1] *= -1
        rot = u @ vt
    scale = float(np.mean(svals))
    kf = sparse.kf_segment == segment
    centres = sparse.kf_centres()[kf]
    sparse.transform(scale, rot, np.zeros(3), segment)
    new_c = centres @ a.T + b
    sparse.kf_tr[kf] = -np.einsum("nij,nj->ni", sparse.kf_r[kf], new_c)
    pts = sparse.point_segment == segment
    # transform() already applied s R to the points; redo them with the true matrix.
    sparse.point_xyz[pts] = (sparse.point_xyz[pts] @ rot / scale) @ a.T + b


def _residuals(
    sparse: SparseMap,
    segment: int,
    log: FlightLog,
    offset_s: float,
    epsg: int,
    excluded: np.ndarray,
    drift: GnssDrift | None = None,
) -> dict[str, float]:
    """Residual statistics over the keyframes, outlier photos left out (after the fitted
    GNSS drift)."""
    kf_idx, world = _keyframe_priors(sparse, segment, log, offset_s, epsg, drift)
    keep = ~np.isin(sparse.kf_t[kf_idx], excluded)
    kf_idx, world = kf_idx[keep], world[keep]
    if len(kf_idx) == 0:
        return {}
    stats = residual_stats(sparse.kf_centres()[kf_idx], world)
    return {k: round(v, 4) for k, v in stats.items()}


def _drop_segment(sparse: SparseMap, segment: int) -> None:
    """Remove a segment's keyframes, points and frames from the map."""
    keep_kf = sparse.kf_segment != segment
    new_index = np.cumsum(keep_kf) - 1
    for name in ("kf_id", "kf_segment", "kf_t", "kf_r", "kf_tr"):
        setattr(sparse, name, getattr(sparse, name)[keep_kf])
    sparse.kf_id = np.arange(keep_kf.sum(), dtype=np.int32)
    obs = keep_kf[sparse.obs_kf]
    sparse.obs_point, sparse.obs_uv = sparse.obs_point[obs], sparse.obs_uv[obs]
    sparse.obs_kf = new_index[sparse.obs_kf[obs]].astype(np.int32)
    pts = sparse.point_segment != segment
    sparse.point_id = sparse.point_id[pts]
    sparse.point_xyz = sparse.point_xyz[pts]
    sparse.point_segment = sparse.point_segment[pts]
    fr = sparse.fr_segment != segment
    for name in ("fr_t", "fr_segment", "fr_r", "fr_tr", "fr_is_kf", "fr_rel_r", "fr_rel_t"):
        setattr(sparse, name, getattr(sparse, name)[fr])
    ref = sparse.fr_ref_kf[fr]
    sparse.fr_ref_kf = np.where(ref >= 0, new_index[np.maximum(ref, 0)], -1).astype(np.int32)
    dense = keep_kf[sparse.dense_kf] & keep_kf[sparse.dense_partner]
    sparse.dense_xyz = sparse.dense_xyz[dense]
    sparse.dense_baseline = sparse.dense_baseline[dense]
    sparse.dense_kf = new_index[sparse.dense_kf[dense]].astype(np.int32)
    sparse.dense_partner = new_index[sparse.dense_partner[dense]].astype(np.int32)
