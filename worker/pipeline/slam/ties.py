"""Tie points between overlapping flight lines, for the bundle adjustment over the whole map.

The SLAM tracks points from frame to frame, so two neighbouring lines of a lawnmower
flight share points only through the turn between them: each line keeps its own small
drift of scale and height, and the DSM shows steps where lines meet and mounds too high
in one line and too low in the next (measured on the paper's mounds: strips a few
centimetres apart). The full bundle adjustment of the georeference stage can remove such
drift only if it sees the same ground points in both lines.

`tie_flight_lines` adds those observations to a `SparseMap`: for each keyframe, the
keyframes of other lines (far apart in time) whose camera centres are within
`max_offset_ratio` of the ground footprint are its partners. The sparse points the
keyframe observes are predicted in the partner image from the current poses; the partner
image is warped onto the keyframe's by the homography of the ground plane (lines flown
in opposite directions see the ground turned by 180 degrees), the points are tracked
there by pyramidal Lucas-Kanade from their predicted place, checked forwards and
backwards, and mapped back. A point found in the partner becomes one more observation of
that point, in that keyframe.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import cv2
import numpy as np

from worker.pipeline.ingest.video import VideoFrame
from worker.pipeline.slam.result import SparseMap
from worker.pipeline.slam.rolling_shutter import global_shutter_image


@dataclass
class TieOptions:
    enabled: bool = True
    min_gap_s: float = 4.0  # partners at least this far apart in time (another line)
    max_offset_ratio: float = 0.5  # centre distance / footprint width
    max_partners: int = 6  # measured on the mounds: 2 -> 6 took the DSM from 3.9 to 3.6 cm
    max_points: int = 300  # per keyframe, the most observed
    max_prediction_px: float = 25.0
    max_round_trip_px: float = 0.7
    window_px: int = 21


@dataclass
class TieReport:
    pairs: int
    observations: int
    points: int

    def to_dict(self) -> dict[str, int]:
        return {"pairs": self.pairs, "observations": self.observations, "points": self.points}


def keyframe_images(sparse: SparseMap, frames: Iterable[VideoFrame]) -> dict[int, np.ndarray]:
    """The grey image of every keyframe (by index), picked by time from `frames`, as a
    global shutter would have taken it where the map models a rolling shutter (its
    observations are)."""
    images: dict[int, np.ndarray] = {}
    times = sparse.kf_t
    for frame in frames:
        j = int(np.searchsorted(times, frame.t))
        for candidate in (j - 1, j):
            if 0 <= candidate < times.size and abs(times[candidate] - frame.t) < 1e-4:
                motion = sparse.keyframe_motion(candidate)
                images[candidate] = (
                    frame.image
                    if motion is None
                    else global_shutter_image(frame.image, sparse.k, sparse.readout_s, motion)
                )
    return images


def _ground_homography(
    k: np.ndarray, pose_a: tuple[np.ndarray, np.ndarray], pose_b: tuple[np.ndarray, np.ndarray],
    normal_a: np.ndarray, distance_a: float,
) -> np.ndarray:  # fmt: skip
    """Pixel homography from image a to image b of the plane n.X = d (in a's frame)."""
    r_a, t_a = pose_a
    r_b, t_b = pose_b
    r_ba = r_b @ r_a.T
    t_ba = t_b - r_ba @ t_a
    h = r_ba + np.outer(t_ba, normal_a) / distance_a
    return k @ h @ np.linalg.inv(k)


def _plane_in_camera(points_cam: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane n.X = d through points in a camera frame (n towards +z)."""
    centre = points_cam.mean(axis=0)
    normal = np.linalg.svd(points_cam - centre, full_matrices=False)[2][2]
    if normal[2] < 0:
        normal = -normal
    return normal, float(normal @ centre)


def tie_flight_lines(
    sparse: SparseMap,
    image_of: Callable[[int], np.ndarray | None],
    options: TieOptions | None = None,
) -> TieReport:
    """Add observations that tie overlapping flight lines (see the module doc); the map's
    observation arrays grow in place. `image_of(keyframe index)` gives its grey image."""
    options = options or TieOptions()
    if not options.enabled or sparse.kf_t.size < 2 or sparse.point_id.size == 0:
        return TieReport(0, 0, 0)
    k = sparse.k
    width, height = sparse.size
    centres = sparse.kf_centres()
    order = np.argsort(sparse.point_id)
    ids_sorted = sparse.point_id[order]
    observed = set(zip(sparse.obs_kf.tolist(), sparse.obs_point.tolist(), strict=True))
    by_kf = np.argsort(sparse.obs_kf, kind="stable")
    starts = np.searchsorted(sparse.obs_kf[by_kf], np.arange(sparse.kf_t.size + 1))
    new_kf: list[np.ndarray] = []
    new_pt: list[np.ndarray] = []
    new_uv: list[np.ndarray] = []
    pairs = 0
    images: dict[int, np.ndarray | None] = {}

    def image(index: int) -> np.ndarray | None:
        if index not in images:
            images[index] = image_of(index)
        return images[index]

    for a in range(sparse.kf_t.size):
        rows = by_kf[starts[a] : starts[a + 1]]
        if rows.size < 10:
            continue
        ids = sparse.obs_point[rows]
        pos = np.clip(np.searchsorted(ids_sorted, ids), 0, ids_sorted.size - 1)
        known = ids_sorted[pos] == ids
        segment = sparse.kf_segment[a]
        known &= sparse.point_segment[order[pos]] == segment
        if known.sum() < 10:
            continue
        ids, uv_a = ids[known], sparse.obs_uv[rows][known].astype(np.float32)
        xyz = sparse.point_xyz[order[pos[known]]]
        if ids.size > options.max_points:
            keep = np.linspace(0, ids.size - 1, options.max_points).astype(int)
            ids, uv_a, xyz = ids[keep], uv_a[keep], xyz[keep]
        r_a, t_a = sparse.kf_r[a], sparse.kf_tr[a]
        cam_a = xyz @ r_a.T + t_a
        depth = float(np.median(cam_a[:, 2]))
        if depth <= 0:
            continue
        footprint = depth * width / k[0, 0]
        distance = np.linalg.norm(centres - centres[a], axis=1)
        candidates = np.flatnonzero(
            (distance < options.max_offset_ratio * footprint)
            & (np.abs(sparse.kf_t - sparse.kf_t[a]) >= options.min_gap_s)
            & (sparse.kf_segment == segment)
        )
        candidates = candidates[np.argsort(distance[candidates])][: options.max_partners]
        normal, plane_d = _plane_in_camera(cam_a)
        for b in candidates.tolist():
            img_a, img_b = image(a), image(b)
            if img_a is None or img_b is None:
                continue
            found = _track_into(
                k, (r_a, t_a), (sparse.kf_r[b], sparse.kf_tr[b]), normal, plane_d,
                img_a, img_b, uv_a, xyz, (width, height), options,
            )  # fmt: skip
            fresh = [
                i for i in np.flatnonzero(found[0]).tolist() if (b, int(ids[i])) not in observed
            ]
            if not fresh:
                continue
            pairs += 1
            observed.update((b, int(ids[i])) for i in fresh)
            new_kf.append(np.full(len(fresh), b, np.int32))
            new_pt.append(ids[fresh])
            new_uv.append(found[1][fresh])
    if not new_kf:
        return TieReport(pairs, 0, 0)
    sparse.obs_kf = np.concatenate([sparse.obs_kf, *new_kf]).astype(sparse.obs_kf.dtype)
    sparse.obs_point = np.concatenate([sparse.obs_point, *new_pt]).astype(sparse.obs_point.dtype)
    sparse.obs_uv = np.concatenate([sparse.obs_uv, *new_uv]).astype(sparse.obs_uv.dtype)
    added = np.concatenate(new_pt)
    return TieReport(pairs, int(added.size), int(np.unique(added).size))


def _track_into(
    k: np.ndarray,
    pose_a: tuple[np.ndarray, np.ndarray],
    pose_b: tuple[np.ndarray, np.ndarray],
    normal: np.ndarray,
    plane_d: float,
    img_a: np.ndarray,
    img_b: np.ndarray,
    uv_a: np.ndarray,
    xyz: np.ndarray,
    size: tuple[int, int],
    options: TieOptions,
) -> tuple[np.ndarray, np.ndarray]:
    """(found mask, uv in image b) of the points seen at uv_a in image a."""
    width, height = size
    r_b, t_b = pose_b
    cam_b = xyz @ r_b.T + t_b
    in_front = cam_b[:, 2] > 0
    depth = np.where(in_front, cam_b[:, 2], 1.0)[:, None]
    predicted = cam_b[:, :2] / depth * np.diag(k)[:2] + k[:2, 2]
    margin = options.window_px
    inside = (
        in_front
        & (predicted[:, 0] > margin)
        & (predicted[:, 0] < width - margin)
        & (predicted[:, 1] > margin)
        & (predicted[:, 1] < height - margin)
    )
    found = np.zeros(len(uv_a), bool)
    uv_b = np.zeros((len(uv_a), 2), np.float32)
    if inside.sum() < 8:
        return found, uv_b
    # Image b warped into a's view by the ground plane: the points then sit near their
    # place in a, whatever the heading of the other line.
    h_ab = _ground_homography(k, pose_a, pose_b, normal, plane_d)
    h_ba = np.linalg.inv(h_ab)
    warped = cv2.warpPerspective(img_b, h_ba, (width, height), flags=cv2.INTER_LINEAR)
    start = _mapped(predicted[inside], h_ba).astype(np.float32).reshape(-1, 1, 2)
    src = uv_a[inside].reshape(-1, 1, 2)
    lk = {
        "winSize": (options.window_px, options.window_px),
        "maxLevel": 3,
        "criteria": (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01),
    }
    tracked, status, _ = cv2.calcOpticalFlowPyrLK(
        img_a, warped, src, start, flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk
    )
    back, status_back, _ = cv2.calcOpticalFlowPyrLK(
        warped, img_a, tracked, src.copy(), flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk
    )
    tracked = tracked.reshape(-1, 2)
    round_trip = np.linalg.norm(back.reshape(-1, 2) - uv_a[inside], axis=1)
    ok = (
        (status.ravel() == 1)
        & (status_back.ravel() == 1)
        & (round_trip < options.max_round_trip_px)
    )
    in_b = _mapped(tracked, h_ab)
    ok &= np.linalg.norm(in_b - predicted[inside], axis=1) < options.max_prediction_px
    ok &= (in_b[:, 0] >= 0) & (in_b[:, 0] < width) & (in_b[:, 1] >= 0) & (in_b[:, 1] < height)
    idx = np.flatnonzero(inside)
    found[idx[ok]] = True
    uv_b[idx[ok]] = in_b[ok].astype(np.float32)
    return found, uv_b


def _mapped(points: np.ndarray, homography: np.ndarray) -> np.ndarray:
    """(N, 2) points through a 3 x 3 homography."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 1, 2)
    return cv2.perspectiveTransform(pts, homography).reshape(-1, 2)
