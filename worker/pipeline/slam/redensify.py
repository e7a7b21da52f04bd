"""Dense pairs matched again once the georeference has corrected their cameras.

SLAM matches each keyframe with its partners while it tracks, on the poses it has then.
Where those poses are wrong (a steep descent that monocular tracking took for motion
along the optical axis: 83° from level where the flight descended at 60°; a stretch
whose scale collapsed), the pair's heights are wrong or missing, and the adjustment
against the log that corrects the cameras afterwards cannot correct them: they were
measured along the wrong epipolar lines. This step compares each pair's relative pose
before and after the georeference, matches again the pairs whose baseline or relative
orientation turned by more than matching tolerates (their old points are dropped
whatever the new match gives), and gives partners on the corrected poses to keyframes
that were left without any.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from worker.pipeline.slam.densify import DensifyOptions, densify_pair, stereo_partners
from worker.pipeline.slam.result import SparseMap


@dataclass
class RedensifyOptions:
    enabled: bool = True
    # A pair is matched again when, between the tracked and the georeferenced poses, its
    # baseline turns by more than this in the first camera's frame, or the second camera
    # turns by more than this relative to the first. On three flights whose tracking held
    # (mounds, 755 pairs) the georeference moved no pair by more than 2.5° and 0.55°; a
    # rotation error of 1° between the views already puts the epipolar lines 7 pixels
    # off at 427 px focal length, beyond what SGBM searches across.
    max_baseline_turn_deg: float = 4.0
    max_relative_turn_deg: float = 1.0
    # Partners on the corrected poses for keyframes SLAM left without a pair (among this
    # many keyframes on either side), only where the log states its positions to this or
    # better, or the user declares it does (RTK): where tracking failed, the baselines
    # between such keyframes come from the log, and a stand-alone log's metres do not fix
    # a 2-m baseline's direction. On 24 mounds flights (seeds 101-124) it took one RTK
    # flight past its overlap bound and harmed none; on stand-alone flights it gave two of
    # 14 DSMs steps of 0.3-0.75 m where such a stretch met the rest (seeds 103 and 303:
    # after shift + tilt 1.21 -> 1.86 px).
    unpaired_max_sigma_m: float = 0.1
    neighbours: int = 12


@dataclass
class RedensifyPlan:
    """Keyframe index pairs (keyframe, partner) of the georeferenced map: `redo`, the
    pairs whose points are dropped and matched again; `new`, partners for keyframes
    left without a pair."""

    redo: list[tuple[int, int]] = field(default_factory=list)
    new: list[tuple[int, int]] = field(default_factory=list)

    def keyframes(self) -> set[int]:
        """Every keyframe whose image the plan needs."""
        return {k for pair in [*self.redo, *self.new] for k in pair}


@dataclass
class RedensifyReport:
    pairs_matched_again: int
    keyframes_paired: int
    points_dropped: int
    points_added: int

    def to_dict(self) -> dict[str, int]:
        return {
            "pairs_matched_again": self.pairs_matched_again,
            "keyframes_paired": self.keyframes_paired,
            "points_dropped": self.points_dropped,
            "points_added": self.points_added,
        }


def _turn_deg(u: np.ndarray, v: np.ndarray) -> float:
    cos = float(u @ v) / max(float(np.linalg.norm(u) * np.linalg.norm(v)), 1e-12)
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def _rotation_deg(r: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0))))


def _pairs(sparse: SparseMap) -> list[tuple[int, int]]:
    """The map's dense pairs, each once (their points lie in runs: read at run starts)."""
    kf, partner = sparse.dense_kf, sparse.dense_partner
    if kf.size == 0:
        return []
    starts = np.flatnonzero(
        np.concatenate([[True], (kf[1:] != kf[:-1]) | (partner[1:] != partner[:-1])])
    )
    return sorted({(int(kf[i]), int(partner[i])) for i in starts})


@dataclass(frozen=True)
class KeyframePoses:
    """Keyframe times and world-to-camera poses: a map's keyframes as they were."""

    t: np.ndarray
    r: np.ndarray
    tr: np.ndarray

    @classmethod
    def of(cls, sparse: SparseMap) -> KeyframePoses:
        return cls(sparse.kf_t.copy(), sparse.kf_r.copy(), sparse.kf_tr.copy())

    def centres(self) -> np.ndarray:
        return -np.einsum("nji,nj->ni", self.r, self.tr)


def plan_redensify(
    tracked: KeyframePoses,
    adjusted: SparseMap,
    options: RedensifyOptions | None = None,
    densify: DensifyOptions | None = None,
    log_sigma_m: float | None = None,
) -> RedensifyPlan:
    """What to match again in `adjusted` (the georeferenced map), against `tracked` (its
    keyframes as SLAM left them; matched by time, since the georeference may have
    dropped segments and renumbered the rest). With the log's stated horizontal sigma
    `log_sigma_m` within `unpaired_max_sigma_m`, a keyframe without a pair gets the
    partners `densify` chooses on the corrected poses where its geometry with them
    moved as a pair to redo would: on unchanged poses, SLAM's attempt stands."""
    options = options or RedensifyOptions()
    densify = densify or DensifyOptions()
    index = {float(t): i for i, t in enumerate(tracked.t.tolist())}
    before = tracked.centres()
    after = adjusted.kf_centres()

    def moved(a: int, b: int) -> bool:
        a0, b0 = index.get(float(adjusted.kf_t[a])), index.get(float(adjusted.kf_t[b]))
        if a0 is None or b0 is None:
            return True
        baseline_then = tracked.r[a0] @ (before[b0] - before[a0])
        baseline_now = adjusted.kf_r[a] @ (after[b] - after[a])
        relative_then = tracked.r[b0] @ tracked.r[a0].T
        relative_now = adjusted.kf_r[b] @ adjusted.kf_r[a].T
        return (
            _turn_deg(baseline_then, baseline_now) > options.max_baseline_turn_deg
            or _rotation_deg(relative_now @ relative_then.T) > options.max_relative_turn_deg
        )

    plan = RedensifyPlan(redo=[(a, b) for a, b in _pairs(adjusted) if moved(a, b)])
    bound = options.unpaired_max_sigma_m
    if log_sigma_m is None or bound is None or log_sigma_m > bound:
        return plan
    paired = set(adjusted.dense_kf.tolist())
    for a in range(adjusted.kf_t.size):
        seen = adjusted.observed_points(a)
        if a in paired or len(seen) < 20:
            continue
        depth = float(np.median(seen[:, 2]))
        ratios = {
            i: float(np.linalg.norm(after[i] - after[a])) / depth
            for i in _candidates(adjusted, a, options.neighbours)
        }
        partners = stereo_partners(ratios, densify)
        if any(moved(a, b) for b in partners):
            plan.new += [(a, b) for b in partners]
    return plan


def _candidates(sparse: SparseMap, a: int, neighbours: int) -> list[int]:
    """Keyframes of `a`'s segment within `neighbours` of it, itself left out."""
    lo, hi = max(0, a - neighbours), min(sparse.kf_t.size, a + neighbours + 1)
    return [i for i in range(lo, hi) if i != a and sparse.kf_segment[i] == sparse.kf_segment[a]]


def redensify(
    sparse: SparseMap,
    images: dict[int, np.ndarray],
    plan: RedensifyPlan,
    densify: DensifyOptions | None = None,
) -> RedensifyReport:
    """Carry out `plan` on `sparse` in place with the keyframes' grey `images` (by
    index; a pair without its images is left out, and a pair to redo loses its points
    all the same)."""
    densify = densify or DensifyOptions()
    redo = set(plan.redo)
    n_kf = max(sparse.kf_t.size, 1)
    pair_key = sparse.dense_kf.astype(np.int64) * n_kf + sparse.dense_partner
    keep = ~np.isin(pair_key, [a * n_kf + b for a, b in redo])
    del pair_key
    dropped = int((~keep).sum())
    centres = sparse.kf_centres()
    # The pairs of one keyframe sample different pixels (densify_pair's phase).
    nth: dict[int, int] = {}
    jobs = []
    for a, b in [*sorted(redo), *plan.new]:
        jobs.append((a, b, nth.get(a, 0)))
        nth[a] = nth.get(a, 0) + 1
    parts_kf, parts_partner, parts_xyz, parts_baseline = [], [], [], []
    for a, b, n in jobs:
        if a not in images or b not in images:
            continue
        pose_a = (sparse.kf_r[a], sparse.kf_tr[a])
        pose_b = (sparse.kf_r[b], sparse.kf_tr[b])
        pts = densify_pair(
            images[a],
            images[b],
            sparse.k,
            pose_a,
            pose_b,
            sparse.observed_points(a),
            densify,
            a + n,
        )
        if len(pts) == 0:
            continue
        parts_kf.append(np.full(len(pts), a, np.int32))
        parts_partner.append(np.full(len(pts), b, np.int32))
        parts_xyz.append(pts)
        parts_baseline.append(np.full(len(pts), float(np.linalg.norm(centres[b] - centres[a]))))
    added = sum(len(p) for p in parts_xyz)
    paired = len({int(k[0]) for k in parts_kf} & {a for a, _ in plan.new})
    sparse.dense_kf = np.concatenate([sparse.dense_kf[keep], *parts_kf]).astype(np.int32)
    sparse.dense_partner = np.concatenate([sparse.dense_partner[keep], *parts_partner]).astype(
        np.int32
    )
    sparse.dense_xyz = np.concatenate([sparse.dense_xyz[keep].reshape(-1, 3), *parts_xyz]).astype(
        np.float32
    )
    sparse.dense_baseline = np.concatenate([sparse.dense_baseline[keep], *parts_baseline])
    return RedensifyReport(
        pairs_matched_again=len(redo),
        keyframes_paired=paired,
        points_dropped=dropped,
        points_added=added,
    )
