"""What a reconstruction produces, independent of the method (SLAM or SfM).

`SparseMap` holds, per map segment (one per tracking loss; SfM gives one), the keyframe
poses, the sparse points and their keyframe observations, every tracked frame's pose,
and dense points in their keyframe's camera frame (so that moving a keyframe moves its
dense points). It is saved as one uncompressed .npz (compressing 9M dense points took
12 s; the dense points' keyframe, partner and baseline are stored once per run of
points they share) and gives the camera `Trajectory`,
the sparse and the dense clouds in any frame.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from worker.pipeline.atomic import atomic_path
from worker.pipeline.slam.rolling_shutter import FrameMotion
from worker.pipeline.trajectory import Trajectory


@dataclass
class SparseMap:
    k: np.ndarray  # 3 x 3 intrinsics of the processed frames
    size: tuple[int, int]  # width, height
    # keyframes
    kf_id: np.ndarray
    kf_segment: np.ndarray
    kf_t: np.ndarray
    kf_r: np.ndarray  # (K, 3, 3) R_cw
    kf_tr: np.ndarray  # (K, 3) t_cw
    # observations of sparse points: keyframe index (into kf arrays), point id, u, v
    obs_kf: np.ndarray
    obs_point: np.ndarray
    obs_uv: np.ndarray
    # sparse points
    point_id: np.ndarray
    point_xyz: np.ndarray
    point_segment: np.ndarray
    # every frame with a pose
    fr_t: np.ndarray
    fr_segment: np.ndarray
    fr_r: np.ndarray
    fr_tr: np.ndarray
    fr_is_kf: np.ndarray
    fr_ref_kf: np.ndarray  # keyframe index the frame pose is relative to (-1: none)
    fr_rel_r: np.ndarray  # (F, 3, 3) R of camera-from-reference-keyframe
    fr_rel_t: np.ndarray
    # dense points: keyframe index of the frame they are in, partner index, xyz (cam)
    dense_kf: np.ndarray = field(default_factory=lambda: np.empty(0, np.int32))
    dense_partner: np.ndarray = field(default_factory=lambda: np.empty(0, np.int32))
    dense_xyz: np.ndarray = field(default_factory=lambda: np.empty((0, 3), np.float32))
    dense_baseline: np.ndarray = field(default_factory=lambda: np.empty(0))  # per point
    # Rolling shutter: a frame's readout time, and per keyframe the camera's motion
    # while it was read (slam/rolling_shutter.FrameMotion: omega, v_over_z; zeros where
    # none was known). The observations and dense points are already moved to a global
    # shutter's view; this is what moves a keyframe image read again (the ties).
    readout_s: float = 0.0
    kf_motion: np.ndarray = field(default_factory=lambda: np.empty((0, 6)))
    stats: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def from_keyframes(
        cls,
        k: np.ndarray,
        size: tuple[int, int],
        *,
        t: np.ndarray,
        r: np.ndarray,
        tr: np.ndarray,
        segment: np.ndarray,
        obs_kf: np.ndarray,
        obs_point: np.ndarray,
        obs_uv: np.ndarray,
        point_id: np.ndarray,
        point_xyz: np.ndarray,
        point_segment: np.ndarray,
    ) -> SparseMap:
        """A map whose only posed frames are its keyframes (an SfM model: every
        registered image is a keyframe). Observations and points as the fields say;
        points must be sorted by id."""
        n = len(t)
        r = np.asarray(r, dtype=np.float64).reshape(n, 3, 3)
        tr = np.asarray(tr, dtype=np.float64).reshape(n, 3)
        t = np.asarray(t, dtype=np.float64)
        segment = np.asarray(segment, dtype=np.int32)
        return cls(
            k=k,
            size=size,
            kf_id=np.arange(n, dtype=np.int32),
            kf_segment=segment,
            kf_t=t,
            kf_r=r,
            kf_tr=tr,
            obs_kf=np.asarray(obs_kf, dtype=np.int32),
            obs_point=np.asarray(obs_point, dtype=np.int64),
            obs_uv=np.asarray(obs_uv, dtype=np.float32).reshape(-1, 2),
            point_id=np.asarray(point_id, dtype=np.int64),
            point_xyz=np.asarray(point_xyz, dtype=np.float64).reshape(-1, 3),
            point_segment=np.asarray(point_segment, dtype=np.int32),
            fr_t=t.copy(),
            fr_segment=segment.copy(),
            fr_r=r.copy(),
            fr_tr=tr.copy(),
            fr_is_kf=np.ones(n, bool),
            fr_ref_kf=np.arange(n, dtype=np.int32),
            fr_rel_r=np.broadcast_to(np.eye(3), (n, 3, 3)).copy(),
            fr_rel_t=np.zeros((n, 3)),
        )

    # -- views ---------------------------------------------------------------------
    @property
    def segments(self) -> list[int]:
        return sorted(set(self.kf_segment.tolist()))

    def keyframe_motion(self, index: int) -> FrameMotion | None:
        """The camera's motion while keyframe `index` was read, where a rolling shutter
        was modelled for it (None: a global shutter or no motion known)."""
        if self.readout_s <= 0 or index >= len(self.kf_motion):
            return None
        row = np.asarray(self.kf_motion[index], dtype=np.float64)
        if not row.any():
            return None
        return FrameMotion(omega=row[:3], v_over_z=row[3:])

    def kf_centres(self) -> np.ndarray:
        return -np.einsum("nji,nj->ni", self.kf_r, self.kf_tr)

    def observed_points(self, kf: int) -> np.ndarray:
        """The map points keyframe `kf` observes, in its camera frame, those in front of
        it (N, 3)."""
        if self.point_id.size == 0:
            return np.empty((0, 3))
        ids = self.obs_point[self.obs_kf == kf]
        index = np.clip(np.searchsorted(self.point_id, ids), 0, self.point_id.size - 1)
        xyz = self.point_xyz[index[self.point_id[index] == ids]]
        seen = xyz @ self.kf_r[kf].T + self.kf_tr[kf]
        return seen[seen[:, 2] > 0]

    def trajectory(self, segment: int | None = None) -> Trajectory:
        sel = np.ones(self.fr_t.size, bool) if segment is None else self.fr_segment == segment
        r_wc = np.transpose(self.fr_r[sel], (0, 2, 1))
        centres = -np.einsum("nji,nj->ni", self.fr_r[sel], self.fr_tr[sel])
        return Trajectory(self.fr_t[sel], centres, r_wc, self.fr_is_kf[sel].copy())

    def sparse_points(self, segment: int | None = None) -> np.ndarray:
        if segment is None:
            return self.point_xyz
        return self.point_xyz[self.point_segment == segment]

    def dense_wide_pair(self) -> np.ndarray:
        """Per dense point, whether its pair is the wider of its keyframe's two (SLAM
        matches a keyframe with a second, wider partner; see DensifyOptions)."""
        kf = self.dense_kf
        wide = np.zeros(kf.size, dtype=bool)
        if kf.size == 0:
            return wide
        partner, baseline = self.dense_partner, self.dense_baseline
        # Points lie in runs of one pair: one decision per run.
        changes = (kf[1:] != kf[:-1]) | (partner[1:] != partner[:-1])
        starts = np.flatnonzero(np.concatenate([[True], changes]))
        ends = np.append(starts[1:], kf.size)
        widest: dict[int, tuple[float, int]] = {}
        pairs_of: dict[int, int] = {}
        for run, start in enumerate(starts):
            key = int(kf[start])
            pairs_of[key] = pairs_of.get(key, 0) + 1
            if key not in widest or baseline[start] > widest[key][0]:
                widest[key] = (float(baseline[start]), run)
        for key, (_, run) in widest.items():
            if pairs_of[key] > 1:
                wide[starts[run] : ends[run]] = True
        return wide

    def dense_points(self, segment: int | None = None, out: np.ndarray | None = None) -> np.ndarray:
        """Dense points in the map frame from the current keyframe poses.

        Each point is stored in its keyframe's camera frame in the units of the moment
        it was computed; it is scaled by the ratio of its pair's current baseline to the
        baseline it was computed with, so similarity transforms and pose-prior
        adjustments carry the dense cloud along. With `out` ((N, 3) float64), the points
        are written there (and `out` is returned)."""
        if self.dense_xyz.size == 0:
            return np.empty((0, 3)) if out is None else out
        kf, partner = self.dense_kf, self.dense_partner
        xyz, then = self.dense_xyz, self.dense_baseline
        if segment is not None:
            sel = self.kf_segment[self.dense_kf] == segment
            kf, partner, xyz, then = kf[sel], partner[sel], xyz[sel], then[sel]
        centres = self.kf_centres()
        if out is None:
            out = np.empty((kf.size, 3))
        elif out.shape != (kf.size, 3) or out.dtype != np.float64:
            raise ValueError(f"out must be a ({kf.size}, 3) float64 array")
        # Points are stored in runs of one keyframe pair: transform run by run.
        edges = np.flatnonzero(
            np.concatenate([[True], (kf[1:] != kf[:-1]) | (partner[1:] != partner[:-1]), [True]])
        )
        for a, b in itertools.pairwise(edges):
            k, p = kf[a], partner[a]
            base_now = float(np.linalg.norm(centres[k] - centres[p]))
            scale = base_now / then[a] if then[a] > 0 else 1.0
            # In place: no temporaries of millions of points (2 to 3 times faster).
            np.matmul(xyz[a:b], scale * self.kf_r[k], out=out[a:b])
            out[a:b] += centres[k]
        return out

    # -- changes -------------------------------------------------------------------
    def transform(
        self,
        scale: float,
        rotation: np.ndarray,
        translation: np.ndarray,
        segment: int | None = None,
    ) -> None:
        """Apply x' = s R x + t to the map, or to one segment of it (poses and points;
        dense points follow their keyframes, see `dense_points`)."""

        def move_poses(r: np.ndarray, tr: np.ndarray, sel: np.ndarray) -> None:
            centres = -np.einsum("nji,nj->ni", r[sel], tr[sel])
            new_c = scale * centres @ rotation.T + translation
            r[sel] = np.einsum("nij,kj->nik", r[sel], rotation)  # R_cw' = R_cw R^T
            tr[sel] = -np.einsum("nij,nj->ni", r[sel], new_c)

        kf_sel = self._segment_mask(self.kf_segment, segment)
        fr_sel = self._segment_mask(self.fr_segment, segment)
        pt_sel = self._segment_mask(self.point_segment, segment)
        move_poses(self.kf_r, self.kf_tr, kf_sel)
        move_poses(self.fr_r, self.fr_tr, fr_sel)
        self.fr_rel_t[fr_sel] = self.fr_rel_t[fr_sel] * scale
        self.point_xyz[pt_sel] = scale * self.point_xyz[pt_sel] @ rotation.T + translation

    @staticmethod
    def _segment_mask(values: np.ndarray, segment: int | None) -> np.ndarray:
        return np.ones(values.size, bool) if segment is None else values == segment

    def split_segment(self, segment: int, first_keyframe: int) -> int:
        """Make keyframe `first_keyframe` (an index into the keyframe arrays) and the
        later keyframes of `segment` a new segment; returns its number. Frames go with
        the keyframe they are posed relative to (those without one, by time); a sparse
        point with the keyframe of its first observation; dense points are in their
        keyframe's frame and go with it."""
        new = int(self.kf_segment.max()) + 1
        in_segment = self.kf_segment == segment
        moved = in_segment & (np.arange(self.kf_t.size) >= first_keyframe)
        self.kf_segment = np.where(moved, new, self.kf_segment).astype(self.kf_segment.dtype)
        frames = self.fr_segment == segment
        ref = self.fr_ref_kf
        follows = np.where(
            ref >= 0, moved[np.maximum(ref, 0)], self.fr_t >= self.kf_t[first_keyframe]
        )
        self.fr_segment = np.where(frames & follows, new, self.fr_segment).astype(
            self.fr_segment.dtype
        )
        points = np.flatnonzero(self.point_segment == segment)
        if points.size and self.obs_kf.size:
            order = np.lexsort((self.obs_kf, self.obs_point))
            ids, first = np.unique(self.obs_point[order], return_index=True)
            first_kf = self.obs_kf[order][first]
            at = np.searchsorted(ids, self.point_id[points])
            seen = (at < ids.size) & (ids[np.minimum(at, ids.size - 1)] == self.point_id[points])
            later = np.zeros(points.size, bool)
            later[seen] = moved[first_kf[at[seen]]]
            self.point_segment[points[later]] = new
        return new

    def update_frames_from_keyframes(self) -> None:
        """Recompute every non-keyframe pose from its reference keyframe's pose."""
        ref = self.fr_ref_kf
        ok = ref >= 0
        r_ref = self.kf_r[ref[ok]]
        t_ref = self.kf_tr[ref[ok]]
        self.fr_r[ok] = np.einsum("nij,njk->nik", self.fr_rel_r[ok], r_ref)
        self.fr_tr[ok] = np.einsum("nij,nj->ni", self.fr_rel_r[ok], t_ref) + self.fr_rel_t[ok]

    # -- files ---------------------------------------------------------------------
    # Per dense point, keyframe, partner and baseline repeat over long runs (a keyframe
    # pair's points): the file keeps them once per run (96 of 168 MB fewer to write and
    # read for 6M points).
    _DENSE_RUN_FIELDS = ("dense_kf", "dense_partner", "dense_baseline")

    def save(self, path: Path) -> None:
        arrays = {
            name: getattr(self, name)
            for name in self.__dataclass_fields__
            if name not in ("size", "stats", "readout_s")
        }
        runs = [np.asarray(getattr(self, name)) for name in self._DENSE_RUN_FIELDS]
        n = len(self.dense_xyz)
        if n and all(r.shape == (n,) for r in runs):
            change = np.zeros(n - 1, dtype=bool)
            for r in runs:
                change |= r[1:] != r[:-1]
            starts = np.concatenate([[0], np.flatnonzero(change) + 1]).astype(np.int64)
            arrays["dense_run_start"] = starts
            for name, r in zip(self._DENSE_RUN_FIELDS, runs, strict=True):
                del arrays[name]
                arrays[f"{name}_run"] = r[starts]
        import json

        meta = {"size": list(self.size), "stats": self.stats, "readout_s": self.readout_s}
        with atomic_path(Path(path)) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **arrays, meta=np.array(json.dumps(meta)))

    @classmethod
    def load(cls, path: Path) -> SparseMap:
        import json

        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            kwargs = {name: data[name] for name in data.files if name != "meta"}
        if "dense_run_start" in kwargs:  # (files from before the runs hold every value)
            starts = kwargs.pop("dense_run_start")
            counts = np.diff(np.append(starts, len(kwargs["dense_xyz"])))
            for name in cls._DENSE_RUN_FIELDS:
                kwargs[name] = np.repeat(kwargs.pop(f"{name}_run"), counts)
        # The readout is in the meta (a file written field by field may hold it too).
        readout = float(kwargs.pop("readout_s", meta.get("readout_s", 0.0)))
        return cls(size=tuple(meta["size"]), stats=meta["stats"], readout_s=readout, **kwargs)
