"""The words of alert e-mails in the site's language: the subject, made when the event
happens, and the plain-text body, made from the event's payload when it is sent.

The texts are in the reports' message catalogues (worker/reports/catalogues); times are
in the site's time zone and numbers in the language's format, as in its reports.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from worker.reports.i18n import Catalogue, catalogue

# The payload's time that each event's e-mail shows.
EVENT_TIMES = {
    "landslides_detected": ("comparison", "finished_at"),
    "job_failed": ("job", "failed_at"),
    "report_ready": ("report", "created_at"),
    "test": (None, "sent_at"),
}


def job_kind(words: Catalogue, kind: str) -> str:
    key = f"job_kind.{kind}"
    return words.text(key) if key in words.messages else kind


def subject(language: str, event: str, **params: Any) -> str:
    """The e-mail's subject: "[slidewatch] {site}: …" in the site's language."""
    words = catalogue(language)
    if event == "job_failed":
        params["kind"] = job_kind(words, params["kind"])
    return words.text(f"email.subject.{event}", **params)


def _event_time(payload: dict[str, Any], words: Catalogue, timezone: str) -> str | None:
    part, field = EVENT_TIMES.get(payload["event"], (None, ""))
    values = payload.get(part, {}) if part else payload
    moment = values.get(field) if isinstance(values, dict) else None
    if not moment:
        return None
    return words.time(datetime.fromisoformat(moment), timezone)


def _detection_line(words: Catalogue, detection: dict[str, Any]) -> str:
    return "  " + words.text(
        "email.detection",
        label=detection.get("label") or detection["id"],
        area=words.number(detection["area_m2"], 1),
        loss=words.number(detection["volume_loss_m3"], 1),
        gain=words.number(detection["volume_gain_m3"], 1),
        dh=words.number(detection["max_abs_dh_m"], 2),
        score=words.number(detection["score"], 2),
        lat=words.number(detection["centroid"]["lat"], 6),
        lon=words.number(detection["centroid"]["lon"], 6),
    )


def email_text(payload: dict[str, Any], language: str = "en", timezone: str = "UTC") -> str:
    """A plain-text e-mail body from an event payload, in `language`, times in `timezone`."""
    words = catalogue(language)
    site = payload.get("site", {})
    lines = [words.text("email.site", site=site.get("name"), id=site.get("id"))]
    when = _event_time(payload, words, timezone)
    if when is not None:
        lines.append(words.text("email.time", time=when))
    lines.append("")
    event = payload["event"]
    if event == "landslides_detected":
        lines.append(
            words.text("email.landslides_detected", comparison=payload["comparison"]["id"])
        )
        lines.append("")
        lines += [_detection_line(words, d) for d in payload["detections"]]
    elif event == "job_failed":
        job = payload["job"]
        lines.append(
            words.text(
                "email.job_failed",
                kind=job_kind(words, job["kind"]),
                job=job["id"],
                error=job["error"],
            )
        )
    elif event == "test":
        lines.append(words.text("email.test"))
    elif event == "report_ready":
        report = payload["report"]
        lines.append(
            words.text("email.report_ready", report=report["id"], count=report["detections"] or 0)
        )
    lines.append("")
    for name, url in payload.get("links", {}).items():
        key = f"email.link.{name}"
        shown = words.text(key) if key in words.messages else name
        lines.append(words.text("email.link", name=shown, url=url))
    return "\n".join(lines) + "\n"
