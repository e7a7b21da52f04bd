"""One detection record for every method: its properties, its GeoJSON feature, its file.

Every detection stage (threshold, scored, cnn and any registered method) builds its polygons'
properties as a `DetectionProperties` and writes them with `write_detections`, so the
detections.geojson of a comparison has the same fields whatever the method, and the same
field names as the API's detections (the platform stores them as rows and writes the
product file again from the rows, with their ids).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import shapely
from shapely.geometry import shape

from worker.pipeline.atomic import write_text_atomic
from worker.pipeline.geo import crs_to_string

Interval = tuple[float, float]


@dataclass(frozen=True)
class Uncertainty:
    """95 % intervals of area and volumes, and the median LoD95 over the polygon."""

    area_m2_ci95: Interval
    volume_loss_m3_ci95: Interval
    volume_gain_m3_ci95: Interval
    lod_m: float

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Uncertainty:
        return cls(
            area_m2_ci95=_interval(data["area_m2_ci95"]),
            volume_loss_m3_ci95=_interval(data["volume_loss_m3_ci95"]),
            volume_gain_m3_ci95=_interval(data["volume_gain_m3_ci95"]),
            lod_m=float(data["lod_m"]),
        )


@dataclass(frozen=True)
class DetectionProperties:
    """What slidewatch says about one detected landslide.

    `score`: the method's confidence 0-1 (a calibrated probability for scored and cnn);
    `model_version`: "name@version" of the model that found it (None: no model, threshold);
    `uncertainty`: None where the method gives no intervals (cnn).
    """

    area_m2: float
    volume_loss_m3: float
    volume_gain_m3: float
    max_abs_dh_m: float
    score: float
    method: str
    model_version: str | None = None
    uncertainty: Uncertainty | None = None

    def to_dict(self) -> dict[str, Any]:
        data = dataclasses.asdict(self)
        if self.uncertainty is not None:
            data["uncertainty"] = {
                key: list(value) if isinstance(value, tuple) else value
                for key, value in data["uncertainty"].items()
            }
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> DetectionProperties:
        """From a feature's properties (extra members, e.g. the API's, are ignored)."""
        uncertainty = data.get("uncertainty")
        return cls(
            area_m2=float(data["area_m2"]),
            volume_loss_m3=float(data["volume_loss_m3"]),
            volume_gain_m3=float(data["volume_gain_m3"]),
            max_abs_dh_m=float(data["max_abs_dh_m"]),
            score=float(data["score"]),
            method=str(data["method"]),
            model_version=data.get("model_version"),
            uncertainty=Uncertainty.from_dict(uncertainty) if uncertainty else None,
        )


def detection_feature(
    detection_id: int | None,
    geometry: dict[str, Any],
    properties: DetectionProperties,
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """A GeoJSON Feature (geometry in WGS84 lon/lat) with the record's properties.

    `extra` adds members the API serves beside the record (comparison id, feedback).
    """
    feature: dict[str, Any] = {"type": "Feature"}
    if detection_id is not None:
        feature["id"] = detection_id
    feature["bbox"] = geometry_bbox(geometry)
    feature["geometry"] = geometry
    feature["properties"] = {**properties.to_dict(), **(extra or {})}
    return feature


def write_detections(
    out_geojson: Path,
    detections: list[tuple[dict[str, Any], DetectionProperties]],
    metric_crs: Any,
) -> dict[str, Any]:
    """Number the detections (largest first) and write the FeatureCollection atomically.

    `detections`: (WGS84 geometry, properties) pairs; `metric_crs`: where area_m2 was
    measured, kept as a foreign member of the collection.
    """
    ordered = sorted(detections, key=lambda d: (-d[1].area_m2, geometry_bbox(d[0])))
    collection = {
        "type": "FeatureCollection",
        "features": [
            detection_feature(number, geometry, properties)
            for number, (geometry, properties) in enumerate(ordered, start=1)
        ],
        "metric_crs": crs_to_string(metric_crs),
    }
    write_text_atomic(Path(out_geojson), json.dumps(collection, separators=(",", ":")))
    return collection


def read_detections(path: Path) -> list[tuple[dict[str, Any], DetectionProperties]]:
    """The (geometry, properties) pairs of a detections.geojson, in its order."""
    collection = json.loads(Path(path).read_text(encoding="utf-8"))
    return [
        (feature["geometry"], DetectionProperties.from_dict(feature["properties"]))
        for feature in collection["features"]
    ]


def geometry_bbox(geometry: dict[str, Any]) -> list[float]:
    """[min lon, min lat, max lon, max lat] of a GeoJSON geometry, rounded to 1e-7 deg."""
    coordinates = shapely.get_coordinates(shape(geometry))
    low, high = coordinates.min(axis=0), coordinates.max(axis=0)
    return [round(float(v), 7) for v in (*low, *high)]


def _interval(values: Any) -> Interval:
    low, high = values
    return float(low), float(high)
