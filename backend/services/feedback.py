"""People's verdicts on detections (confirmed landslide or false alarm), and their export
as training labels for the detection model."""

from datetime import UTC, datetime
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.db.models import (
    ApiToken,
    Comparison,
    Detection,
    DetectionFeedback,
    Product,
    Verdict,
)
from backend.services.users import author_of

# 1 = landslide, 0 = not one: the label convention of worker/pipeline/cnn.
LABELS = {Verdict.confirmed: 1, Verdict.false_alarm: 0}


def give_verdict(
    session: Session, detection: Detection, token: ApiToken, verdict: Verdict, note: str
) -> DetectionFeedback:
    """Record (or change) this person's verdict on the detection."""
    author = author_of(token)
    now = datetime.now(UTC)
    feedback = session.scalar(
        select(DetectionFeedback).where(
            DetectionFeedback.detection_id == detection.id, DetectionFeedback.author == author
        )
    )
    if feedback is None:
        feedback = DetectionFeedback(
            detection_id=detection.id, author=author, user_id=token.user_id, created_at=now
        )
        session.add(feedback)
    feedback.verdict, feedback.note, feedback.updated_at = verdict, note, now
    session.commit()
    return feedback


def withdraw_verdict(session: Session, detection: Detection, token: ApiToken) -> bool:
    feedback = session.scalar(
        select(DetectionFeedback).where(
            DetectionFeedback.detection_id == detection.id,
            DetectionFeedback.author == author_of(token),
        )
    )
    if feedback is None:
        return False
    session.delete(feedback)
    session.commit()
    return True


def feedback_summary(detection: Detection) -> dict[str, Any]:
    """Counts of each verdict and the latest one, for the detection's GeoJSON properties."""
    counts = {v.value: 0 for v in Verdict}
    for feedback in detection.feedback:
        counts[feedback.verdict.value] += 1
    latest = max(detection.feedback, key=lambda f: f.updated_at, default=None)
    return {
        **counts,
        "latest": None
        if latest is None
        else {
            "verdict": latest.verdict.value,
            "author": latest.author,
            "at": latest.updated_at.isoformat(),
        },
    }


def _dsm_product_ids(session: Session, comparison: Comparison) -> dict[str, int | None]:
    ids = {}
    for role, survey_id in (("pre", comparison.pre_survey_id), ("post", comparison.post_survey_id)):
        ids[f"{role}_dsm_product_id"] = session.scalar(
            select(Product.id).where(Product.survey_id == survey_id, Product.kind == "dsm")
        )
    return ids


def training_labels(session: Session, site_id: int) -> dict[str, Any]:
    """Every verdict of the site as a GeoJSON FeatureCollection: the detection's polygon
    (WGS84 lon/lat), `label` 1 confirmed / 0 false alarm, who and when, and what it was
    detected on (comparison, surveys, their DSM products, method)."""
    rows = session.execute(
        select(DetectionFeedback, Detection, Comparison)
        .join(Detection, DetectionFeedback.detection_id == Detection.id)
        .join(Comparison, Detection.comparison_id == Comparison.id)
        .where(Comparison.site_id == site_id)
        .order_by(DetectionFeedback.id)
    ).all()
    products: dict[int, dict[str, int | None]] = {}
    features = []
    for feedback, detection, comparison in rows:
        if comparison.id not in products:
            products[comparison.id] = _dsm_product_ids(session, comparison)
        features.append(
            {
                "type": "Feature",
                "id": feedback.id,
                "geometry": detection.geometry,
                "properties": {
                    "label": LABELS[feedback.verdict],
                    "verdict": feedback.verdict.value,
                    "note": feedback.note,
                    "author": feedback.author,
                    "at": feedback.updated_at.isoformat(),
                    "detection_id": detection.id,
                    "comparison_id": comparison.id,
                    "pre_survey_id": comparison.pre_survey_id,
                    "post_survey_id": comparison.post_survey_id,
                    **products[comparison.id],
                    "method": detection.method,
                    "model_version": detection.model_version,
                    "score": detection.score,
                    "area_m2": detection.area_m2,
                    "max_abs_dh_m": detection.max_abs_dh_m,
                },
            }
        )
    return {"type": "FeatureCollection", "features": features}
