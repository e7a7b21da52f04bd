"""The conventional reference: Structure-from-Motion with pycolmap and GNSS pose priors.

As the paper ran OpenDroneMap on frames taken at 3 fps at a higher resolution, this
method takes still frames (or an image set) and runs COLMAP's pipeline on 2 cores:

1. SIFT on the CPU (`first_octave=0`: no upsampling, ~9x faster than COLMAP's default
   on 640 px frames, and `max_features`), one pinhole camera with the known intrinsics
   (a simple pinhole, one focal length, when they are a guess);
2. GNSS positions as pose priors in the database (local metres around the survey's
   centre, sigmas `prior_sigma_h_m`/`prior_sigma_v_m`, or the position's own stated
   sigma where the log states one: RTK photos);
3. sequential matching (`sequential_overlap` neighbours) plus spatial matching by the
   priors (`spatial_neighbors`, the paper's "pre-matching neighbouring frames based on
   Exif data");
4. incremental mapping with the priors (`use_prior_position`, robust loss), the initial
   pair at >= `init_min_tri_angle` degrees (the default 16 fails on video frames), the
   focal length fixed (freeing it moved it by 16 % in the notes' tests), a guessed one
   too (`Intrinsics.focal_guess`: no camera identified), with a warning: focal length
   and the ground's depth trade off, and refining a right guess moved it by 15-21 %
   where the heights varied from 7 to 20 m and by up to 2.6 times at one height
   (`refine_guessed_focal` turns the refinement on; the refined camera is then used
   from then on);
5. dense points: OpenCV SGBM on pairs of registered images (`worker.pipeline.slam.densify`,
   at `dense_width` pixels), because COLMAP's patch-match stereo needs CUDA; each image
   pairs with up to two others chosen by how their ground footprints overlap its own
   (`_stereo_partners`: along its line and behind it, or on the next line).

The result is a `SparseMap` in UTM coordinates (one segment), like the SLAM's.
"""

from __future__ import annotations

import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pycolmap

from worker.pipeline.errors import InputError
from worker.pipeline.footprints import camera_footprints
from worker.pipeline.georef import log_to_utm, survey_epsg
from worker.pipeline.ingest.camera import Intrinsics
from worker.pipeline.ingest.flight_log import FlightLog
from worker.pipeline.progress import ProgressFn, no_progress
from worker.pipeline.slam.densify import DensifyOptions, densify_pair
from worker.pipeline.slam.result import SparseMap


@dataclass
class SfmOptions:
    fps: float = 3.0
    max_width: int = 2560
    max_features: int = 4000
    first_octave: int | None = None  # None: -1 (upsample) below 1200 px wide, else 0
    peak_threshold: float = 0.004  # COLMAP's 0.0067 finds too little on sand and grass
    sequential_overlap: int = 10
    spatial_neighbors: int = 20
    init_min_tri_angle: float = 4.0
    prior_sigma_h_m: float = 2.0
    prior_sigma_v_m: float = 4.0
    # RTK photos' priors at their stated sigma, but no tighter than this: below it the
    # camera centre's offset from the antenna (lever arm) is no longer negligible.
    min_prior_sigma_m: float = 0.02
    dense: bool = True
    dense_width: int = 1280
    min_model_images: int = 4  # smaller COLMAP models are dropped
    # A guessed focal length is kept fixed unless this is set. At one height a nadir
    # survey cannot tell a focal length from a height (a longer lens over deeper ground
    # gives the same images): refining the right guess (427 px) on the mounds
    # flights at 7 m gave 1129, 181 and 145 px and put the ground 4-11 m off; on the
    # paper's 3-D path (7-20 m) 338 px, 2.6 m off.
    refine_guessed_focal: bool = False
    min_inliers: int = 20  # to register an image (twice that for the first pair)
    threads: int = 2
    seed: int = 0


def run_sfm(
    image_paths: list[str],
    times: list[float],
    log: FlightLog,
    offset_s: float,
    intrinsics: Intrinsics,
    work_dir: Path,
    options: SfmOptions | None = None,
    progress: ProgressFn = no_progress,
) -> tuple[SparseMap, dict[str, Any]]:
    """COLMAP SfM on the images (see the module doc): (map in UTM, report)."""
    options = options or SfmOptions()
    if len(image_paths) < 3:
        raise InputError("SfM needs at least three images")
    work_dir = Path(work_dir)
    if work_dir.exists():
        shutil.rmtree(work_dir)  # a re-run starts from scratch: idempotent
    work_dir.mkdir(parents=True)
    image_dir = Path(image_paths[0]).parent
    if any(Path(p).parent != image_dir for p in image_paths):
        raise InputError("the images of one survey must be in one folder")
    names = [Path(p).name for p in image_paths]
    time_of = dict(zip(names, times, strict=True))
    timing: dict[str, float] = {}
    pycolmap.set_random_seed(options.seed)
    database = work_dir / "database.db"

    t0 = time.perf_counter()
    reader = pycolmap.ImageReaderOptions()
    if intrinsics.focal_guess:
        # One focal length to refine, not fx and fy apart: a guess has no aspect to keep.
        reader.camera_model = "SIMPLE_PINHOLE"
        reader.camera_params = f"{intrinsics.fx},{intrinsics.cx},{intrinsics.cy}"
    else:
        reader.camera_model = "PINHOLE"
        reader.camera_params = f"{intrinsics.fx},{intrinsics.fy},{intrinsics.cx},{intrinsics.cy}"
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = options.threads
    extraction.use_gpu = False
    extraction.sift.max_num_features = options.max_features
    extraction.sift.first_octave = (
        options.first_octave
        if options.first_octave is not None
        else (-1 if intrinsics.width < 1200 else 0)
    )
    extraction.sift.max_num_orientations = 1
    extraction.sift.peak_threshold = options.peak_threshold
    pycolmap.extract_features(
        database,
        image_dir,
        image_names=names,
        camera_mode=pycolmap.CameraMode.SINGLE,
        reader_options=reader,
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )
    timing["extract"] = time.perf_counter() - t0
    progress(0.3)

    epsg = survey_epsg(log)
    values = log.interpolate(np.asarray(times) + offset_s)
    alt = np.nan_to_num(values["alt"])
    ok = np.isfinite(values["lat"]) & np.isfinite(values["lon"])
    world = np.full((len(times), 3), np.nan)
    world[ok] = log_to_utm(values["lon"][ok], values["lat"][ok], alt[ok], epsg)
    if ok.sum() < 3:
        raise InputError("fewer than three images have a GNSS position at their time")
    origin = np.round(np.nanmean(world, axis=0))
    prior_of = {name: world[i] - origin for i, name in enumerate(names) if ok[i]}
    cov_of = _prior_covariances(log, np.asarray(times) + offset_s, names, options)
    db = pycolmap.Database.open(database)
    try:
        # COLMAP writes WGS84 priors from EXIF GPS itself: ours (metres, from the log at
        # the image time) replace them.
        db.clear_pose_priors()
        for image in db.read_all_images():
            if image.name not in prior_of:
                continue
            prior = pycolmap.PosePrior()
            prior.corr_data_id = image.data_id
            prior.position = prior_of[image.name]
            prior.position_covariance = cov_of[image.name]
            prior.coordinate_system = pycolmap.PosePriorCoordinateSystem.CARTESIAN
            db.write_pose_prior(prior)
    finally:
        db.close()

    t0 = time.perf_counter()
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = options.threads
    matching.use_gpu = False
    sequential = pycolmap.SequentialPairingOptions()
    sequential.overlap = options.sequential_overlap
    sequential.quadratic_overlap = False
    pycolmap.match_sequential(
        database, matching_options=matching, pairing_options=sequential, device=pycolmap.Device.cpu
    )
    if options.spatial_neighbors > 0:
        spatial = pycolmap.SpatialPairingOptions()
        spatial.max_num_neighbors = options.spatial_neighbors
        spatial.ignore_z = False
        spatial.max_distance = 1e9
        pycolmap.match_spatial(
            database, matching_options=matching, pairing_options=spatial, device=pycolmap.Device.cpu
        )
    timing["match"] = time.perf_counter() - t0
    progress(0.55)

    t0 = time.perf_counter()
    refine_focal = refines_focal(intrinsics, options)
    recs = _incremental_mapping(database, image_dir, work_dir / "model", options, refine_focal)
    if not recs:
        raise InputError("SfM could not reconstruct the images (too little overlap or texture)")
    warnings: list[str] = []
    if refine_focal:
        intrinsics = _refined(intrinsics, recs[0])
        warnings.append(intrinsics.warnings[-1])
    elif intrinsics.focal_guess:
        warnings.append(
            f"SfM kept the guessed focal length (fx = {intrinsics.fx:.0f} px): a drone "
            "survey cannot tell a focal length from its height above the ground well "
            "enough to correct it; give the camera to be sure"
        )
    timing["map"] = time.perf_counter() - t0
    progress(0.8)

    sparse, kf_names = _to_sparse_map(recs, time_of, origin, intrinsics)
    rec = recs[0]
    t0 = time.perf_counter()
    if options.dense:
        _densify(sparse, kf_names, image_dir, intrinsics, options)
    timing["dense"] = time.perf_counter() - t0
    report = {
        "images": len(names),
        "models": len(recs),
        "registered": int(sum(r.num_reg_images() for r in recs)),
        "points3D": int(sum(r.num_points3D() for r in recs)),
        "mean_reprojection_error_px": round(float(rec.compute_mean_reprojection_error()), 4),
        "timing_s": {k: round(v, 3) for k, v in timing.items()},
        "focal_refined": refine_focal,
        "fx": round(intrinsics.fx, 2),
        "fy": round(intrinsics.fy, 2),
    }
    if warnings:
        report["warnings"] = warnings
    sparse.stats = {"sfm": report}
    progress(1.0)
    return sparse, report


def _prior_covariances(
    log: FlightLog, log_t: np.ndarray, names: list[str], options: SfmOptions
) -> dict[str, np.ndarray]:
    """Each image's pose-prior covariance: the position's own stated sigma where the log
    states one (RTK photos: centimetres, at least `min_prior_sigma_m`), else the
    options' stand-alone GNSS sigmas."""
    default = np.array([options.prior_sigma_h_m, options.prior_sigma_h_m, options.prior_sigma_v_m])
    stated = log.stated_sigma_at(log_t)
    out = {}
    for i, name in enumerate(names):
        sigma = default
        if stated is not None and np.isfinite(stated[i]).all():
            sigma = np.maximum(stated[i], options.min_prior_sigma_m)
        out[name] = np.diag(sigma**2)
    return out


def _incremental_mapping(
    database: Path, image_dir: Path, model_dir: Path, options: SfmOptions, refine_focal: bool
) -> list[pycolmap.Reconstruction]:
    """COLMAP's models, the largest first, those under `min_model_images` dropped
    (unless none is larger); empty when nothing could be reconstructed."""
    model_dir.mkdir()
    mapping = _mapping_options(options, refine_focal)
    models = pycolmap.incremental_mapping(database, image_dir, model_dir, mapping)
    recs = sorted(models.values(), key=lambda r: -r.num_reg_images())
    return [r for r in recs if r.num_reg_images() >= options.min_model_images] or recs[:1]


def refines_focal(intrinsics: Intrinsics, options: SfmOptions) -> bool:
    """Whether the mapping refines the focal length: only a guessed one, only on request
    (see `SfmOptions.refine_guessed_focal`)."""
    return intrinsics.focal_guess and options.refine_guessed_focal


def _mapping_options(
    options: SfmOptions, refine_focal: bool
) -> pycolmap.IncrementalPipelineOptions:
    """COLMAP's incremental mapping as the module doc says. The intrinsics stay fixed
    (freeing them drifted 16 %), unless `refine_focal`: then bundle adjustment and
    registration refine the focal length."""
    mapping = pycolmap.IncrementalPipelineOptions()
    mapping.use_prior_position = True
    mapping.use_robust_loss_on_prior_position = True
    mapping.ba_refine_focal_length = refine_focal
    mapping.ba_refine_principal_point = False
    mapping.ba_refine_extra_params = False
    mapping.num_threads = options.threads
    mapping.random_seed = options.seed
    mapping.multiple_models = True
    mapping.mapper.init_min_tri_angle = options.init_min_tri_angle
    mapping.mapper.init_min_num_inliers = options.min_inliers * 2
    mapping.mapper.abs_pose_min_num_inliers = options.min_inliers
    mapping.min_model_size = options.min_model_images
    mapping.mapper.abs_pose_refine_focal_length = refine_focal
    mapping.mapper.abs_pose_refine_extra_params = False
    return mapping


def _refined(intrinsics: Intrinsics, rec: pycolmap.Reconstruction) -> Intrinsics:
    """The guessed intrinsics with the focal length the largest model refined (one
    camera per model: the smaller models' refinements are left, having less support)."""
    camera = next(iter(rec.cameras.values()))
    fx = fy = float(camera.params[0])  # SIMPLE_PINHOLE: f, cx, cy
    out = replace(intrinsics, fx=fx, fy=fy, warnings=list(intrinsics.warnings))
    out.warnings.append(
        f"SfM refined the guessed focal length from fx = {intrinsics.fx:.0f} px to "
        f"{fx:.0f} px ({out.hfov_deg:.0f} deg horizontal field of view)"
    )
    return out


def _to_sparse_map(
    recs: list[pycolmap.Reconstruction],
    time_of: dict[str, float],
    origin: np.ndarray,
    intrinsics: Intrinsics,
) -> tuple[SparseMap, list[str]]:
    """Registered images as keyframes, one segment per COLMAP model, each in time
    order (and the image names in keyframe order). Point ids are made unique."""
    kf_seg, kf_t, kf_r, kf_tr, names = [], [], [], [], []
    obs_kf, obs_pt, obs_uv = [], [], []
    pt_id, pt_xyz, pt_seg = [], [], []
    for seg, rec in enumerate(recs):
        base = seg * 10_000_000
        images = sorted(
            (rec.image(i) for i in rec.reg_image_ids()), key=lambda im: time_of[im.name]
        )
        for image in images:
            k = len(kf_t)
            pose = image.cam_from_world()
            r = np.array(pose.rotation.matrix())
            kf_r.append(r)
            # Moving the world by +origin: t' = t - R origin.
            kf_tr.append(np.asarray(pose.translation) - r @ origin)
            kf_t.append(time_of[image.name])
            kf_seg.append(seg)
            names.append(image.name)
            for p2 in image.points2D:
                if p2.has_point3D():
                    obs_kf.append(k)
                    obs_pt.append(base + p2.point3D_id)
                    obs_uv.append(p2.xy)
        for pid in sorted(rec.point3D_ids()):
            pt_id.append(base + pid)
            pt_xyz.append(np.asarray(rec.point3D(pid).xyz) + origin)
            pt_seg.append(seg)
    order = np.argsort(np.array(pt_id, dtype=np.int64))
    sparse = SparseMap.from_keyframes(
        intrinsics.K,
        (intrinsics.width, intrinsics.height),
        t=np.array(kf_t),
        r=np.array(kf_r),
        tr=np.array(kf_tr),
        segment=np.array(kf_seg),
        obs_kf=np.array(obs_kf),
        obs_point=np.array(obs_pt),
        obs_uv=np.array(obs_uv),
        point_id=np.array(pt_id, dtype=np.int64)[order],
        point_xyz=np.array(pt_xyz).reshape(-1, 3)[order],
        point_segment=np.array(pt_seg)[order],
    )
    return sparse, names


# A second partner must add at least this share of the image's footprint: less is not
# worth an SGBM run (about a second per pair at 1280 px).
_MIN_NEW_OVERLAP = 0.1


def _stereo_partners(
    sparse: SparseMap, depths: np.ndarray, options: DensifyOptions, max_partners: int = 2
) -> list[list[int]]:
    """Per image, up to `max_partners` images to pair it with for dense stereo, chosen by
    where they look, not by time: photo sets are flown in lines, and an image's best
    partners are its neighbours along the line and on the next line, whenever they were
    taken. Candidates share its segment and have a baseline ratio (baseline over its
    median depth) within the options' bounds. The first partner is the one whose ground
    footprint overlaps its own most, weighted by how near the ratio is to the target
    (depth precision); the second the one that adds most of its footprint not yet paired
    (the other side: behind it on the line, or the other line), if that is at least
    `_MIN_NEW_OVERLAP` of it. A pair's dense points cover the overlap of its two
    footprints, so between them the partners cover what the image shares with others."""
    centres = sparse.kf_centres()
    views = camera_footprints(sparse)
    partners: list[list[int]] = []
    for a in range(len(centres)):
        chosen: list[int] = []
        partners.append(chosen)
        view_a = views[a]
        if view_a is None or not np.isfinite(depths[a]):
            continue
        ratio = np.linalg.norm(centres - centres[a], axis=1) / depths[a]
        ok = (
            (sparse.kf_segment == sparse.kf_segment[a])
            & (ratio >= options.min_baseline_ratio)
            & (ratio <= options.max_baseline_ratio)
        )
        ok[a] = False
        # How near each ratio is to the target, 1 at the target (a ratio half or twice
        # the target scores 0.5).
        quality = np.exp(-np.abs(np.log(np.maximum(ratio, 1e-9) / options.target_baseline_ratio)))
        shared = {
            int(b): view_a.intersection(views[b])
            for b in np.flatnonzero(ok)
            if views[b] is not None and view_a.intersects(views[b])
        }
        covered = None
        area_a = view_a.area
        while shared and len(chosen) < max_partners:
            least = _MIN_NEW_OVERLAP if chosen else 0.0
            gains = {}
            for b, part in shared.items():
                gain = (part if covered is None else part.difference(covered)).area / area_a
                if gain > 0 and gain >= least:
                    gains[b] = gain
            if not gains:
                break
            best = max(gains, key=lambda b: gains[b] * quality[b])
            chosen.append(best)
            part = shared.pop(best)
            covered = part if covered is None else covered.union(part)
    return partners


def _densify(
    sparse: SparseMap,
    kf_names: list[str],
    image_dir: Path,
    intrinsics: Intrinsics,
    options: SfmOptions,
) -> None:
    """SGBM between each image and its stereo partners (`_stereo_partners`)."""
    dense_opts = DensifyOptions()
    scale = min(1.0, options.dense_width / intrinsics.width)
    size = (round(intrinsics.width * scale), round(intrinsics.height * scale))
    k = intrinsics.scaled(*size).K
    centres = sparse.kf_centres()
    cache: dict[int, np.ndarray] = {}

    def gray(i: int) -> np.ndarray:
        if i not in cache:
            img = cv2.imread(str(image_dir / kf_names[i]), cv2.IMREAD_GRAYSCALE)
            cache[i] = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
            if len(cache) > 8:
                cache.pop(next(iter(cache)))
        return cache[i]

    n = len(centres)
    depths = np.full(n, np.nan)
    seen_points: dict[int, np.ndarray] = {}  # in each view's camera frame
    for a in range(n):
        seen = sparse.observed_points(a)
        if len(seen) < 20:
            continue
        depths[a] = float(np.median(seen[:, 2]))
        seen_points[a] = seen
    chunks = []
    for a, chosen in enumerate(_stereo_partners(sparse, depths, dense_opts)):
        for pair, b in enumerate(chosen):
            pts = densify_pair(
                gray(a),
                gray(b),
                k,
                (sparse.kf_r[a], sparse.kf_tr[a]),
                (sparse.kf_r[b], sparse.kf_tr[b]),
                seen_points[a],
                dense_opts,
                sample_phase=a + pair,
            )
            if len(pts):
                baseline = float(np.linalg.norm(centres[b] - centres[a]))
                chunks.append((a, b, pts, baseline))
    if chunks:
        sparse.dense_kf = np.concatenate([np.full(len(c[2]), c[0], np.int32) for c in chunks])
        sparse.dense_partner = np.concatenate([np.full(len(c[2]), c[1], np.int32) for c in chunks])
        sparse.dense_xyz = np.concatenate([c[2] for c in chunks])
        sparse.dense_baseline = np.concatenate([np.full(len(c[2]), c[3]) for c in chunks])
