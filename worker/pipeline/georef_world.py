"""The world-frame adjustment of one georeferenced video segment against its log.

The similarity fit is not the end: the map's own drift (monocular scale drift, a bent
line) is what remains, and the positions can remove it. `adjust_segment` runs
`world_bundle_adjust` on the segment's keyframes and points in UTM with a prior on every
keyframe's centre (at the log's stated sigmas, RTK; else at the spread of the fit's
residuals, the fitted GNSS drift removed from the positions), on its rotation from the
logged camera attitude (less one bias of the log's over the segment, found with it), and
on the offset between the video's clock and the log's (its standard error reported, for
the segments placed after this one: georef_map), then
writes the adjusted poses and points back (dense points follow their keyframes'
depths). Nothing of the adjustment is undone: the positions and the attitude fix every
degree of freedom, the roll of a straight line included (which positions alone cannot:
a straight segment without a logged attitude is not adjusted), and the attitude keeps a
stand-alone GPS's height drift from tilting a small site.

Where the adjusted centres still miss the log by far (a map bent by its tracking, out
of a local adjustment's reach from the similarity fit), the adjustment starts again from
the log's own poses and keeps the lower cost (`restart_from_log_sigmas`).

Measured on a 12-s RTK line over the hillslope at 144 m (seed 20 of the many-flight
benchmark): the offset went from 69.096 s (the trajectory fit, misled by the map's
drift) to 69.007 s (the truth 68.998 s), the camera centres to 5 cm of their log.
docs/reconstruction.md gives the many-flight figures, RTK and stand-alone.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from worker.pipeline.attitude import camera_attitude_at
from worker.pipeline.georef import GnssDrift, log_to_utm
from worker.pipeline.ingest.flight_log import FlightLog
from worker.pipeline.slam.result import SparseMap
from worker.pipeline.slam.world_bundle import WorldBAProblem, WorldBAResult, world_bundle_adjust


@dataclass
class WorldAdjustOptions:
    # The logged camera attitude keyframe to keyframe, its bias taken out (world_bundle):
    # an IMU-levelled gimbal's tilt, logged to 0.1 deg at 10 Hz and read between
    # samples; the compass's heading.
    tilt_sigma_deg: float = 0.3
    heading_sigma_deg: float = 2.0
    # The bias of the whole segment's logged attitude: the level's error and a camera
    # mounted askew (tenths of a degree), the compass's (degrees).
    tilt_bias_sigma_deg: float = 0.5
    heading_bias_sigma_deg: float = 5.0
    # Without stated accuracy (stand-alone GPS) the positions' metres cannot tell a bias
    # of the logged attitude from a tilt or turn of the site, so the log's attitude is
    # taken as it is, keyframe by keyframe at these sigmas, and no bias is sought (with a
    # heading bias sought, two of twelve mounds flights' DSMs turned: 0.61 -> 0.95 and
    # 0.89 -> 1.18 px after shift and tilt). Nor is the tilt held as tightly: the offset
    # is settled to tens of milliseconds there, and in the turns and climbs of the
    # paper's 3-D path the log read that far off turned two of five flights' maps at 0.3
    # deg (seeds 101 and 123: their cameras 0.17 -> 0.54 and 0.16 -> 0.46 m RMS off
    # their track's shape).
    standalone_tilt_sigma_deg: float = 1.0
    standalone_heading_sigma_deg: float = 5.0
    # The offset's prior around the estimate in use: loose, the data decides where the
    # flight's speed changes (measured: the same offset with 0.1, 0.3 and 1 s). Segments
    # after the first take the offset the ones before settled, at its standard error
    # (georef_map): one clock for the whole recording.
    offset_sigma_s: float = 0.5
    # The least standard error a settled offset is taken at for the segments after it:
    # a sixth of a frame at 30 fps (a formal error below it trusts the log's interpolation
    # between samples too far).
    min_offset_sigma_s: float = 0.005
    max_iterations: int = 15
    # The adjusted map must still fit its images: a reprojection RMS above both this
    # and twice the one before means the positions and the map disagree (a broken
    # segment), reported and not kept.
    max_reprojection_rms_px: float = 2.0
    # The log's velocity (the offset's derivative) by a central difference this far
    # either side: at 0.05 s, between two 10-Hz fixes, RTK's 2 cm made it 0.3 m/s of
    # noise, which stalled the offset where it began and claimed it to 20 ms where it was
    # 150 ms off (a 7-keyframe line accelerating at 0.4 m/s^2; at 0.25 s: within 50 ms,
    # its stated error 55-90 ms).
    velocity_step_s: float = 0.25
    # Observations in the problem at most (about 0.25 s per iteration at 60 000 on two
    # cores): a long flight's points beyond it, drawn at random (seeded), ride with the
    # keyframe that first saw them.
    max_observations: int = 60_000
    # Where the adjusted centres still miss their log by more than this many stated
    # sigmas and the log has the camera's attitude, the adjustment starts again from
    # the log's poses (the map's points triangulated again on them) and the lower cost
    # is kept: a map bent or tilted by its tracking (22 deg over a 4-line lawnmower at
    # 7 m, issue 18's flight seed 3) is beyond the reach of a local adjustment from the
    # similarity fit. None: never.
    restart_from_log_sigmas: float | None = 10.0


def adjust_segment(
    sparse: SparseMap,
    segment: int,
    log: FlightLog,
    offset_s: float,
    epsg: int,
    sigma_m: np.ndarray,
    options: WorldAdjustOptions,
    offset_sigma_s: float | None = None,
    straight: bool = False,
    drift: GnssDrift | None = None,
    stated_accuracy: bool = True,
) -> dict[str, Any]:
    """Adjust one segment of `sparse` (in place, in UTM) against the log; returns the
    report kept in georeference.json (with `offset_s`, the offset the segment uses, and
    `offset_sigma_s`, its standard error). `offset_sigma_s`: the prior's sigma about
    `offset_s` (None: the offset is held).
    `stated_accuracy`: the log states its positions' accuracy (RTK): the frames between
    keyframes are put on its positions (better there than the tracking between
    keyframes), and the bias of its tilt is sought (see WorldAdjustOptions)."""
    kf = np.flatnonzero(sparse.kf_segment == segment)
    times = sparse.kf_t[kf]
    attitude, source = camera_attitude_at(log, times + offset_s)
    if attitude is not None and not np.isfinite(attitude).all():
        attitude = None
    if attitude is None and straight:
        return {
            "skipped": "a near-straight track and no logged camera attitude: nothing holds "
            "its roll",
            "offset_s": offset_s,
        }
    pt_sel, obs = _points_in_problem(sparse, kf, segment, options.max_observations)
    index = np.full(int(sparse.point_id.max(initial=0)) + 1, -1, np.int64)
    index[sparse.point_id[pt_sel]] = np.arange(pt_sel.size)
    kf_index = np.full(len(sparse.kf_t), -1, np.int64)
    kf_index[kf] = np.arange(kf.size)
    step = options.velocity_step_s

    span = log.t[log.valid]
    first, last = (float(span.min()), float(span.max())) if span.size else (0.0, 0.0)

    def positions_at(offset: float) -> tuple[np.ndarray, np.ndarray]:
        def at(t: np.ndarray) -> np.ndarray:
            values = log.interpolate(t)
            world = log_to_utm(values["lon"], values["lat"], values["alt"], epsg)
            return world if drift is None else world - drift.at(times)

        # The velocity by a central difference, one-sided at the ends of the log (a
        # keyframe at its last sample has no position a step later).
        t = times + offset
        before, after = np.clip(t - step, first, last), np.clip(t + step, first, last)
        with np.errstate(invalid="ignore", divide="ignore"):
            velocity = (at(after) - at(before)) / (after - before)[:, None]
        return at(t), velocity

    problem = WorldBAProblem(
        k=sparse.k,
        r_cw=sparse.kf_r[kf].copy(),
        centres=sparse.kf_centres()[kf],
        points=sparse.point_xyz[pt_sel].copy(),
        obs_kf=kf_index[sparse.obs_kf[obs]],
        obs_point=index[sparse.obs_point[obs]],
        obs_uv=sparse.obs_uv[obs].astype(np.float64),
        positions_at=positions_at,
        position_sigma_m=np.asarray(sigma_m, dtype=np.float64),
        offset_s=offset_s,
        offset_prior_s=offset_s,
        offset_sigma_s=offset_sigma_s,
        attitude_r_wc=attitude,
        **_attitude_sigmas(options, stated_accuracy),
    )
    # Work about the segment's centre: UTM coordinates are too large for a well-scaled
    # problem.
    origin = problem.centres.mean(axis=0)
    problem.centres = problem.centres - origin
    problem.points = problem.points - origin

    def about_origin(offset: float) -> tuple[np.ndarray, np.ndarray]:
        world, velocity = positions_at(offset)
        return world - origin, velocity

    problem.positions_at = about_origin
    result = world_bundle_adjust(problem, max_iterations=options.max_iterations)
    restarted = None
    limit = options.restart_from_log_sigmas
    if (
        attitude is not None
        and limit is not None
        and result.report["position_rms_m_after"] > limit * float(np.max(sigma_m))
    ):
        restarted = _restart_from_log(sparse, kf, pt_sel, problem, attitude, origin, options)
        if (
            restarted is not None
            and restarted[1].report["final_cost"] < result.report["final_cost"]
        ):
            problem, result = restarted
    report = dict(result.report)
    if restarted is not None:
        report["restarted_from_log"] = {
            "kept": result is restarted[1],
            "final_cost": restarted[1].report["final_cost"],
        }
    report["attitude_source"] = str(source) if attitude is not None else "none"
    if not report["final_cost"] < report["initial_cost"]:
        report["kept"] = False
        report["reason"] = "no step of the adjustment lowered its cost: the segment keeps its fit"
        report["offset_s"], report["offset_sigma_s"] = offset_s, None
        return report
    before = report["reprojection_rms_px_before"]
    after = report["reprojection_rms_px_after"]
    if not after <= max(options.max_reprojection_rms_px, 2 * before):
        report["kept"] = False
        report["reason"] = (
            f"the adjusted map no longer fits its images ({after:.2f} px RMS against "
            f"{before:.2f} px before): the positions and the reconstruction disagree"
        )
        report["offset_s"], report["offset_sigma_s"] = offset_s, None
        return report
    others = _hosted_points(sparse, segment, pt_sel)
    r_before, c_before = sparse.kf_r.copy(), sparse.kf_centres()
    sparse.kf_r[kf] = result.r_cw
    centres = result.centres + origin
    sparse.kf_tr[kf] = -np.einsum("nij,nj->ni", result.r_cw, centres)
    points_before = sparse.point_xyz[pt_sel].copy()
    sparse.point_xyz[pt_sel] = result.points + origin
    report["dense_depth_scale"] = _dense_follow_depth(
        sparse, kf, problem, pt_sel, points_before, r_before, c_before
    )
    # Points left out of the problem are triangulated again from their observations on
    # the adjusted cameras; where their rays are too near parallel for that, they ride
    # with the keyframe that first saw them.
    if others[0].size:
        pts, host = others
        moved = _triangulate(sparse, pts)
        ride = ~np.isfinite(moved).all(axis=1)
        hr = host[ride]
        local = np.einsum("nij,nj->ni", r_before[hr], sparse.point_xyz[pts[ride]] - c_before[hr])
        moved[ride] = np.einsum("nji,nj->ni", sparse.kf_r[hr], local) + sparse.kf_centres()[hr]
        sparse.point_xyz[pts] = moved
        report["points_triangulated_again"] = int((~ride).sum())
    report["points_outside_the_problem"] = int(others[0].size)
    if stated_accuracy:
        report["frames_on_log"] = _frames_on_log(sparse, segment, log, result.offset_s, epsg, drift)
    report["kept"] = True
    return report


def _attitude_sigmas(options: WorldAdjustOptions, stated_accuracy: bool) -> dict[str, float]:
    """The attitude priors' sigmas for WorldBAProblem: with stated accuracy, keyframe to
    keyframe and the bias; without, keyframe by keyframe and no bias."""
    if stated_accuracy:
        return {
            "tilt_sigma_deg": options.tilt_sigma_deg,
            "heading_sigma_deg": options.heading_sigma_deg,
            "tilt_bias_sigma_deg": options.tilt_bias_sigma_deg,
            "heading_bias_sigma_deg": options.heading_bias_sigma_deg,
        }
    return {
        "tilt_sigma_deg": options.standalone_tilt_sigma_deg,
        "heading_sigma_deg": options.standalone_heading_sigma_deg,
        "tilt_bias_sigma_deg": 0.0,
        "heading_bias_sigma_deg": 0.0,
    }


def _restart_from_log(
    sparse: SparseMap,
    kf: np.ndarray,
    pt_sel: np.ndarray,
    problem: WorldBAProblem,
    attitude: np.ndarray,
    origin: np.ndarray,
    options: WorldAdjustOptions,
) -> tuple[WorldBAProblem, WorldBAResult] | None:
    """The adjustment started from the log's poses instead of the similarity fit: the
    keyframes at their logged positions and camera attitudes, the points triangulated
    again on them (those whose rays are too near parallel keep their place). None
    where too few points could be triangulated."""
    world, _ = problem.positions_at(problem.offset_s)
    if not np.isfinite(world).all():
        return None
    r_cw = np.transpose(attitude, (0, 2, 1)).copy()
    kept_r, kept_tr = sparse.kf_r[kf].copy(), sparse.kf_tr[kf].copy()
    sparse.kf_r[kf] = r_cw
    sparse.kf_tr[kf] = -np.einsum("nij,nj->ni", r_cw, world + origin)
    try:
        points = _triangulate(sparse, pt_sel) - origin
    finally:
        sparse.kf_r[kf], sparse.kf_tr[kf] = kept_r, kept_tr
    fresh = np.isfinite(points).all(axis=1)
    if fresh.sum() < max(0.5 * fresh.size, 50):
        return None
    points[~fresh] = problem.points[~fresh]
    again = replace(problem, r_cw=r_cw, centres=world.copy(), points=points)
    return again, world_bundle_adjust(again, max_iterations=options.max_iterations)


def _dense_follow_depth(
    sparse: SparseMap,
    kf: np.ndarray,
    problem: WorldBAProblem,
    pt_sel: np.ndarray,
    points_before: np.ndarray,
    r_before: np.ndarray,
    c_before: np.ndarray,
) -> list[float]:
    """Scale each keyframe's dense points by how the adjustment scaled the depths of the
    sparse points that keyframe sees (their median ratio), not by its pair's new
    baseline: the dense depths were measured in the map's own local scale, and a pair's
    baseline moves with the positions' centimetres (on 1-m baselines over the mounds,
    dense NMAD 0.21 -> 0.31 m by the baselines, 0.21 m by the depths; over the
    hillslope, where the map's scale drifted 2.6 %, 5.7 -> 4.3 m either way). Returns
    the scales' 10th, 50th and 90th percentiles."""
    obs_kf = kf[problem.obs_kf]
    after_c = sparse.kf_centres()
    depth_before = np.einsum(
        "nj,nj->n", r_before[obs_kf, 2], points_before[problem.obs_point] - c_before[obs_kf]
    )
    depth_after = np.einsum(
        "nj,nj->n",
        sparse.kf_r[obs_kf, 2],
        sparse.point_xyz[pt_sel[problem.obs_point]] - after_c[obs_kf],
    )
    ok = (depth_before > 0) & (depth_after > 0)
    ratio = np.ones(len(sparse.kf_t))
    # Each keyframe's median ratio, by one sort rather than a mask per keyframe.
    owner, values = obs_kf[ok], depth_after[ok] / depth_before[ok]
    order = np.lexsort((values, owner))
    owner, values = owner[order], values[order]
    keys, start, count = np.unique(owner, return_index=True, return_counts=True)
    enough = count >= 10
    lower = values[start + (count - 1) // 2]
    upper = values[start + count // 2]
    ratio[keys[enough]] = (0.5 * (lower + upper))[enough]
    if sparse.dense_kf.size:
        # Dense points lie in runs of one pair: one factor per run (millions of points).
        pair_kf, pair_partner = sparse.dense_kf, sparse.dense_partner
        changes = (pair_kf[1:] != pair_kf[:-1]) | (pair_partner[1:] != pair_partner[:-1])
        edges = np.flatnonzero(np.concatenate([[True], changes]))
        a, b = pair_kf[edges], pair_partner[edges]
        baseline_before = np.linalg.norm(c_before[a] - c_before[b], axis=1)
        baseline_after = np.linalg.norm(after_c[a] - after_c[b], axis=1)
        # dense_points scales by (baseline now / baseline then): keep its old scale
        # times the keyframe's depth ratio.
        factor = np.where(
            np.isin(a, kf), baseline_after / np.maximum(baseline_before, 1e-12) / ratio[a], 1.0
        )
        sparse.dense_baseline *= np.repeat(factor, np.diff(np.append(edges, pair_kf.size)))
    return [round(float(v), 5) for v in np.percentile(ratio[kf], [10, 50, 90])]


def _points_in_problem(
    sparse: SparseMap, kf: np.ndarray, segment: int, max_observations: int
) -> tuple[np.ndarray, np.ndarray]:
    """(indices of the segment's points in the problem, indices of their observations)."""
    pt_sel = np.flatnonzero(sparse.point_segment == segment)
    in_segment = np.isin(sparse.obs_point, sparse.point_id[pt_sel])
    obs = np.flatnonzero(np.isin(sparse.obs_kf, kf) & in_segment)
    if obs.size > max_observations:
        rng = np.random.default_rng(0)
        keep = rng.random(pt_sel.size) < max_observations / obs.size
        pt_sel = pt_sel[keep]
        obs = obs[np.isin(sparse.obs_point[obs], sparse.point_id[pt_sel])]
    return pt_sel, obs


def _hosted_points(
    sparse: SparseMap, segment: int, in_problem: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(indices of the segment's points not in the problem, the keyframe that first saw
    each: its oldest observation)."""
    rest = np.setdiff1d(np.flatnonzero(sparse.point_segment == segment), in_problem)
    if rest.size == 0:
        return rest, rest
    order = np.lexsort((sparse.obs_kf, sparse.obs_point))
    ids, first = np.unique(sparse.obs_point[order], return_index=True)
    host_of = dict(zip(ids.tolist(), sparse.obs_kf[order][first].tolist(), strict=True))
    hosts = np.array([host_of.get(int(p), -1) for p in sparse.point_id[rest]], dtype=np.int64)
    seen = hosts >= 0
    return rest[seen], hosts[seen]


def _triangulate(sparse: SparseMap, pts: np.ndarray, min_angle_deg: float = 1.0) -> np.ndarray:
    """Midpoint triangulation of points (indices) from all their observations on the
    current poses: the X nearest all their rays in the least-squares sense. NaN rows
    where the rays span less than about `min_angle_deg` (depth undetermined)."""
    ids = sparse.point_id[pts]
    order = np.argsort(ids)
    obs = np.flatnonzero(np.isin(sparse.obs_point, ids))
    row = order[np.searchsorted(ids[order], sparse.obs_point[obs])]
    kf = sparse.obs_kf[obs]
    uv1 = np.column_stack([sparse.obs_uv[obs], np.ones(obs.size)])
    rays = np.einsum("nji,nj->ni", sparse.kf_r[kf], uv1 @ np.linalg.inv(sparse.k).T)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    proj = np.eye(3) - rays[:, :, None] * rays[:, None, :]  # (M, 3, 3)
    centres = sparse.kf_centres()[kf]
    n = pts.size
    a = np.zeros((n, 3, 3))
    b = np.zeros((n, 3))
    for i in range(3):
        b[:, i] = np.bincount(row, weights=np.einsum("nj,nj->n", proj[:, i], centres), minlength=n)
        for j in range(3):
            a[:, i, j] = np.bincount(row, weights=proj[:, i, j], minlength=n)
    out = np.full((n, 3), np.nan)
    # The smallest eigenvalue of the summed projectors grows as the rays' spread does.
    ok = np.linalg.eigvalsh(a)[:, 0] > np.sin(np.radians(min_angle_deg)) ** 2 / 2
    out[ok] = np.linalg.solve(a[ok], b[ok][:, :, None])[:, :, 0]
    return out


def _frames_on_log(
    sparse: SparseMap,
    segment: int,
    log: FlightLog,
    offset_s: float,
    epsg: int,
    drift: GnssDrift | None,
) -> int:
    """Put the segment's frames between keyframes at the log's positions (their
    rotations stay relative to their keyframe): tracked against the map in its own
    scale, a frame 16 m past its keyframe was 2.8 m off where the log is within 2 cm.
    Returns how many frames were placed."""
    sel = np.flatnonzero(
        (sparse.fr_segment == segment) & ~sparse.fr_is_kf.astype(bool) & (sparse.fr_ref_kf >= 0)
    )
    if sel.size == 0:
        return 0
    values = log.interpolate(sparse.fr_t[sel] + offset_s)
    world = log_to_utm(values["lon"], values["lat"], values["alt"], epsg)
    if drift is not None:
        world = world - drift.at(sparse.fr_t[sel])
    ok = np.isfinite(world).all(axis=1)
    sel, world = sel[ok], world[ok]
    ref = sparse.fr_ref_kf[sel]
    r = np.einsum("nij,njk->nik", sparse.fr_rel_r[sel], sparse.kf_r[ref])
    wanted_t = -np.einsum("nij,nj->ni", r, world)
    # update_frames_from_keyframes: t = rel_r t_ref + rel_t.
    moved = np.einsum("nij,nj->ni", sparse.fr_rel_r[sel], sparse.kf_tr[ref])
    sparse.fr_rel_t[sel] = wanted_t - moved
    return int(sel.size)
