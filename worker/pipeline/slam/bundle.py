"""Bundle adjustment through pycolmap (Ceres): windowed with fixed keyframes, or with
GNSS position priors on the camera centres.

Problems are given as plain arrays; a small pycolmap `Reconstruction` is built for each
call (about 30 ms for 15 keyframes and 1.5k points) and read back. Intrinsics are fixed
(known from the camera table; freeing them moved the focal length by 16 % in the
notes' tests).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pycolmap

pycolmap.logging.minloglevel = 2


@dataclass
class BAProblem:
    poses: dict[int, tuple[np.ndarray, np.ndarray]]  # keyframe id -> (R_cw, t_cw)
    observations: dict[int, tuple[np.ndarray, np.ndarray]]  # kf id -> (point ids, uv)
    points: dict[int, np.ndarray]  # point id -> xyz
    fixed: set[int] = field(default_factory=set)
    # kf id -> (camera centre prior (3,), sigmas (3,)); with priors no pose is fixed.
    priors: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


@dataclass
class BAReport:
    keyframes: int
    points: int
    observations: int
    initial_cost: float
    final_cost: float
    iterations: int
    seconds: float
    priors_used: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {k: (round(v, 5) if isinstance(v, float) else v) for k, v in vars(self).items()}


def bundle_adjust(
    problem: BAProblem,
    k: np.ndarray,
    size: tuple[int, int],
    loss_px: float = 2.0,
    max_iterations: int = 10,
    threads: int = 2,
    min_track_length: int = 2,
    prior_loss_scale: float = 10.0,
) -> tuple[dict[int, tuple[np.ndarray, np.ndarray]], dict[int, np.ndarray], BAReport]:
    """Refine poses (except `fixed`) and points; returns updated copies and a report.

    With `problem.priors`, COLMAP first aligns the reconstruction to the priors by a
    robust similarity (which fails on a straight track: then no prior is used and the
    report says so through `priors_used`) and adds one covariance-weighted residual per
    camera centre."""
    start = time.perf_counter()
    rec = pycolmap.Reconstruction()
    camera = pycolmap.Camera.create_from_model_name(1, "PINHOLE", float(k[0, 0]), *size)
    camera.params = [float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2])]
    rec.add_camera_with_trivial_rig(camera)
    kf_list = sorted(problem.poses)
    image_of = {kf: i + 1 for i, kf in enumerate(kf_list)}
    # Which observations belong to points that are in the problem, grouped by point with
    # one sort (a TrackElement per observation gathered in a dict of lists took about a
    # third of the time of a windowed BA).
    point_ids = np.fromiter(problem.points.keys(), dtype=np.int64, count=len(problem.points))
    obs_pid, obs_img, obs_idx = [], [], []
    for kf in kf_list:
        ids, uv = problem.observations.get(kf, (np.empty(0, np.int64), np.empty((0, 2))))
        ids = np.asarray(ids, dtype=np.int64)
        sel = np.isin(ids, point_ids)
        uv = np.asarray(uv, dtype=np.float64)[sel]
        image = pycolmap.Image(name=str(kf), keypoints=uv, camera_id=1, image_id=image_of[kf])
        r, t = problem.poses[kf]
        rec.add_image_with_trivial_frame(
            image, pycolmap.Rigid3d(pycolmap.Rotation3d(np.asarray(r)), np.asarray(t))
        )
        obs_pid.append(ids[sel])
        obs_img.append(np.full(len(uv), image_of[kf], np.int64))
        obs_idx.append(np.arange(len(uv), dtype=np.int64))
    pid = np.concatenate(obs_pid) if obs_pid else np.empty(0, np.int64)
    order = np.argsort(pid, kind="stable")  # stable: each track in keyframe order
    pid = pid[order]
    img = np.concatenate(obs_img)[order].tolist() if obs_pid else []
    idx = np.concatenate(obs_idx)[order].tolist() if obs_pid else []
    track_pid, first, length = np.unique(pid, return_index=True, return_counts=True)
    colmap_of: dict[int, int] = {}
    n_obs = 0
    for p, a, n in zip(track_pid.tolist(), first.tolist(), length.tolist(), strict=True):
        if n < min_track_length:
            continue
        track = pycolmap.Track()
        for j in range(a, a + n):
            track.add_element(img[j], idx[j])
        colmap_of[p] = rec.add_point3D(np.asarray(problem.points[p], dtype=np.float64), track)
        n_obs += n
    config = pycolmap.BundleAdjustmentConfig()
    for kf in kf_list:
        config.add_image(image_of[kf])
    config.set_constant_cam_intrinsics(1)
    if not problem.priors:
        for kf in problem.fixed:
            if kf in image_of:
                config.set_constant_rig_from_world_pose(rec.image(image_of[kf]).frame_id)
    options = pycolmap.BundleAdjustmentOptions()
    options.refine_focal_length = False
    options.refine_principal_point = False
    options.refine_extra_params = False
    options.print_summary = False
    options.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    options.ceres.loss_function_scale = loss_px
    options.ceres.solver_options.max_num_iterations = max_iterations
    options.ceres.solver_options.num_threads = threads
    if problem.priors:
        priors = []
        for kf, (centre, sigma) in problem.priors.items():
            if kf not in image_of:
                continue
            prior = pycolmap.PosePrior()
            prior.corr_data_id = rec.image(image_of[kf]).data_id
            prior.position = np.asarray(centre, dtype=np.float64)
            prior.position_covariance = np.diag(np.asarray(sigma, dtype=np.float64) ** 2)
            prior.coordinate_system = pycolmap.PosePriorCoordinateSystem.CARTESIAN
            priors.append(prior)
        prior_options = pycolmap.PosePriorBundleAdjustmentOptions()
        prior_options.ceres.prior_position_loss_function_type = pycolmap.LossFunctionType.CAUCHY
        prior_options.ceres.prior_position_loss_scale = prior_loss_scale
        before = np.array([rec.image(image_of[kf]).projection_center() for kf in kf_list])
        adjuster = pycolmap.create_pose_prior_bundle_adjuster(
            options, prior_options, config, priors, rec
        )
        after = np.array([rec.image(image_of[kf]).projection_center() for kf in kf_list])
        # COLMAP moves the reconstruction onto the priors only when its alignment works.
        priors_used = len(priors) if not np.allclose(before, after) else 0
    else:
        priors_used = 0
        adjuster = pycolmap.create_default_bundle_adjuster(options, config, rec)
    summary = adjuster.solve()
    solver = getattr(summary, "ceres_summary", None)
    poses = {}
    for kf in kf_list:
        pose = rec.image(image_of[kf]).cam_from_world()
        poses[kf] = (np.array(pose.rotation.matrix()), np.array(pose.translation))
    points3d = rec.points3D
    points = {p: np.array(points3d[cid].xyz) for p, cid in colmap_of.items()}
    report = BAReport(
        keyframes=len(kf_list),
        points=len(colmap_of),
        observations=n_obs,
        initial_cost=float(getattr(solver, "initial_cost", np.nan)),
        final_cost=float(getattr(solver, "final_cost", np.nan)),
        iterations=int(
            getattr(solver, "num_successful_steps", 0)
            + getattr(solver, "num_unsuccessful_steps", 0)
        ),
        seconds=time.perf_counter() - start,
        priors_used=priors_used,
    )
    return poses, points, report
