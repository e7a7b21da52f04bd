"""KLT feature tracking with persistent ids (OpenCV pyramidal Lucas-Kanade).

Each frame is tracked from the previous one, forward and backward (tracks whose round
trip misses by more than `fb_threshold_px` are dropped); new corners are detected only
when asked (at keyframes), away from existing tracks, so every track id starts at a
keyframe.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass
class TrackerOptions:
    max_points: int = 800
    min_distance_px: int = 12
    quality: float = 0.005
    window_px: int = 15
    levels: int = 2
    fb_threshold_px: float = 1.0
    border_px: int = 4
    flow_guess_px: float = 12.0  # start LK from the last median motion when above this


class KltTracker:
    def __init__(self, options: TrackerOptions | None = None):
        self.options = options or TrackerOptions()
        self.ids = np.empty(0, dtype=np.int64)
        self.pts = np.empty((0, 2), dtype=np.float32)
        self.next_id = 0
        self._prev: np.ndarray | None = None
        self._flow = np.zeros(2, dtype=np.float32)  # last median displacement
        self._shape: tuple[int, int] | None = None

    def track(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Track the current points into `gray`; returns (ids, points)."""
        o = self.options
        self._shape = gray.shape
        if self._prev is not None and len(self.pts):
            p0 = self.pts.reshape(-1, 1, 2)
            criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.03)
            win = (o.window_px, o.window_px)
            # Fast video: start from the last frame's median motion so that it stays
            # within reach of a shallow pyramid (slow video tracks better without).
            fast = float(np.hypot(*self._flow)) > o.flow_guess_px
            flow = self._flow if fast else np.zeros(2, np.float32)
            guess = (p0 + flow).astype(np.float32)
            p1, st1, _ = cv2.calcOpticalFlowPyrLK(
                self._prev,
                gray,
                p0,
                guess,
                winSize=win,
                maxLevel=o.levels,
                criteria=criteria,
                flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
            )
            p0b, st2, _ = cv2.calcOpticalFlowPyrLK(
                gray,
                self._prev,
                p1,
                (p1 - flow).astype(np.float32),
                winSize=win,
                maxLevel=o.levels,
                criteria=criteria,
                flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
            )
            fb = np.linalg.norm((p0b - p0).reshape(-1, 2), axis=1)
            p1 = p1.reshape(-1, 2)
            h, w = gray.shape
            b = o.border_px
            ok = (
                (st1.ravel() == 1)
                & (st2.ravel() == 1)
                & (fb < o.fb_threshold_px)
                & (p1[:, 0] >= b)
                & (p1[:, 0] < w - b)
                & (p1[:, 1] >= b)
                & (p1[:, 1] < h - b)
            )
            if ok.sum() >= 5:
                self._flow = np.median(p1[ok] - self.pts[ok], axis=0).astype(np.float32)
            self.ids, self.pts = self.ids[ok], p1[ok].astype(np.float32)
        self._prev = gray
        return self.ids, self.pts

    def detect(self, gray: np.ndarray) -> int:
        """Add corners away from existing tracks, up to `max_points`; returns how many."""
        o = self.options
        room = o.max_points - len(self.pts)
        if room <= o.max_points // 20:
            return 0
        mask = np.full(gray.shape, 255, dtype=np.uint8)
        b = o.border_px + 2
        mask[:b], mask[-b:], mask[:, :b], mask[:, -b:] = 0, 0, 0, 0
        for x, y in self.pts.astype(int):
            cv2.circle(mask, (int(x), int(y)), o.min_distance_px, 0, -1)
        corners = cv2.goodFeaturesToTrack(
            gray, room, o.quality, o.min_distance_px, mask=mask, blockSize=7
        )
        if corners is None:
            return 0
        corners = corners.reshape(-1, 2).astype(np.float32)
        new_ids = np.arange(self.next_id, self.next_id + len(corners), dtype=np.int64)
        self.next_id += len(corners)
        self.ids = np.concatenate([self.ids, new_ids])
        self.pts = np.vstack([self.pts, corners])
        return len(corners)

    def remove(self, ids: np.ndarray) -> None:
        if len(ids):
            keep = ~np.isin(self.ids, ids)
            self.ids, self.pts = self.ids[keep], self.pts[keep]
