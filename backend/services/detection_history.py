"""A detection's history: the detections of the site's other comparisons on the same
ground, in time order, so a landslide can be followed from survey to survey (growing,
retreating, or seen once).

Two detections are "the same ground" when their polygons overlap; the share of this
detection's area they cover says how much. Candidates are first narrowed by their
bounding boxes in the database, then intersected exactly (shapely, on a plane tangent at
the detection: shares of areas need no more).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime

import numpy as np
import shapely
from shapely.geometry import shape
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.db.detections import detection_labels
from backend.db.models import Comparison, Detection

EARTH_RADIUS_M = 6371008.8


@dataclass
class HistoryEntry:
    comparison_id: int
    detection_id: int
    label: int  # the detection's number in its comparison (1…n), as the page shows it
    pre_captured_at: datetime
    post_captured_at: datetime
    area_m2: float
    volume_loss_m3: float
    volume_gain_m3: float
    max_abs_dh_m: float
    score: float
    # Share of the asked detection's area this one covers (1.0 for the detection itself).
    overlap: float
    this: bool


def _local_plane(lon0: float, lat0: float) -> Callable[[np.ndarray], np.ndarray]:
    """Lon/lat (N x 2) to metres east and north of (lon0, lat0), on a tangent plane."""
    scale = np.array(
        [math.radians(1) * EARTH_RADIUS_M * math.cos(math.radians(lat0)),
         math.radians(1) * EARTH_RADIUS_M]
    )  # fmt: skip
    origin = np.array([lon0, lat0])

    def to_metres(lonlat: np.ndarray) -> np.ndarray:
        return (lonlat - origin) * scale

    return to_metres


def detection_history(session: Session, detection: Detection) -> list[HistoryEntry]:
    """This detection and every detection of the site's other comparisons that overlaps
    it, ordered by the post survey's time (then the pre survey's)."""
    comparison = detection.comparison
    candidates = session.scalars(
        select(Detection)
        .join(Comparison, Detection.comparison_id == Comparison.id)
        .where(
            Comparison.site_id == comparison.site_id,
            Detection.max_lon >= detection.min_lon,
            Detection.min_lon <= detection.max_lon,
            Detection.max_lat >= detection.min_lat,
            Detection.min_lat <= detection.max_lat,
        )
    ).all()
    plane = _local_plane(
        (detection.min_lon + detection.max_lon) / 2, (detection.min_lat + detection.max_lat) / 2
    )
    mine = shapely.transform(shape(detection.geometry), plane).buffer(0)
    entries = []
    for other in candidates:
        if other.id == detection.id:
            overlap = 1.0
        else:
            theirs = shapely.transform(shape(other.geometry), plane).buffer(0)
            shared = mine.intersection(theirs).area
            if shared <= 0 or mine.area <= 0:
                continue
            overlap = shared / mine.area
        owner = other.comparison
        entries.append(
            HistoryEntry(
                comparison_id=owner.id,
                detection_id=other.id,
                label=detection_labels(owner)[other.id],
                pre_captured_at=owner.pre_survey.captured_at,
                post_captured_at=owner.post_survey.captured_at,
                area_m2=other.area_m2,
                volume_loss_m3=other.volume_loss_m3,
                volume_gain_m3=other.volume_gain_m3,
                max_abs_dh_m=other.max_abs_dh_m,
                score=other.score,
                overlap=round(overlap, 4),
                this=other.id == detection.id,
            )
        )
    entries.sort(key=lambda e: (e.post_captured_at, e.pre_captured_at, e.comparison_id))
    return entries
