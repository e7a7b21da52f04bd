"""The texts of a report in its language, shared by the PDF and the HTML: the summary, the
change since the previous report, the landslide table's header and rows, and the
processing and parameter tables."""

from __future__ import annotations

from typing import Any

from worker.reports.data import DetectionRow, ReportData
from worker.reports.i18n import Catalogue, catalogue

COLUMNS = ("number", "area", "loss", "gain", "max_dh", "latitude", "longitude", "score")


def words_of(data: ReportData) -> Catalogue:
    return catalogue(data.language)


def created_text(data: ReportData) -> str:
    return words_of(data).time(data.created_at, data.timezone)


def meta_text(data: ReportData) -> str:
    words = words_of(data)
    return words.text(
        "report.meta",
        report=data.report_id,
        created=created_text(data),
        trigger=words.text(f"report.trigger.{data.trigger}"),
        comparison=data.comparison_id,
    )


def summary_text(data: ReportData) -> str:
    words, totals = words_of(data), data.totals
    return words.text(
        "report.summary_text",
        count=int(totals["detections"]),
        area=words.number(totals["total_area_m2"], 1),
        loss=words.number(totals["total_volume_loss_m3"], 1),
        gain=words.number(totals["total_volume_gain_m3"], 1),
        dh=words.number(totals["max_abs_dh_m"], 2),
    )


def change_text(data: ReportData) -> str:
    words, change = words_of(data), data.change
    if change is None or change.previous_report_id is None:
        return words.text("report.change.first")
    if change.previous_created_at is None:
        since = words.text("report.change.since", report=change.previous_report_id)
    else:
        since = words.text(
            "report.change.since_at",
            report=change.previous_report_id,
            created=words.time(change.previous_created_at, data.timezone),
        )
    if change.same_comparison:
        return words.text("report.change.same_comparison", since=since)
    return words.text(
        "report.change.counts",
        count=change.detections,
        since=since,
        detections=words.number(change.detections, 0, signed=True),
        area=words.number(change.total_area_m2, 1, signed=True),
        loss=words.number(change.total_volume_loss_m3, 1, signed=True),
        gain=words.number(change.total_volume_gain_m3, 1, signed=True),
    )


def table_header(data: ReportData) -> list[str]:
    words = words_of(data)
    return [words.text(f"report.column.{column}") for column in COLUMNS]


def table_row(data: ReportData, row: DetectionRow) -> list[str]:
    """One landslide's cells; its number is its label, 1…n in the comparison."""
    words = words_of(data)
    return [
        str(row.number),
        words.number(row.area_m2, 1),
        words.number(row.volume_loss_m3, 1),
        words.number(row.volume_gain_m3, 1),
        words.number(row.max_abs_dh_m, 2),
        words.number(row.centroid_lat, 6),
        words.number(row.centroid_lon, 6),
        words.number(row.score, 2),
    ]


def flatten(data: ReportData, values: dict[str, Any], prefix: str = "") -> list[tuple[str, str]]:
    """Nested values as (dotted.name, value) rows; the names are the API's, untranslated."""
    words = words_of(data)
    rows: list[tuple[str, str]] = []
    for key, value in values.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            rows += flatten(data, value, f"{name}.")
        elif isinstance(value, float):
            rows.append((name, f"{value:.4g}".replace(".", words.decimal)))
        else:
            rows.append((name, str(value)))
    return rows
