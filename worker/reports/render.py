"""Render a report as PDF (reportlab) and HTML (Jinja2), with the site map figure, in the
report's language (worker/reports/catalogues).

The PDF embeds DejaVu Sans, and a Japanese font for what DejaVu has no glyph for
(worker/reports/fonts.py), so "Δh", "m²", "m³", "−", "|Δh|" and Japanese render and can be
extracted as text.
"""

from __future__ import annotations

import base64
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from jinja2 import Environment, FileSystemLoader, select_autoescape
from reportlab.lib import colors
from reportlab.lib.enums import TA_LEFT, TA_RIGHT
from reportlab.lib.pagesizes import A4
from reportlab.lib.styles import ParagraphStyle
from reportlab.lib.units import mm
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
from worker.reports.fonts import FONT, FONT_BOLD, markup, register_fonts
from worker.reports.words import (
    change_text,
    created_text,
    flatten,
    meta_text,
    summary_text,
    table_header,
    table_row,
    words_of,
)

TEMPLATES = Path(__file__).parent / "templates"
# The landslide table's columns (mm): number, area, loss, gain, max |Δh|, lat, lon, score.
COLUMN_WIDTHS_MM = (12, 21, 21, 21, 28, 22, 24, 17)


@dataclass(frozen=True)
class ReportFiles:
    pdf: Path
    html: Path
    figure: Path


def render_pdf(data: ReportData, figure: Path, out_pdf: Path) -> Path:
    register_fonts()
    words = words_of(data)
    body = ParagraphStyle(
        "body",
        fontName=FONT,
        fontSize=9.5,
        leading=12.5,
        alignment=TA_LEFT,
        wordWrap=words.pdf_word_wrap,  # Japanese breaks between any two characters
    )
    small = ParagraphStyle("small", parent=body, fontSize=8, leading=10, textColor=colors.grey)
    h1 = ParagraphStyle("h1", parent=body, fontName=FONT_BOLD, fontSize=15, leading=19)
    h2 = ParagraphStyle(
        "h2", parent=body, fontName=FONT_BOLD, fontSize=11, leading=14, spaceBefore=8
    )
    cell = ParagraphStyle("cell", parent=body, fontSize=8, leading=10)
    head = ParagraphStyle("head", parent=cell, fontName=FONT_BOLD, alignment=TA_RIGHT)

    def text(value: str, style: ParagraphStyle) -> Paragraph:
        return Paragraph(markup(value), style)

    story: list[Any] = [
        text(words.text("report.title", site=data.site_name), h1),
        text(meta_text(data), small),
        text(words.text("report.before", survey=data.pre_survey), small),
        text(words.text("report.after", survey=data.post_survey), small),
        text(words.text("report.times_in", zone=data.timezone), small),
        Spacer(1, 4 * mm),
        text(summary_text(data), body),
    ]
    story += [Paragraph(f"<i>{markup(note)}</i>", body) for note in data.notes]
    width = A4[0] - 36 * mm
    story += [Spacer(1, 3 * mm), Image(str(figure), width=width, height=width * 5.6 / 7.2)]

    story.append(text(words.text("report.landslides"), h2))
    if data.detections:
        rows = [[text(name, head) for name in table_header(data)]]
        rows += [table_row(data, r) for r in data.detections]
        table = Table(rows, colWidths=[w * mm for w in COLUMN_WIDTHS_MM], repeatRows=1)
        table.setStyle(
            TableStyle(
                [
                    ("FONTNAME", (0, 0), (-1, -1), FONT),
                    ("FONTSIZE", (0, 0), (-1, -1), 8),
                    ("ALIGN", (0, 0), (-1, -1), "RIGHT"),
                    ("VALIGN", (0, 0), (-1, -1), "MIDDLE"),
                    ("BACKGROUND", (0, 0), (-1, 0), colors.Color(0.92, 0.92, 0.92)),
                    ("GRID", (0, 0), (-1, -1), 0.4, colors.grey),
                ]
            )
        )
        story.append(table)
    else:
        story.append(text(words.text("report.no_landslides"), body))

    story += [text(words.text("report.change"), h2), text(change_text(data), body)]
    for title, values in (
        (words.text("report.processing"), data.processing),
        (words.text("report.parameters"), data.parameters),
    ):
        story.append(text(title, h2))
        rows = [[text(k, cell), text(v, cell)] for k, v in flatten(data, values)]
        if rows:
            table = Table(rows, colWidths=[70 * mm, width - 70 * mm])
            table.setStyle(TableStyle([("GRID", (0, 0), (-1, -1), 0.3, colors.lightgrey)]))
            story.append(table)
    story += [
        Spacer(1, 3 * mm),
        text(words.text("report.model_version", version=data.model_version), small),
    ]

    with atomic_path(Path(out_pdf)) as tmp:
        document = SimpleDocTemplate(
            str(tmp),
            pagesize=A4,
            leftMargin=18 * mm,
            rightMargin=18 * mm,
            topMargin=16 * mm,
            bottomMargin=16 * mm,
            title=words.text("report.document_title", report=data.report_id, site=data.site_name),
            author="slidewatch",
            lang=words.code,
            invariant=1,  # the same data gives the same bytes
        )
        document.build(story)
    return Path(out_pdf)


def render_html(data: ReportData, figure: Path, out_html: Path) -> Path:
    environment = Environment(
        loader=FileSystemLoader(TEMPLATES), autoescape=select_autoescape(["html"])
    )
    html = environment.get_template("report.html").render(
        d=data,
        language=data.language,
        t=words_of(data).text,
        created=created_text(data),
        meta=meta_text(data),
        summary=summary_text(data),
        header=table_header(data),
        rows=[table_row(data, r) for r in data.detections],
        figure=base64.b64encode(Path(figure).read_bytes()).decode(),
        change_text=change_text(data),
        processing=flatten(data, data.processing),
        parameters=flatten(data, data.parameters),
    )
    with atomic_path(Path(out_html)) as tmp:
        tmp.write_text(html, encoding="utf-8")
    return Path(out_html)


def build_report(data: ReportData, out_dir: Path) -> ReportFiles:
    """Write map.png, report.pdf and report.html into `out_dir`."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    # Imported here: matplotlib's pyplot takes most of a second to import, and the API and
    # every worker import this package for its data types and words.
    from worker.reports.figure import site_map

    figure = site_map(
        data.dh_path,
        data.dsm_path,
        data.detections,
        out_dir / "map.png",
        words_of(data).text("map.title", site=data.site_name, comparison=data.comparison_id),
        words=words_of(data),
    )
    return ReportFiles(
        pdf=render_pdf(data, figure, out_dir / "report.pdf"),
        html=render_html(data, figure, out_dir / "report.html"),
        figure=figure,
    )
