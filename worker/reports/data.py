"""What a report shows, as plain values."""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class DetectionRow:
    number: int  # 1.. in the table and on the map
    id: int
    area_m2: float
    volume_loss_m3: float
    volume_gain_m3: float
    max_abs_dh_m: float
    centroid_lat: float
    centroid_lon: float
    score: float
    geometry: dict[str, Any]  # GeoJSON, WGS84 lon/lat


@dataclass(frozen=True)
class Change:
    """The report's totals against those of the site's previous report."""

    previous_report_id: int | None
    previous_created_at: datetime | None
    same_comparison: bool
    detections: int  # differences: this report minus the previous one
    total_area_m2: float
    total_volume_loss_m3: float
    total_volume_gain_m3: float


@dataclass
class ReportData:
    report_id: int
    site_name: str
    created_at: datetime
    trigger: str  # schedule | on_demand
    comparison_id: int
    pre_survey: str  # "survey 1 'June flight' (2026-06-01 10:00 UTC)", in the report's language
    post_survey: str
    dh_path: Path  # Δh raster (metric CRS)
    dsm_path: Path  # post DSM, for the hillshade
    detections: list[DetectionRow]
    change: Change | None
    parameters: dict[str, Any]  # comparison options, flattened or nested
    processing: dict[str, Any]  # what the stages measured (shift, NMAD, LoD, ...)
    model_version: str
    notes: list[str] = field(default_factory=list)
    # The site's IANA time zone: every time in the report is in it, as in the page.
    timezone: str = "UTC"
    # The language it is written in: a catalogue of worker/reports/catalogues.
    language: str = "en"

    @property
    def totals(self) -> dict[str, float]:
        return {
            "detections": len(self.detections),
            "total_area_m2": round(sum(d.area_m2 for d in self.detections), 2),
            "total_volume_loss_m3": round(sum(d.volume_loss_m3 for d in self.detections), 2),
            "total_volume_gain_m3": round(sum(d.volume_gain_m3 for d in self.detections), 2),
            "max_abs_dh_m": round(max((d.max_abs_dh_m for d in self.detections), default=0.0), 3),
        }
