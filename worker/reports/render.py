"""Render a report as PDF (reportlab) and HTML (Jinja2), with the site map figure.

The PDF embeds matplotlib's DejaVu Sans as a TrueType font, so "Δh", "m²", "m³", "−" and
"|Δh|" render and can be extracted as text; no system font is needed.
"""

from __future__ import annotations

import base64
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import cache
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

import matplotlib
from jinja2 import Environment, FileSystemLoader, select_autoescape
from reportlab.lib import colors
from reportlab.lib.enums import TA_LEFT
from reportlab.lib.pagesizes import A4
from reportlab.lib.styles import ParagraphStyle
from reportlab.lib.units import mm
from reportlab.pdfbase import pdfmetrics
from reportlab.pdfbase.ttfonts import TTFont
from reportlab.platypus import (
    Image,
    Paragraph,
    SimpleDocTemplate,
    Spacer,
    Table,
    TableStyle,
)

from worker.pipeline.atomic import atomic_path
from worker.reports.data import ReportData
from worker.reports.figure import site_map

FONT, FONT_BOLD = "DejaVuSans", "DejaVuSans-Bold"
TEMPLATES = Path(__file__).parent / "templates"


@dataclass(frozen=True)
class ReportFiles:
    pdf: Path
    html: Path
    figure: Path


@cache
def register_fonts() -> None:
    fonts = Path(matplotlib.get_data_path()) / "fonts" / "ttf"
    pdfmetrics.registerFont(TTFont(FONT, str(fonts / "DejaVuSans.ttf")))
    pdfmetrics.registerFont(TTFont(FONT_BOLD, str(fonts / "DejaVuSans-Bold.ttf")))
    pdfmetrics.registerFontFamily(FONT, normal=FONT, bold=FONT_BOLD)


def local_time(moment: datetime, timezone: str = "UTC") -> str:
    """The time in the site's zone, named, as the page shows it: "2026-06-01 19:00 JST"."""
    moment = moment if moment.tzinfo else moment.replace(tzinfo=UTC)
    try:
        zone = ZoneInfo(timezone)
    except (ZoneInfoNotFoundError, ValueError):
        zone = ZoneInfo("UTC")  # a report is still made; the zone is named below
    return moment.astimezone(zone).strftime("%Y-%m-%d %H:%M %Z")


def _flatten(values: dict[str, Any], prefix: str = "") -> list[tuple[str, str]]:
    rows: list[tuple[str, str]] = []
    for key, value in values.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            rows += _flatten(value, f"{name}.")
        elif isinstance(value, float):
            rows.append((name, f"{value:.4g}"))
        else:
            rows.append((name, str(value)))
    return rows


def change_text(data: ReportData) -> str:
    change = data.change
    if change is None or change.previous_report_id is None:
        return "This is the first report of the site."
    since = f"report {change.previous_report_id}"
    if change.previous_created_at is not None:
        since += f" ({local_time(change.previous_created_at, data.timezone)})"
    if change.same_comparison:
        return f"No new comparison since {since}: the landslides are those reported then."
    return (
        f"Since {since}: {change.detections:+d} "
        f"landslide{'' if abs(change.detections) == 1 else 's'}, "
        f"area {change.total_area_m2:+.1f} m², loss {change.total_volume_loss_m3:+.1f} m³, "
        f"gain {change.total_volume_gain_m3:+.1f} m³."
    )


def _trigger(data: ReportData) -> str:
    return "scheduled" if data.trigger == "schedule" else "on demand"


def _summary_text(data: ReportData) -> str:
    t = data.totals
    plural = "" if t["detections"] == 1 else "s"
    return (
        f"{t['detections']} landslide{plural} detected: total area {t['total_area_m2']:.1f} m², "
        f"loss {t['total_volume_loss_m3']:.1f} m³, gain {t['total_volume_gain_m3']:.1f} m³, "
        f"largest |Δh| {t['max_abs_dh_m']:.2f} m."
    )


def render_pdf(data: ReportData, figure: Path, out_pdf: Path) -> Path:
    register_fonts()
    body = ParagraphStyle("body", fontName=FONT, fontSize=9.5, leading=12.5, alignment=TA_LEFT)
    small = ParagraphStyle("small", parent=body, fontSize=8, leading=10, textColor=colors.grey)
    h1 = ParagraphStyle("h1", parent=body, fontName=FONT_BOLD, fontSize=15, leading=19)
    h2 = ParagraphStyle(
        "h2", parent=body, fontName=FONT_BOLD, fontSize=11, leading=14, spaceBefore=8
    )
    cell = ParagraphStyle("cell", parent=body, fontSize=8, leading=10)

    story: list[Any] = [
        Paragraph(f"Landslide monitoring report: {_escape(data.site_name)}", h1),
        Paragraph(
            f"Report {data.report_id} · {local_time(data.created_at, data.timezone)} · "
            f"{_trigger(data)} · comparison {data.comparison_id}",
            small,
        ),
        Paragraph(f"Before: {_escape(data.pre_survey)}", small),
        Paragraph(f"After: {_escape(data.post_survey)}", small),
        Paragraph(f"Times in {_escape(data.timezone)}.", small),
        Spacer(1, 4 * mm),
        Paragraph(_summary_text(data), body),
    ]
    story += [Paragraph(f"<i>{_escape(note)}</i>", body) for note in data.notes]
    width = A4[0] - 36 * mm
    story += [Spacer(1, 3 * mm), Image(str(figure), width=width, height=width * 5.6 / 7.2)]

    story.append(Paragraph("Landslides", h2))
    if data.detections:
        header = ["#", "Area (m²)", "Loss (m³)", "Gain (m³)", "max |Δh| (m)", "Lat", "Lon", "Score"]
        rows = [header] + [
            [
                str(r.number),
                f"{r.area_m2:.1f}",
                f"{r.volume_loss_m3:.1f}",
                f"{r.volume_gain_m3:.1f}",
                f"{r.max_abs_dh_m:.2f}",
                f"{r.centroid_lat:.6f}",
                f"{r.centroid_lon:.6f}",
                f"{r.score:.2f}",
            ]
            for r in data.detections
        ]
        table = Table(rows, repeatRows=1)
        table.setStyle(
            TableStyle(
                [
                    ("FONTNAME", (0, 0), (-1, -1), FONT),
                    ("FONTNAME", (0, 0), (-1, 0), FONT_BOLD),
                    ("FONTSIZE", (0, 0), (-1, -1), 8),
                    ("ALIGN", (0, 0), (-1, -1), "RIGHT"),
                    ("BACKGROUND", (0, 0), (-1, 0), colors.Color(0.92, 0.92, 0.92)),
                    ("GRID", (0, 0), (-1, -1), 0.4, colors.grey),
                ]
            )
        )
        story.append(table)
    else:
        story.append(Paragraph("No landslide was detected.", body))

    story += [Paragraph("Change since the previous report", h2), Paragraph(change_text(data), body)]
    for title, values in (("Processing", data.processing), ("Parameters", data.parameters)):
        story.append(Paragraph(title, h2))
        rows = [
            [Paragraph(_escape(k), cell), Paragraph(_escape(v), cell)] for k, v in _flatten(values)
        ]
        if rows:
            table = Table(rows, colWidths=[70 * mm, width - 70 * mm])
            table.setStyle(TableStyle([("GRID", (0, 0), (-1, -1), 0.3, colors.lightgrey)]))
            story.append(table)
    story += [Spacer(1, 3 * mm), Paragraph(f"Model version: {_escape(data.model_version)}", small)]

    with atomic_path(Path(out_pdf)) as tmp:
        document = SimpleDocTemplate(
            str(tmp),
            pagesize=A4,
            leftMargin=18 * mm,
            rightMargin=18 * mm,
            topMargin=16 * mm,
            bottomMargin=16 * mm,
            title=f"slidewatch report {data.report_id}: {data.site_name}",
            author="slidewatch",
            invariant=1,  # the same data gives the same bytes
        )
        document.build(story)
    return Path(out_pdf)


def _escape(text: str) -> str:
    return str(text).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def render_html(data: ReportData, figure: Path, out_html: Path) -> Path:
    environment = Environment(
        loader=FileSystemLoader(TEMPLATES), autoescape=select_autoescape(["html"])
    )
    html = environment.get_template("report.html").render(
        d=data,
        created=local_time(data.created_at, data.timezone),
        trigger=_trigger(data),
        totals=data.totals,
        figure=base64.b64encode(Path(figure).read_bytes()).decode(),
        change_text=change_text(data),
        processing=_flatten(data.processing),
        parameters=_flatten(data.parameters),
    )
    with atomic_path(Path(out_html)) as tmp:
        tmp.write_text(html, encoding="utf-8")
    return Path(out_html)


def build_report(data: ReportData, out_dir: Path) -> ReportFiles:
    """Write map.png, report.pdf and report.html into `out_dir`."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    figure = site_map(
        data.dh_path,
        data.dsm_path,
        data.detections,
        out_dir / "map.png",
        f"{data.site_name}: Δh and landslides (comparison {data.comparison_id})",
    )
    return ReportFiles(
        pdf=render_pdf(data, figure, out_dir / "report.pdf"),
        html=render_html(data, figure, out_dir / "report.html"),
        figure=figure,
    )
