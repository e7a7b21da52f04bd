"""A one-segment keyframe map made in memory for the reconstruction tests."""

import numpy as np

from worker.pipeline.slam.result import SparseMap


def keyframe_map(
    k: np.ndarray,
    size: tuple[int, int],
    r: np.ndarray,
    tr: np.ndarray,
    obs_kf: list[int],
    obs_point: list[int],
    points: np.ndarray,
) -> SparseMap:
    """Keyframes at times 0, 1, ... with world-to-camera poses (r, tr), all in segment
    0, observing `points` as (obs_kf, obs_point) say (image positions left at zero)."""
    return SparseMap.from_keyframes(
        k,
        size,
        t=np.arange(len(r), dtype=float),
        r=r,
        tr=tr,
        segment=np.zeros(len(r)),
        obs_kf=np.array(obs_kf),
        obs_point=np.array(obs_point),
        obs_uv=np.zeros((len(obs_kf), 2)),
        point_id=np.arange(len(points)),
        point_xyz=points,
        point_segment=np.zeros(len(points)),
    )
