"""The SLAM loop: one call per frame (`VisualSlam.process`), `finish` at the end.

Per frame: KLT tracking; while initialising, wait for enough parallax against a
reference frame, then essential matrix (USAC MAGSAC), relative pose and two-view
triangulation; while tracking, the camera pose from the tracked map points (PnP from
the constant-velocity prediction, RANSAC only when that fails) and the keyframe policy.

Per keyframe: triangulate tracks seen by an older keyframe of the window with enough
ray angle, windowed bundle adjustment (the newest `ba_window` keyframes free, up to
`ba_fixed` older ones fixed; the first two keyframes of a segment stay fixed and set its
scale), cull points that reproject badly, detect new corners, and densify the keyframes
that have left the window with SGBM against the partner whose baseline is closest to
`target_baseline_ratio` of the depth, and against a second one closest to
`wide_baseline_ratio` (the DSM takes the wider pair's heights where the two agree: the
noise of a height falls as the baseline grows; the first pair keeps the rest). SGBM
runs in a worker thread beside the tracking (OpenCV releases the GIL): its inputs are
fixed when it is queued, so the result does not depend on the timing.

With the camera's readout time (`Intrinsics.readout_s`: a rolling shutter), every
tracked point and keyframe image is moved to where a global shutter would have seen it
(slam/rolling_shutter.py) before it is used: by the camera's motion over the last two
posed frames, and for a segment's first pair by the motion that pair shows (its
geometry is solved twice): the segment's scale is set there, and later keyframes moved
by the rolling shutter's correction must agree with it.

When too few map points are tracked, the segment ends and a new one initialises from
the current frame ("recovery": segments are placed on the ground independently by the
georeferencing, which needs no visual overlap between them).
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from worker.pipeline.frames import KeyframePolicy
from worker.pipeline.ingest.camera import Intrinsics
from worker.pipeline.progress import ProgressFn, no_progress
from worker.pipeline.slam.bundle import BAProblem, bundle_adjust
from worker.pipeline.slam.densify import DensifyOptions, densify_pair, stereo_partners
from worker.pipeline.slam.geometry import camera_center, project, rays_world, triangulate_midpoint
from worker.pipeline.slam.result import SparseMap
from worker.pipeline.slam.rolling_shutter import (
    FrameMotion,
    global_shutter_image,
    to_global_shutter,
)
from worker.pipeline.slam.tracker import KltTracker, TrackerOptions


@dataclass
class SlamOptions:
    tracker: TrackerOptions = field(default_factory=TrackerOptions)
    keyframes: KeyframePolicy = field(default_factory=KeyframePolicy)
    densify: DensifyOptions = field(default_factory=DensifyOptions)
    # Frames closer than this in image motion are skipped (see frames.tracking_frames).
    track_step_px: float = 12.0
    track_max_gap_s: float = 0.5
    init_parallax_px: float = 25.0
    init_min_points: int = 80
    init_min_angle_deg: float = 1.0
    init_max_frames: int = 150
    min_tri_angle_deg: float = 1.0
    max_reproj_px: float = 2.5
    cull_reproj_px: float = 4.0
    pnp_min_points: int = 25
    ba_window: int = 8
    ba_fixed: int = 4
    ba_iterations: int = 10
    ba_loss_px: float = 2.0
    ba_max_points: int = 1000  # the most-observed points of the window take part
    triangulation_window: int = 10
    min_segment_keyframes: int = 4
    keyframe_images: int = 16
    seed: int = 0


@dataclass
class _Keyframe:
    index: int  # position in VisualSlam.keyframes
    segment: int
    frame_index: int
    t: float
    r: np.ndarray  # R_cw
    tr: np.ndarray  # t_cw
    ids: np.ndarray
    uv: np.ndarray
    image: np.ndarray | None
    densified: bool = False
    motion: FrameMotion | None = None  # while it was read (rolling shutter)


@dataclass
class _Frame:
    t: float
    segment: int
    r: np.ndarray
    tr: np.ndarray
    is_kf: bool
    ref_kf: int
    rel_r: np.ndarray
    rel_t: np.ndarray


@dataclass
class _Reference:
    t: float
    frame_index: int
    image: np.ndarray
    ids: np.ndarray
    uv: np.ndarray
    frames: int = 0


class VisualSlam:
    """Streaming monocular SLAM for one camera (see the module doc)."""

    def __init__(self, intrinsics: Intrinsics, options: SlamOptions | None = None):
        self.options = options or SlamOptions()
        self.k = intrinsics.K
        self.k_inv = np.linalg.inv(self.k)
        self.size = (intrinsics.width, intrinsics.height)
        self.tracker = KltTracker(self.options.tracker)
        self.keyframes: list[_Keyframe] = []
        self.frames: list[_Frame] = []
        # The current segment's points as arrays sorted by id (tracking, culling and BA
        # look them up by id in bulk); earlier segments' as (segment, ids, xyz).
        self.point_ids = np.empty(0, np.int64)
        self.point_xyz = np.empty((0, 3))
        self.archived: list[tuple[int, np.ndarray, np.ndarray]] = []
        # (keyframe index, partner index, points in the keyframe's frame, baseline)
        self.dense: list[tuple[int, int, Future[np.ndarray], float]] = []
        self._densifier = ThreadPoolExecutor(max_workers=1, thread_name_prefix="densify")
        self.segment = -1
        self.segment_start = 0  # index of the segment's first keyframe
        self.state = "init"
        self.ref: _Reference | None = None
        self.velocity: tuple[np.ndarray, np.ndarray] | None = None
        self.last_pose: tuple[np.ndarray, np.ndarray] | None = None
        # Rolling shutter: the readout, the time of `last_pose` and the camera's motion
        # over the last tracked frames (None until two frames of a segment are posed).
        self.readout_s = float(intrinsics.readout_s)
        self.last_t: float | None = None
        self.motion: FrameMotion | None = None
        self.timing: dict[str, float] = {
            k: 0.0
            for k in (
                "track",
                "init",
                "pose",
                "keyframe",
                "ba",
                "densify",  # choosing partners and queueing
                "densify_thread",  # SGBM and depth, in the worker thread
                "densify_wait",  # waiting for the worker at the end
            )
        }
        self.counts: dict[str, int] = {
            "frames": 0,
            "tracked_frames": 0,
            "keyframes": 0,
            "lost": 0,
            "ba_runs": 0,
            "dense_pairs": 0,
        }
        self.events: list[dict[str, Any]] = []
        cv2.setRNGSeed(self.options.seed)

    # -- public -----------------------------------------------------------------------
    def process(self, t: float, frame_index: int, gray: np.ndarray) -> bool:
        """Feed one grey frame; returns True when the frame got a pose."""
        self.counts["frames"] += 1
        t0 = time.perf_counter()
        ids, pts = self.tracker.track(gray)
        self.timing["track"] += time.perf_counter() - t0
        if self.state == "init":
            t0 = time.perf_counter()
            ok = self._initialize(t, frame_index, gray, ids, pts)
            self.timing["init"] += time.perf_counter() - t0
            return ok
        t0 = time.perf_counter()
        pose = self._track_pose(t, ids, pts)
        self.timing["pose"] += time.perf_counter() - t0
        if pose is None:
            self._lost(t, frame_index, gray)
            return False
        r, tr, tracked = pose
        self.counts["tracked_frames"] += 1
        pts = self._global_shutter(pts)
        last = self.keyframes[-1]
        common, ia, ib = np.intersect1d(last.ids, ids, return_indices=True)
        parallax = (
            float(np.median(np.linalg.norm(last.uv[ia] - pts[ib], axis=1))) if len(common) else 0.0
        )
        survival = len(common) / max(len(last.ids), 1)
        if self.options.keyframes.is_keyframe(parallax, survival, tracked):
            t0 = time.perf_counter()
            self._add_keyframe(t, frame_index, gray, r, tr)
            self.timing["keyframe"] += time.perf_counter() - t0
        else:
            self._record_frame(t, r, tr, False)
        return True

    def finish(self) -> SparseMap:
        """Densify what is left and return the map (segments too short are dropped)."""
        self._densify(final=True)
        t0 = time.perf_counter()
        self._densifier.shutdown(wait=True)
        self.timing["densify_wait"] += time.perf_counter() - t0
        return self._build_map()

    def close(self) -> None:
        """Stop the densification thread (finish does it too)."""
        self._densifier.shutdown(wait=True, cancel_futures=True)

    # -- initialisation -----------------------------------------------------------------
    def _set_reference(self, t: float, frame_index: int, gray: np.ndarray) -> None:
        self.tracker.detect(gray)
        self.ref = _Reference(
            t, frame_index, gray, self.tracker.ids.copy(), self.tracker.pts.copy()
        )

    def _initialize(
        self, t: float, frame_index: int, gray: np.ndarray, ids: np.ndarray, pts: np.ndarray
    ) -> bool:
        o = self.options
        if self.ref is None:
            self._set_reference(t, frame_index, gray)
            return False
        ref = self.ref
        ref.frames += 1
        common, ia, ib = np.intersect1d(ref.ids, ids, return_indices=True)
        if len(common) < o.init_min_points or ref.frames > o.init_max_frames:
            self._set_reference(t, frame_index, gray)
            return False
        p0 = ref.uv[ia].astype(np.float64)
        p1 = pts[ib].astype(np.float64)
        parallax = float(np.median(np.linalg.norm(p1 - p0, axis=1)))
        if parallax < o.init_parallax_px:
            return False
        geometry = self._relative_geometry(p0, p1)
        if geometry is None:
            return False
        motion = self._initial_motion(geometry, t - ref.t)
        if motion is not None:
            # Rolling shutter: the pair again, its points where a global shutter would
            # have seen them, by the motion the pair itself shows (the segment's scale
            # is set here: later keyframes, moved, must agree with these two).
            moved = self._relative_geometry(
                self._global_shutter(p0, motion), self._global_shutter(p1, motion)
            )
            if moved is not None:
                geometry = moved
            else:
                motion = None
        r, t1, xyz, good, angle = geometry
        if good.sum() < o.init_min_points or np.median(angle[good]) < o.init_min_angle_deg:
            if parallax > 4 * o.init_parallax_px:
                self._set_reference(t, frame_index, gray)
            return False
        # Success: a new segment with two keyframes; earlier points are put aside.
        if len(self.point_ids):
            self.archived.append((self.segment, self.point_ids, self.point_xyz))
        self.point_ids, self.point_xyz = np.empty(0, np.int64), np.empty((0, 3))
        self.segment += 1
        self.segment_start = len(self.keyframes)
        r0, t0 = np.eye(3), np.zeros(3)
        self.motion = motion
        kf0 = self._new_keyframe(
            ref.t,
            ref.frame_index,
            r0,
            t0,
            ref.ids,
            self._global_shutter(ref.uv),
            self._global_shutter_image(ref.image),
        )
        kf0.motion = motion
        self._record_frame(ref.t, r0, t0, True, kf0.index)
        self._add_points(common[good], xyz[good])
        kf1 = self._new_keyframe(
            t, frame_index, r, t1, ids, self._global_shutter(pts), self._global_shutter_image(gray)
        )
        kf1.motion = motion
        self._record_frame(t, r, t1, True, kf1.index)
        self._bundle(fix_all=True)
        self._cull([kf0.index, kf1.index])
        self._detect_into(kf1, gray)
        self.state = "tracking"
        self.ref = None
        self.last_pose = (r.copy(), t1.copy())
        self.last_t = t
        self.velocity = None
        self.events.append({"event": "initialised", "t": t, "segment": self.segment})
        return True

    def _relative_geometry(self, p0: np.ndarray, p1: np.ndarray):
        """The second view's pose relative to the first (essential matrix) and the
        pair's points: (R, t of unit length, xyz, good mask, ray angle deg), or None."""
        e, mask = cv2.findEssentialMat(
            p0, p1, self.k, method=cv2.USAC_MAGSAC, prob=0.999, threshold=1.0
        )
        if e is None or e.shape != (3, 3):
            return None
        _, r, tvec, mask = cv2.recoverPose(e, p0, p1, self.k, mask=mask)
        t1 = tvec.ravel() / max(np.linalg.norm(tvec), 1e-12)
        xyz, good, angle = self._two_view(np.eye(3), np.zeros(3), r, t1, p0, p1)
        return r, t1, xyz, good & (mask.ravel() > 0), angle

    def _initial_motion(self, geometry, seconds: float) -> FrameMotion | None:
        """The motion a new segment's first pair shows, where a rolling shutter is
        modelled (the scene's depth: its points' median, in the first view)."""
        r, t1, xyz, good, _ = geometry
        if self.readout_s <= 0 or seconds <= 0 or not good.any():
            return None
        depth = float(np.median(xyz[good][:, 2]))
        if depth <= 0:
            return None
        return FrameMotion.between(np.eye(3), np.zeros(3), r, t1, seconds, depth)

    def _two_view(self, ra, ta, rb, tb, uva, uvb):
        """Midpoint triangulation with checks: (xyz, good mask, ray angle deg)."""
        ca, cb = camera_center(ra, ta), camera_center(rb, tb)
        da = rays_world(ra, self.k_inv, uva)
        db = rays_world(rb, self.k_inv, uvb)
        n = len(uva)
        xyz, sa, sb, angle = triangulate_midpoint(np.tile(ca, (n, 1)), da, np.tile(cb, (n, 1)), db)
        good = np.isfinite(xyz).all(axis=1) & (sa > 0) & (sb > 0)
        good &= angle >= self.options.min_tri_angle_deg
        for r, t, uv in ((ra, ta, uva), (rb, tb, uvb)):
            proj, z = project(r, t, self.k, np.nan_to_num(xyz))
            err = np.linalg.norm(proj - uv, axis=1)
            good &= (z > 0) & (err < self.options.max_reproj_px)
        return xyz, good, angle

    # -- tracking -------------------------------------------------------------------------
    def _add_points(self, ids: np.ndarray, xyz: np.ndarray) -> None:
        """Add points with new ids to the current segment (tracks that outlive a segment
        get new points: the old segment's frame must not leak into the new one)."""
        all_ids = np.concatenate([self.point_ids, ids.astype(np.int64)])
        order = np.argsort(all_ids, kind="stable")
        self.point_ids = all_ids[order]
        self.point_xyz = np.concatenate([self.point_xyz, xyz.reshape(-1, 3)])[order]

    def _remove_points(self, ids: np.ndarray) -> None:
        keep = ~np.isin(self.point_ids, ids)
        self.point_ids, self.point_xyz = self.point_ids[keep], self.point_xyz[keep]

    def _points_of(self, ids: np.ndarray) -> np.ndarray:
        """Positions of current-segment points given by id (all must exist)."""
        return self.point_xyz[np.searchsorted(self.point_ids, ids)]

    def _track_pose(self, t: float, ids: np.ndarray, pts: np.ndarray):
        o = self.options
        pos = np.searchsorted(self.point_ids, ids)
        pos = np.clip(pos, 0, max(len(self.point_ids) - 1, 0))
        sel = (self.point_ids[pos] == ids) if len(self.point_ids) else np.zeros(len(ids), bool)
        if sel.sum() < o.pnp_min_points:
            return None
        obj = self.point_xyz[pos[sel]]
        seen = pts[sel].astype(np.float64)
        r_prev, t_prev = self.last_pose
        if self.velocity is not None:
            dr, dt = self.velocity
            r_pred, t_pred = dr @ r_prev, dr @ t_prev + dt
        else:
            r_pred, t_pred = r_prev, t_prev
        # Rolling shutter: first by the last frames' motion, the predicted depths.
        img = self._moved(seen, obj, r_pred, t_pred, self.motion)
        rvec, _ = cv2.Rodrigues(r_pred)
        tvec = t_pred.reshape(3, 1).copy()
        ok, rvec, tvec = cv2.solvePnP(
            obj,
            img,
            self.k,
            None,
            rvec,
            tvec,
            useExtrinsicGuess=True,
            flags=cv2.SOLVEPNP_ITERATIVE,
        )
        inl = self._inliers(obj, img, rvec, tvec) if ok else np.zeros(len(obj), bool)
        if inl.mean() < 0.6:
            ok, rvec, tvec, idx = cv2.solvePnPRansac(
                obj,
                img,
                self.k,
                None,
                iterationsCount=100,
                reprojectionError=o.max_reproj_px,
                confidence=0.999,
                flags=cv2.SOLVEPNP_AP3P,
            )
            if not ok or idx is None:
                return None
            inl = np.zeros(len(obj), bool)
            inl[idx.ravel()] = True
        if inl.sum() < o.pnp_min_points:
            return None
        rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], self.k, None, rvec, tvec)
        inl = self._inliers(obj, img, rvec, tvec)
        if inl.sum() < o.pnp_min_points:
            return None
        if self.readout_s > 0 and self.last_t is not None and t > self.last_t:
            # ... then again by the motion this frame's pose shows (a turn's start
            # is not in the last frames' motion), and the pose refined on them.
            r = cv2.Rodrigues(rvec)[0]
            depth = float(np.median((obj[inl] @ r.T + tvec.ravel())[:, 2]))
            if depth > 0:
                motion = FrameMotion.between(
                    r_prev, t_prev, r, tvec.ravel(), t - self.last_t, depth
                )
                img = self._moved(seen, obj, r, tvec.ravel(), motion)
                rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], self.k, None, rvec, tvec)
                inl = self._inliers(obj, img, rvec, tvec)
                if inl.sum() < o.pnp_min_points:
                    return None
                self.motion = motion
        bad_ids = ids[sel][~inl]
        if len(bad_ids):
            self.tracker.remove(bad_ids)
        r = cv2.Rodrigues(rvec)[0]
        tr = tvec.ravel()
        self.velocity = (r @ r_prev.T, tr - (r @ r_prev.T) @ t_prev)
        self.last_pose = (r, tr)
        self.last_t = t
        return r, tr, int(inl.sum())

    def _moved(
        self,
        seen: np.ndarray,
        obj: np.ndarray,
        r: np.ndarray,
        tr: np.ndarray,
        motion: FrameMotion | None,
    ) -> np.ndarray:
        """Map points' observations where a global shutter would have seen them, each
        by its own depth under the pose (r, tr)."""
        if self.readout_s <= 0 or motion is None:
            return seen
        depth = (obj @ r.T + tr)[:, 2]
        scale = np.clip(np.median(depth) / np.maximum(depth, 1e-9), 0.5, 2.0)
        return to_global_shutter(seen, self.k, self.size[1], self.readout_s, motion, scale)

    def _inliers(self, obj, img, rvec, tvec) -> np.ndarray:
        proj, _ = cv2.projectPoints(obj, rvec, tvec, self.k, None)
        return np.linalg.norm(proj.reshape(-1, 2) - img, axis=1) < self.options.max_reproj_px

    def _lost(self, t: float, frame_index: int, gray: np.ndarray) -> None:
        self.counts["lost"] += 1
        self.events.append({"event": "lost", "t": t, "segment": self.segment})
        self._densify(final=True)
        self.state = "init"
        self.last_pose = None
        self.last_t = None
        self.velocity = None
        self.motion = None
        self._set_reference(t, frame_index, gray)

    # -- keyframes ------------------------------------------------------------------------
    def _new_keyframe(self, t, frame_index, r, tr, ids, uv, image) -> _Keyframe:
        kf = _Keyframe(
            index=len(self.keyframes),
            segment=self.segment,
            frame_index=frame_index,
            t=t,
            r=np.array(r, dtype=np.float64),
            tr=np.array(tr, dtype=np.float64),
            ids=np.array(ids, dtype=np.int64),
            uv=np.array(uv, dtype=np.float64),
            image=image,
        )
        self.keyframes.append(kf)
        self.counts["keyframes"] += 1
        return kf

    def _record_frame(self, t, r, tr, is_kf: bool, kf_index: int | None = None) -> None:
        ref = kf_index if kf_index is not None else len(self.keyframes) - 1
        kf = self.keyframes[ref]
        rel_r = r @ kf.r.T
        rel_t = tr - rel_r @ kf.tr
        self.frames.append(_Frame(t, self.segment, r.copy(), tr.copy(), is_kf, ref, rel_r, rel_t))

    def _add_keyframe(self, t, frame_index, gray, r, tr) -> None:
        uv = self._global_shutter(self.tracker.pts)
        image = self._global_shutter_image(gray)
        kf = self._new_keyframe(t, frame_index, r, tr, self.tracker.ids, uv, image)
        kf.motion = self.motion
        self._record_frame(t, r, tr, True, kf.index)
        self._triangulate(kf)
        window = self._bundle()
        self._cull(window)
        self._detect_into(kf, gray)
        self.last_pose = (kf.r.copy(), kf.tr.copy())
        t0 = time.perf_counter()
        self._densify()
        self.timing["densify"] += time.perf_counter() - t0

    def _detect_into(self, kf: _Keyframe, gray: np.ndarray) -> None:
        self.tracker.detect(gray)
        kf.ids = self.tracker.ids.copy()
        kf.uv = self._global_shutter(self.tracker.pts)

    def _global_shutter(self, uv: np.ndarray, motion: FrameMotion | None = None) -> np.ndarray:
        """Tracked points (the current frame's) where a global shutter would have seen
        them, by `motion` or else the motion of the last frames (as tracked: none known
        yet, or a global shutter)."""
        motion = motion or self.motion
        if self.readout_s <= 0 or motion is None:
            return np.asarray(uv, dtype=np.float64)
        return to_global_shutter(uv, self.k, self.size[1], self.readout_s, motion)

    def _global_shutter_image(self, image: np.ndarray) -> np.ndarray:
        """The current frame's image as a global shutter would have taken it."""
        if self.readout_s <= 0 or self.motion is None:
            return image
        return global_shutter_image(image, self.k, self.readout_s, self.motion)

    def _segment_keyframes(self) -> list[_Keyframe]:
        return self.keyframes[self.segment_start :]

    def _triangulate(self, kf: _Keyframe) -> None:
        candidates = kf.ids[~np.isin(kf.ids, self.point_ids)]
        older = self._segment_keyframes()[:-1][-self.options.triangulation_window :]
        for other in older:
            if len(candidates) == 0:
                break
            common, ia, _ = np.intersect1d(other.ids, candidates, return_indices=True)
            if len(common) == 0:
                continue
            _, ik, _ = np.intersect1d(kf.ids, common, return_indices=True)
            xyz, good, _ = self._two_view(other.r, other.tr, kf.r, kf.tr, other.uv[ia], kf.uv[ik])
            self._add_points(common[good], xyz[good])
            candidates = candidates[~np.isin(candidates, common[good])]

    def _bundle(self, fix_all: bool = False) -> list[int]:
        """Windowed BA; returns the keyframe indices that took part."""
        o = self.options
        seg = self._segment_keyframes()
        free = seg[-o.ba_window :]
        before = seg[: max(0, len(seg) - o.ba_window)][-o.ba_fixed :]
        included = before + free
        fixed = {kf.index for kf in before}
        fixed |= {kf.index for kf in seg[:2]}
        if fix_all:
            fixed = {kf.index for kf in included}
        all_ids = np.concatenate([kf.ids for kf in included])
        free_ids = np.unique(np.concatenate([kf.ids for kf in free]))
        point_ids = free_ids[np.isin(free_ids, self.point_ids)]
        if len(point_ids) > o.ba_max_points:
            all_ids.sort()
            seen = np.searchsorted(all_ids, point_ids, side="right") - np.searchsorted(
                all_ids, point_ids, side="left"
            )
            point_ids = point_ids[np.argsort(-seen, kind="stable")[: o.ba_max_points]]
        if len(point_ids) < 10:
            return [kf.index for kf in included]
        problem = BAProblem(
            poses={kf.index: (kf.r, kf.tr) for kf in included},
            observations={kf.index: (kf.ids, kf.uv) for kf in included},
            points=dict(zip(point_ids.tolist(), self._points_of(point_ids), strict=True)),
            fixed=fixed,
        )
        t0 = time.perf_counter()
        poses, points, _report = bundle_adjust(
            problem, self.k, self.size, loss_px=o.ba_loss_px, max_iterations=o.ba_iterations
        )
        self.timing["ba"] += time.perf_counter() - t0
        self.counts["ba_runs"] += 1
        for kf in included:
            if kf.index not in fixed:
                kf.r, kf.tr = poses[kf.index]
        if points:
            ids = np.fromiter(points.keys(), np.int64, len(points))
            self.point_xyz[np.searchsorted(self.point_ids, ids)] = np.array(list(points.values()))
        return [kf.index for kf in included]

    def _cull(self, kf_indices: list[int]) -> None:
        """Remove points that reproject worse than `cull_reproj_px` in a keyframe."""
        bad: set[int] = set()
        for i in kf_indices:
            kf = self.keyframes[i]
            sel = np.isin(kf.ids, self.point_ids)
            ids = kf.ids[sel]
            if len(ids) == 0:
                continue
            xyz = self._points_of(ids)
            proj, z = project(kf.r, kf.tr, self.k, xyz)
            err = np.linalg.norm(proj - kf.uv[sel], axis=1)
            bad.update(ids[(err > self.options.cull_reproj_px) | (z <= 0)].tolist())
        if bad:
            bad_ids = np.fromiter(bad, dtype=np.int64)
            self._remove_points(bad_ids)
            self.tracker.remove(bad_ids)

    # -- densification --------------------------------------------------------------------
    def _densify(self, final: bool = False) -> None:
        o = self.options
        if not o.densify.enabled:
            for kf in self.keyframes:
                kf.image = None
            return
        seg = self._segment_keyframes()
        ready = seg if final else seg[: max(0, len(seg) - o.ba_window)]
        for kf in ready:
            if kf.densified or kf.image is None:
                continue
            kf.densified = True
            if (kf.index - self.segment_start) % max(1, o.densify.every) == 0:
                self._densify_keyframe(kf, seg)
        # Free images no longer needed as partners.
        keep_from = len(seg) - o.keyframe_images - o.ba_window
        for kf in seg[: max(0, keep_from)]:
            kf.image = None
        if final:
            for kf in seg:
                kf.image = None

    def _densify_keyframe(self, kf: _Keyframe, seg: list[_Keyframe]) -> None:
        o = self.options.densify
        sel = np.isin(kf.ids, self.point_ids)
        if sel.sum() < 20:
            return
        seen = self._points_of(kf.ids[sel]) @ kf.r.T + kf.tr  # in the keyframe's frame
        seen = seen[seen[:, 2] > 0]
        if len(seen) < 20:
            return
        depth = float(np.median(seen[:, 2]))
        centre = camera_center(kf.r, kf.tr)
        ratios = {
            other.index: float(np.linalg.norm(camera_center(other.r, other.tr) - centre)) / depth
            for other in seg
            if other is not kf and other.image is not None
        }
        partners = stereo_partners(ratios, o)
        for pair, index in enumerate(partners):
            other = self.keyframes[index]
            future = self._densifier.submit(
                self._densify_pair,
                kf.image,
                other.image,
                self.k,
                (kf.r.copy(), kf.tr.copy()),
                (other.r.copy(), other.tr.copy()),
                seen,
                o,
                # Each keyframe's pairs sample their own pixels (see densify_pair).
                kf.index + pair,
            )
            baseline = ratios[index] * depth
            self.dense.append((kf.index, other.index, future, baseline))

    def _densify_pair(self, *args: Any) -> np.ndarray:
        """`densify_pair` in the worker thread, timed (only that thread adds to the key)."""
        t0 = time.perf_counter()
        pts = densify_pair(*args)
        self.timing["densify_thread"] += time.perf_counter() - t0
        return pts

    # -- output ---------------------------------------------------------------------------
    def _build_map(self) -> SparseMap:
        o = self.options
        counts: dict[int, int] = {}
        for kf in self.keyframes:
            counts[kf.segment] = counts.get(kf.segment, 0) + 1
        keep_segments = {s for s, n in counts.items() if n >= o.min_segment_keyframes}
        dropped = sorted(set(counts) - keep_segments)
        kfs = [kf for kf in self.keyframes if kf.segment in keep_segments]
        new_index = {kf.index: i for i, kf in enumerate(kfs)}
        obs_kf, obs_pt, obs_uv = [], [], []
        # Every segment's points; an id a later segment triangulated again is the later one's.
        parts = [*self.archived, (self.segment, self.point_ids, self.point_xyz)][::-1]
        pt_ids = np.concatenate([p[1] for p in parts])
        pt_xyz = np.concatenate([p[2] for p in parts])
        pt_seg = np.concatenate([np.full(len(p[1]), p[0], np.int32) for p in parts])
        _, first = np.unique(pt_ids, return_index=True)
        first = first[np.isin(pt_seg[first], sorted(keep_segments))]
        point_ids = pt_ids[first]
        for kf in kfs:
            sel = np.isin(kf.ids, point_ids)
            obs_kf.append(np.full(sel.sum(), new_index[kf.index], np.int32))
            obs_pt.append(kf.ids[sel])
            obs_uv.append(kf.uv[sel].astype(np.float32))
        frames = [f for f in self.frames if f.segment in keep_segments]
        dense = [(a, b, f.result(), base) for a, b, f, base in self.dense]
        self.counts["dense_pairs"] = sum(len(d[2]) > 0 for d in dense)
        dense = [d for d in dense if len(d[2]) and d[0] in new_index and d[1] in new_index]
        stats = {
            "counts": dict(self.counts),
            "timing_s": {k: round(v, 3) for k, v in self.timing.items()},
            "events": self.events,
            "segments_dropped": dropped,
        }

        def stack(items, shape, dtype):
            return np.array(items, dtype=dtype) if items else np.empty(shape, dtype)

        return SparseMap(
            k=self.k,
            size=self.size,
            kf_id=np.arange(len(kfs), dtype=np.int32),
            kf_segment=stack([kf.segment for kf in kfs], (0,), np.int32),
            kf_t=stack([kf.t for kf in kfs], (0,), np.float64),
            kf_r=stack([kf.r for kf in kfs], (0, 3, 3), np.float64),
            kf_tr=stack([kf.tr for kf in kfs], (0, 3), np.float64),
            readout_s=self.readout_s,
            kf_motion=stack([_motion_row(kf.motion) for kf in kfs], (0, 6), np.float64),
            obs_kf=np.concatenate(obs_kf) if obs_kf else np.empty(0, np.int32),
            obs_point=np.concatenate(obs_pt) if obs_pt else np.empty(0, np.int64),
            obs_uv=np.concatenate(obs_uv) if obs_uv else np.empty((0, 2), np.float32),
            point_id=point_ids,
            point_xyz=pt_xyz[first],
            point_segment=pt_seg[first],
            fr_t=stack([f.t for f in frames], (0,), np.float64),
            fr_segment=stack([f.segment for f in frames], (0,), np.int32),
            fr_r=stack([f.r for f in frames], (0, 3, 3), np.float64),
            fr_tr=stack([f.tr for f in frames], (0, 3), np.float64),
            fr_is_kf=stack([f.is_kf for f in frames], (0,), bool),
            fr_ref_kf=stack([new_index.get(f.ref_kf, -1) for f in frames], (0,), np.int32),
            fr_rel_r=stack([f.rel_r for f in frames], (0, 3, 3), np.float64),
            fr_rel_t=stack([f.rel_t for f in frames], (0, 3), np.float64),
            dense_kf=np.concatenate([np.full(len(d[2]), new_index[d[0]], np.int32) for d in dense])
            if dense
            else np.empty(0, np.int32),
            dense_partner=np.concatenate(
                [np.full(len(d[2]), new_index[d[1]], np.int32) for d in dense]
            )
            if dense
            else np.empty(0, np.int32),
            dense_xyz=np.concatenate([d[2] for d in dense])
            if dense
            else np.empty((0, 3), np.float32),
            dense_baseline=np.concatenate([np.full(len(d[2]), d[3]) for d in dense])
            if dense
            else np.empty(0),
            stats=stats,
        )


def _motion_row(motion: FrameMotion | None) -> np.ndarray:
    """A keyframe's motion as SparseMap.kf_motion stores it (zeros: none known)."""
    if motion is None:
        return np.zeros(6)
    return np.concatenate([motion.omega, motion.v_over_z])


def run_slam(
    frames: Iterable[tuple[float, int, np.ndarray]],
    intrinsics: Intrinsics,
    options: SlamOptions | None = None,
    progress: ProgressFn = no_progress,
    total_frames: int | None = None,
) -> SparseMap:
    """Run the SLAM over (t, frame index, grey image) tuples; returns the map."""
    slam = VisualSlam(intrinsics, options)
    start = time.perf_counter()
    try:
        for n, (t, index, gray) in enumerate(frames, start=1):
            slam.process(t, index, gray)
            if total_frames and n % 25 == 0:
                progress(min(0.95 * n / total_frames, 0.95))
        result = slam.finish()
    finally:
        slam.close()
    result.stats["seconds"] = round(time.perf_counter() - start, 3)
    progress(1.0)
    return result
