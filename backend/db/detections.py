"""Detection rows from and to the library's one detection record (detection_record.py).

A comparison's detections are stored once, as rows; the detections product file and the
API's GeoJSON are both written from the rows by `detection_feature`, so they have the same
ids and the same field names.
"""

from collections.abc import Mapping
from typing import Any

from backend.db.models import Comparison, Detection
from worker.pipeline import detection_record
from worker.pipeline.detection_methods import detection_method
from worker.pipeline.detection_record import DetectionProperties, Uncertainty
from worker.pipeline.errors import InputError


def detection_row(
    comparison_id: int, geometry: dict[str, Any], properties: DetectionProperties
) -> Detection:
    min_lon, min_lat, max_lon, max_lat = detection_record.geometry_bbox(geometry)
    uncertainty = properties.to_dict()["uncertainty"]
    return Detection(
        comparison_id=comparison_id,
        geometry=geometry,
        min_lon=min_lon,
        min_lat=min_lat,
        max_lon=max_lon,
        max_lat=max_lat,
        area_m2=properties.area_m2,
        volume_loss_m3=properties.volume_loss_m3,
        volume_gain_m3=properties.volume_gain_m3,
        max_abs_dh_m=properties.max_abs_dh_m,
        score=properties.score,
        method=properties.method,
        model_version=properties.model_version,
        uncertainty=uncertainty,
    )


def detection_properties(row: Detection) -> DetectionProperties:
    return DetectionProperties(
        area_m2=row.area_m2,
        volume_loss_m3=row.volume_loss_m3,
        volume_gain_m3=row.volume_gain_m3,
        max_abs_dh_m=row.max_abs_dh_m,
        score=row.score,
        method=row.method,
        model_version=row.model_version,
        uncertainty=Uncertainty.from_dict(row.uncertainty) if row.uncertainty else None,
    )


def detection_labels(comparison: Comparison) -> dict[int, int]:
    """Each detection's label, 1…n within its comparison: the one number people see.

    The rows are stored in the order the detection stage numbered them (largest first), so
    their id order is that numbering; the page, the GeoJSON, the exports, the alerts and the
    report all use this label rather than the database id, which runs on across comparisons.
    """
    return {row.id: number for number, row in enumerate(comparison.detections, start=1)}


def detection_feature(
    row: Detection, extra: dict[str, Any] | None = None, label: int | None = None
) -> dict[str, Any]:
    """The row as a GeoJSON Feature: its id, its record, its comparison, its label (and
    `extra`)."""
    members: dict[str, Any] = {"comparison_id": row.comparison_id}
    if label is not None:
        members["label"] = label
    return detection_record.detection_feature(
        row.id, row.geometry, detection_properties(row), {**members, **(extra or {})}
    )


def detection_model(comparison: Comparison, results: Mapping[str, Mapping[str, Any]]) -> str | None:
    """ "name@version" of the model that found (or will find) the detections, if any.

    The one the detection stage ran (`results`: stage name -> result; scored: its scorer;
    cnn: its network), else, before it has run, the registered model kept in the
    parameters at creation (cnn); none for a method without a model (threshold), or for a
    method whose module this process has not loaded.
    """
    try:
        method = detection_method(comparison.method)
    except InputError:
        return None
    ran = (results.get(method.stage.name) or {}).get("model")
    return ran or ((comparison.parameters or {}).get(method.options_key) or {}).get("model")
