"""Alerts: webhook calls and e-mails when landslides are found, a job fails or a report is
ready, each delivered by a Celery task with retries and every attempt logged.

Events and what triggers them:

    landslides_detected  a comparison succeeded with detections above the site's thresholds
    job_failed           any job of the site failed for good
    report_ready         a report of the site was generated

Thresholds (AlertSettings, per site, all must hold for a detection to count):
`area_m2 >= min_area_m2`, `volume_loss_m3 + volume_gain_m3 >= min_volume_m3` (material
moved) and `score >= min_score`.

An event makes one Delivery row per target (each active webhook that subscribed to it, and
the site's e-mail recipients when SMTP is configured) in the caller's transaction; a
unique key per event and target means an event is never delivered twice to one target.
The tasks are queued after that transaction commits. `attempt_delivery` makes one attempt:
it claims the attempt with a conditional UPDATE (so two copies of a task cannot both send),
sends without holding a database transaction, and records the outcome.
"""

from __future__ import annotations

import json
import logging
import smtplib
import ssl
import time
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from email.headerregistry import Address
from email.message import EmailMessage
from typing import Any

import httpx
from celery import Celery
from sqlalchemy import event, select, update
from sqlalchemy.orm import Session

from backend.config import Settings
from backend.db.detections import detection_labels
from backend.db.models import (
    AlertSettings,
    Comparison,
    Delivery,
    DeliveryAttempt,
    DeliveryStatus,
    Detection,
    Job,
    Report,
    Site,
    StoredFile,
    Webhook,
)
from backend.outbound import UrlRefused, parse_networks, resolve_target
from backend.services.alert_messages import email_text, subject
from backend.signing import SIGNATURE_HEADER, TIMESTAMP_HEADER, sign
from backend.storage import LocalStorage
from backend.urls import api_url

log = logging.getLogger(__name__)

EVENTS = ("landslides_detected", "job_failed", "report_ready")
MAX_BACKOFF_S = 3600.0


def utcnow() -> datetime:
    return datetime.now(UTC)


def _aware(moment: datetime | None) -> datetime | None:
    if moment is None:
        return None
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)


def _iso(moment: datetime | None) -> str | None:
    moment = _aware(moment)
    return moment.isoformat().replace("+00:00", "Z") if moment else None


def alert_settings(session: Session, site_id: int) -> AlertSettings:
    """The site's settings, or the defaults (not stored) where it has none."""
    found = session.get(AlertSettings, site_id)
    if found is not None:
        return found
    return AlertSettings(
        site_id=site_id,
        min_area_m2=0.0,
        min_volume_m3=0.0,
        min_score=0.0,
        email_recipients=[],
        notify_job_failures=True,
    )


def above_thresholds(rules: AlertSettings, detections: list[Detection]) -> list[Detection]:
    return [
        d
        for d in detections
        if d.area_m2 >= rules.min_area_m2
        and d.volume_loss_m3 + d.volume_gain_m3 >= rules.min_volume_m3
        and d.score >= rules.min_score
    ]


# --- events -----------------------------------------------------------------------------


def _links(settings: Settings, site_id: int, **paths: str) -> dict[str, str]:
    base = settings.resolved_public_url
    return {name: f"{base}{path}" for name, path in paths.items()}


def detection_summary(detection: Detection, label: int | None = None) -> dict[str, Any]:
    from shapely.geometry import shape

    centroid = shape(detection.geometry).centroid
    return {
        "id": detection.id,
        "label": label,  # 1…n in its comparison, as in the page, the GeoJSON and the report
        "area_m2": round(detection.area_m2, 2),
        "volume_loss_m3": round(detection.volume_loss_m3, 2),
        "volume_gain_m3": round(detection.volume_gain_m3, 2),
        "max_abs_dh_m": round(detection.max_abs_dh_m, 3),
        "score": round(detection.score, 3),
        "centroid": {"lon": round(centroid.x, 6), "lat": round(centroid.y, 6)},
    }


def comparison_succeeded(
    session: Session, comparison: Comparison, settings: Settings
) -> list[Delivery]:
    """Alert when the comparison found landslides above the site's thresholds."""
    rules = alert_settings(session, comparison.site_id)
    found = above_thresholds(rules, list(comparison.detections))
    if not found:
        return []
    site = session.get(Site, comparison.site_id)
    labels = detection_labels(comparison)
    api = api_url("sites", comparison.site_id, "comparisons", comparison.id)
    payload = {
        "event": "landslides_detected",
        "site": {"id": site.id, "name": site.name},
        "comparison": {
            "id": comparison.id,
            "pre_survey_id": comparison.pre_survey_id,
            "post_survey_id": comparison.post_survey_id,
            "finished_at": _iso(comparison.finished_at),
        },
        "thresholds": {
            "min_area_m2": rules.min_area_m2,
            "min_volume_m3": rules.min_volume_m3,
            "min_score": rules.min_score,
        },
        "detections": [detection_summary(d, labels[d.id]) for d in found],
        "links": _links(
            settings,
            site.id,
            comparison=api,
            detections=f"{api}/detections",
            features=f"/ogc/collections/detections/items?comparison_id={comparison.id}",
        ),
    }
    return create_deliveries(
        session,
        settings,
        site,
        "landslides_detected",
        f"comparison:{comparison.id}",
        payload,
        subject(
            site.language,
            "landslides_detected",
            site=site.name,
            count=len(found),
            comparison=comparison.id,
        ),
    )


def job_failed(session: Session, job: Job, settings: Settings) -> list[Delivery]:
    rules = alert_settings(session, job.site_id)
    if not rules.notify_job_failures:
        return []
    site = session.get(Site, job.site_id)
    if site is None:
        return []
    failed_at = _iso(job.finished_at) or _iso(utcnow())
    payload = {
        "event": "job_failed",
        "site": {"id": site.id, "name": site.name},
        "job": {
            "id": job.id,
            "kind": job.kind,
            "comparison_id": job.comparison_id,
            "survey_id": job.survey_id,
            "error": job.error,
            "failed_at": failed_at,
        },
        "links": _links(settings, site.id, job=api_url("sites", site.id, "jobs", job.id)),
    }
    title = subject(site.language, "job_failed", site=site.name, kind=job.kind, job=job.id)
    # A job retried and failed again is a new event: the failure time is part of the key.
    return create_deliveries(
        session, settings, site, "job_failed", f"job:{job.id}:{failed_at}", payload, title
    )


def report_ready(session: Session, report: Report, settings: Settings) -> list[Delivery]:
    site = session.get(Site, report.site_id)
    api = api_url("sites", site.id, "reports", report.id)
    summary = report.summary or {}
    payload = {
        "event": "report_ready",
        "site": {"id": site.id, "name": site.name},
        "report": {
            "id": report.id,
            "trigger": report.trigger,
            "schedule_id": report.schedule_id,
            "comparison_id": report.comparison_id,
            "detections": summary.get("detections"),
            "total_area_m2": summary.get("total_area_m2"),
            "created_at": _iso(report.created_at),
        },
        "links": _links(settings, site.id, report=api, pdf=f"{api}/pdf", html=f"{api}/html"),
    }
    return create_deliveries(
        session,
        settings,
        site,
        "report_ready",
        f"report:{report.id}",
        payload,
        subject(site.language, "report_ready", site=site.name, report=report.id),
        report=report,
    )


def create_deliveries(
    session: Session,
    settings: Settings,
    site: Site,
    event_name: str,
    event_key: str,
    payload: dict[str, Any],
    email_subject: str,
    report: Report | None = None,
) -> list[Delivery]:
    """One delivery per target that wants this event; queued once the session commits."""
    created: list[Delivery] = []
    webhooks = session.scalars(
        select(Webhook).where(Webhook.site_id == site.id, Webhook.active.is_(True))
    )
    targets: list[tuple[str, Webhook | None]] = [
        ("webhook", w) for w in webhooks if event_name in (w.events or EVENTS)
    ]
    rules = alert_settings(session, site.id)
    if rules.email_recipients:
        if settings.smtp_host:
            targets.append(("email", None))
        else:
            log.warning("site %s has e-mail recipients but SLIDEWATCH_SMTP_HOST is unset", site.id)
    for channel, webhook in targets:
        key = f"{event_key}:{event_name}:{channel}:{webhook.id if webhook else 'email'}"
        if session.scalar(select(Delivery.id).where(Delivery.dedupe_key == key)) is not None:
            continue
        delivery = Delivery(
            site_id=site.id,
            channel=channel,
            webhook_id=webhook.id if webhook else None,
            recipients=list(rules.email_recipients) if channel == "email" else None,
            report_id=report.id if report is not None else None,
            event=event_name,
            dedupe_key=key,
            payload={**payload, **_email_extras(site, email_subject)}
            if channel == "email"
            else payload,
            status=DeliveryStatus.pending,
            attempts=0,
            next_attempt_at=utcnow(),
        )
        session.add(delivery)
        created.append(delivery)
    if created:
        session.flush()
        queue_after_commit(session, settings, [d.id for d in created])
    return created


def _email_extras(site: Site, email_subject: str) -> dict[str, str]:
    """What an e-mail delivery keeps besides the event: its subject, and the language and
    time zone its body is written in when sent (the site's when the event happened)."""
    return {"subject": email_subject, "language": site.language, "timezone": site.timezone}


class EmailUnavailable(RuntimeError):
    """E-mail is asked for while this server has no SMTP server; the message says so."""


EMAIL_UNAVAILABLE = (
    "e-mail cannot be sent: this server has no SMTP server configured "
    "(SLIDEWATCH_SMTP_HOST is unset); ask its administrator to set one, or use a webhook"
)


def check_email_available(settings: Settings) -> None:
    # Refused where it is asked for, rather than accepted and never sent: a recipient
    # saved without SMTP would believe alerts reach them.
    if not settings.smtp_host:
        raise EmailUnavailable(EMAIL_UNAVAILABLE)


def test_delivery(
    session: Session, settings: Settings, site: Site, webhook: Webhook | None, who: str
) -> Delivery:
    """A delivery of the event `test` to one webhook, or (webhook None) to the site's e-mail
    recipients: sent by the worker like any alert, with its attempts in the delivery log."""
    rules = alert_settings(session, site.id)
    if webhook is None:
        check_email_available(settings)
        if not rules.email_recipients:
            raise LookupError(f"site {site.id} has no e-mail recipients to send a test to")
    moment = utcnow()
    payload = {
        "event": "test",
        "site": {"id": site.id, "name": site.name},
        "sent_by": who,
        "sent_at": _iso(moment),
        "message": "A test from slidewatch: this target receives the site's alerts.",
        "links": _links(settings, site.id, site=api_url("sites", site.id)),
    }
    target = f"webhook:{webhook.id}" if webhook is not None else "email"
    delivery = Delivery(
        site_id=site.id,
        channel="webhook" if webhook is not None else "email",
        webhook_id=webhook.id if webhook is not None else None,
        recipients=None if webhook is not None else list(rules.email_recipients),
        event="test",
        # Every test is its own delivery: the key only has to be unique.
        dedupe_key=f"test:{moment.timestamp():.6f}:{target}"[:200],
        payload=payload
        if webhook is not None
        else {**payload, **_email_extras(site, subject(site.language, "test", site=site.name))},
        status=DeliveryStatus.pending,
        attempts=0,
        next_attempt_at=moment,
    )
    session.add(delivery)
    session.flush()
    queue_after_commit(session, settings, [delivery.id])
    return delivery


# --- queueing ---------------------------------------------------------------------------


# Celery clients by broker URL: each keeps its own connection pool, so one is made per
# broker and reused by every delivery queued in this process.
_clients: dict[str, Celery] = {}


def _celery(settings: Settings) -> Celery:
    from worker.celery_app import create_celery

    broker_url = settings.resolved_broker_url
    if broker_url not in _clients:
        _clients[broker_url] = create_celery(settings)
    return _clients[broker_url]


def send_delivery_task(
    settings: Settings, delivery_id: int, countdown: float | None = None
) -> None:
    from worker.celery_app import DELIVER_TASK, QUEUE

    celery = _celery(settings)
    celery.send_task(DELIVER_TASK, args=[delivery_id], queue=QUEUE, countdown=countdown)


def queue_after_commit(session: Session, settings: Settings, delivery_ids: list[int]) -> None:
    """Queue the deliveries' tasks once `session` commits (never for a rolled-back one)."""
    pending: list[int] = session.info.setdefault("deliveries_to_queue", [])
    # The after-commit listener gets the session alone: it finds the broker here.
    session.info["deliveries_settings"] = settings
    if not session.info.get("deliveries_listener"):
        event.listen(session, "after_commit", _queue_pending)
        event.listen(session, "after_rollback", _forget_pending)
        session.info["deliveries_listener"] = True
    pending.extend(delivery_ids)


def _queue_pending(session: Session) -> None:
    ids = session.info.pop("deliveries_to_queue", [])
    settings = session.info.get("deliveries_settings")
    for delivery_id in ids:
        try:
            send_delivery_task(settings, delivery_id)
        except Exception:  # the sweep of overdue deliveries queues it again
            log.warning("could not queue delivery %s", delivery_id, exc_info=True)


def _forget_pending(session: Session) -> None:
    session.info.pop("deliveries_to_queue", None)


def overdue_deliveries(
    session: Session, settings: Settings, now: datetime | None = None
) -> list[int]:
    """Deliveries whose next attempt is well past due: their message or worker was lost."""
    now = now or utcnow()
    grace = timedelta(seconds=max(60.0, settings.webhook_timeout_s * 3))
    return list(
        session.scalars(
            select(Delivery.id).where(
                Delivery.status.in_([DeliveryStatus.pending, DeliveryStatus.retrying]),
                Delivery.next_attempt_at < now - grace,
            )
        )
    )


# --- one attempt ------------------------------------------------------------------------


@dataclass(frozen=True)
class AttemptOutcome:
    delivered: bool
    retry_in_s: float | None  # None: nothing more to do (delivered, given up or not ours)
    status_code: int | None = None
    error: str | None = None


def backoff_s(settings: Settings, attempt: int) -> float:
    return min(settings.delivery_retry_base_s * 2 ** (attempt - 1), MAX_BACKOFF_S)


def _claim_attempt(session: Session, delivery: Delivery, settings: Settings) -> int | None:
    """Take attempt n+1 with a conditional UPDATE; None if another worker took it."""
    attempt = delivery.attempts + 1
    if attempt > settings.delivery_max_attempts:
        # Its attempts are used up (an attempt that died with its worker counted too): it
        # fails now rather than being tried again.
        session.execute(
            update(Delivery)
            .where(Delivery.id == delivery.id, Delivery.attempts == delivery.attempts)
            .values(
                status=DeliveryStatus.failed,
                next_attempt_at=None,
                last_error=(
                    f"gave up after {delivery.attempts} attempts: "
                    f"{delivery.last_error or 'the last attempt did not finish'}"
                ),
            )
            .execution_options(synchronize_session=False)
        )
        return None
    # While it is in flight, the sweep must not think the delivery is lost.
    in_flight_until = utcnow() + timedelta(seconds=settings.webhook_timeout_s + 30)
    claimed = session.execute(
        update(Delivery)
        .where(
            Delivery.id == delivery.id,
            Delivery.attempts == delivery.attempts,
            Delivery.status.in_([DeliveryStatus.pending, DeliveryStatus.retrying]),
        )
        .values(attempts=attempt, next_attempt_at=in_flight_until)
        .execution_options(synchronize_session=False)
    )
    return attempt if claimed.rowcount == 1 else None


def attempt_delivery(
    delivery_id: int, session_factory, storage: LocalStorage, settings: Settings
) -> AttemptOutcome:
    """Make the next attempt of a delivery and record it; say whether to retry and when."""
    with session_factory() as session:
        delivery = session.get(Delivery, delivery_id)
        if delivery is None or delivery.status in (DeliveryStatus.delivered, DeliveryStatus.failed):
            return AttemptOutcome(delivery is not None, None)
        attempt = _claim_attempt(session, delivery, settings)
        session.commit()
        if attempt is None:
            return AttemptOutcome(False, None)
        webhook = session.get(Webhook, delivery.webhook_id) if delivery.webhook_id else None
        try:
            request: _Request | None = _prepare(session, storage, delivery, webhook)
        except Exception as exc:  # recorded as a failed attempt, like a refused call
            request, prepare_error = None, f"could not prepare the message: {exc}"

    started = time.perf_counter()
    if request is None:
        status_code, error = None, prepare_error
    else:
        try:
            status_code, error = _send(settings, request)
        except Exception as exc:
            # Whatever the failure, it is this attempt's, recorded below and counted: an
            # error that escaped would leave the delivery claimed with no record, to be
            # found overdue and tried again without end.
            status_code, error = None, f"{type(exc).__name__}: {exc}"
    duration_ms = (time.perf_counter() - started) * 1000
    delivered = error is None

    give_up = not delivered and attempt >= settings.delivery_max_attempts
    retry_in = None if delivered or give_up else backoff_s(settings, attempt)
    with session_factory() as session:
        delivery = session.get(Delivery, delivery_id)
        session.add(
            DeliveryAttempt(
                delivery_id=delivery_id,
                attempt=attempt,
                at=utcnow(),
                status_code=status_code,
                error=error,
                duration_ms=round(duration_ms, 1),
            )
        )
        if delivered:
            delivery.status = DeliveryStatus.delivered
            delivery.delivered_at = utcnow()
            delivery.next_attempt_at = None
            delivery.last_error = None
        elif give_up:
            delivery.status = DeliveryStatus.failed
            delivery.next_attempt_at = None
            delivery.last_error = f"gave up after {attempt} attempts: {error}"
        else:
            delivery.status = DeliveryStatus.retrying
            delivery.next_attempt_at = utcnow() + timedelta(seconds=retry_in or 0)
            delivery.last_error = error
        session.commit()
    if not delivered:
        log.warning("delivery %s attempt %s failed: %s", delivery_id, attempt, error)
    return AttemptOutcome(delivered, retry_in, status_code, error)


@dataclass(frozen=True)
class _Request:
    channel: str
    delivery_id: int
    event: str
    body: bytes
    url: str | None = None
    secret: str | None = None
    recipients: tuple[str, ...] = ()
    subject: str = ""
    text: str = ""
    attachment: tuple[str, bytes] | None = None


def _prepare(
    session: Session, storage: LocalStorage, delivery: Delivery, webhook: Webhook | None
) -> _Request:
    payload = dict(delivery.payload)
    if delivery.channel == "webhook":
        if webhook is None:
            raise LookupError(f"webhook of delivery {delivery.id} is gone")
        body = json.dumps(payload, separators=(",", ":"), ensure_ascii=False).encode()
        return _Request(
            "webhook", delivery.id, delivery.event, body, url=webhook.url, secret=webhook.secret
        )
    title = payload.pop("subject", f"[slidewatch] {delivery.event}")
    # Deliveries made before e-mails had languages: English, times in UTC.
    language, timezone = payload.pop("language", "en"), payload.pop("timezone", "UTC")
    attachment = None
    if delivery.report_id is not None:
        report = session.get(Report, delivery.report_id)
        pdf = session.get(StoredFile, report.pdf_file_id) if report and report.pdf_file_id else None
        if pdf is not None:
            path = storage.absolute(pdf.path)
            attachment = (f"slidewatch-report-{report.id}.pdf", path.read_bytes())
    return _Request(
        "email",
        delivery.id,
        delivery.event,
        b"",
        recipients=tuple(delivery.recipients or ()),
        subject=title,
        text=email_text(payload, language, timezone),
        attachment=attachment,
    )


def _send(settings: Settings, request: _Request) -> tuple[int | None, str | None]:
    """Send; return (HTTP status or None, error or None)."""
    if request.channel == "webhook":
        timestamp = int(time.time())
        headers = {
            "Content-Type": "application/json",
            "User-Agent": "slidewatch-webhooks/1",
            "X-Slidewatch-Event": request.event,
            "X-Slidewatch-Delivery": str(request.delivery_id),
            TIMESTAMP_HEADER: str(timestamp),
            SIGNATURE_HEADER: sign(request.secret or "", timestamp, request.body),
        }
        try:
            # Checked again now (its name may resolve elsewhere than when it was saved),
            # and called at the very address checked.
            target = resolve_target(
                request.url or "", parse_networks(settings.webhook_allowed_networks)
            )
        except UrlRefused as exc:
            return None, f"refused: {exc}"
        try:
            # A redirect is an answer, not a new target: it is never followed.
            with httpx.Client(timeout=settings.webhook_timeout_s, follow_redirects=False) as http:
                response = http.post(
                    target.url,
                    content=request.body,
                    headers={**headers, "Host": target.host_header},
                    extensions={"sni_hostname": target.server_name},
                )
        except httpx.HTTPError as exc:
            return None, f"{type(exc).__name__}: {exc}"
        if 200 <= response.status_code < 300:
            return response.status_code, None
        # The status and its reason phrase only: what the receiver wrote back is its own
        # (an internal service on the allow-list may answer with its data), and the log
        # is readable by every member of the site.
        reason = response.reason_phrase or ""
        return response.status_code, f"HTTP {response.status_code} {reason}".rstrip()
    try:
        send_email(settings, request.recipients, request.subject, request.text, request.attachment)
    except (OSError, smtplib.SMTPException, ValueError) as exc:
        # ValueError: the library refused to build a header (e.g. a recipient saved before
        # addresses were checked): a failed attempt like any other, never a stuck delivery.
        code = getattr(exc, "smtp_code", None)
        return code, f"{type(exc).__name__}: {exc}"
    return None, None


def send_email(
    settings: Settings,
    recipients: tuple[str, ...] | list[str],
    subject: str,
    text: str,
    attachment: tuple[str, bytes] | None = None,
) -> None:
    message = EmailMessage()
    # Headers built by the library from parsed addresses: it refuses what is no address.
    message["From"] = settings.smtp_from
    message["To"] = [Address(addr_spec=r) for r in recipients]
    message["Subject"] = " ".join(subject.split())  # a site's name may hold line breaks
    message.set_content(text)
    if attachment is not None:
        name, data = attachment
        message.add_attachment(data, maintype="application", subtype="pdf", filename=name)
    host, port, timeout = (
        settings.smtp_host or "localhost",
        settings.smtp_port,
        settings.smtp_timeout_s,
    )
    if settings.smtp_security == "ssl":
        smtp: smtplib.SMTP = smtplib.SMTP_SSL(
            host, port, timeout=timeout, context=ssl.create_default_context()
        )
    else:
        smtp = smtplib.SMTP(host, port, timeout=timeout)
    with smtp:
        if settings.smtp_security == "starttls":
            smtp.starttls(context=ssl.create_default_context())
        if settings.smtp_username:
            smtp.login(settings.smtp_username, settings.smtp_password or "")
        smtp.send_message(message)
