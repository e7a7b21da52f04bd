"""Request and response bodies of alerts, webhooks, schedules and reports."""

from datetime import datetime
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator

from backend.api.schemas import check_language_code
from backend.db.models import DeliveryStatus, JobState
from backend.email_address import email_problem
from backend.ids import RowId
from backend.outbound import check_url_form
from backend.services.alerts import EVENTS


class ORMModel(BaseModel):
    model_config = ConfigDict(from_attributes=True)


def check_events(values: list[str] | None) -> list[str] | None:
    if values is None:
        return values
    unknown = sorted(set(values) - set(EVENTS))
    if unknown:
        raise ValueError(f"unknown events {unknown}; events: {', '.join(EVENTS)}")
    if not values:
        raise ValueError("a webhook needs at least one event")
    return values


class AlertSettingsIn(BaseModel):
    min_area_m2: float = Field(default=0.0, ge=0, description="Smallest landslide that alerts.")
    min_volume_m3: float = Field(
        default=0.0, ge=0, description="Least material moved (loss + gain) that alerts."
    )
    min_score: float = Field(default=0.0, ge=0, le=1, description="Least detection score.")
    email_recipients: list[str] = Field(default_factory=list, max_length=50)
    notify_job_failures: bool = True

    @field_validator("email_recipients")
    @classmethod
    def _addresses(cls, values: list[str]) -> list[str]:
        for value in values:
            problem = email_problem(value)
            if problem:
                raise ValueError(problem)
        return values


class AlertSettingsOut(AlertSettingsIn, ORMModel):
    site_id: int
    email_available: bool = Field(
        default=False, description="Whether this server can send e-mail (SMTP configured)."
    )
    email_unavailable_reason: str | None = Field(
        default=None, description="Why e-mail recipients are refused, when they are."
    )


class WebhookCreate(BaseModel):
    url: str = Field(max_length=2048, description="http(s) URL that receives POSTed JSON.")
    events: list[str] = Field(
        default_factory=lambda: list(EVENTS),
        description=f"Events to receive: {', '.join(EVENTS)}.",
    )
    description: str = Field(default="", max_length=200)
    active: bool = True

    @field_validator("url")
    @classmethod
    def _url(cls, value: str) -> str:
        check_url_form(value)  # its addresses are checked by the route, with the settings
        return value

    _events = field_validator("events")(check_events)


class WebhookUpdate(BaseModel):
    active: bool | None = None
    events: list[str] | None = None
    description: str | None = Field(default=None, max_length=200)

    _events = field_validator("events")(check_events)


class WebhookOut(ORMModel):
    id: int
    site_id: int
    url: str
    events: list[str]
    description: str
    active: bool
    created_at: datetime


class WebhookCreated(WebhookOut):
    secret: str = Field(
        description="Signs every call (HMAC-SHA256); shown only now. See docs/alerts.md."
    )


class DeliveryAttemptOut(ORMModel):
    attempt: int
    at: datetime
    status_code: int | None
    error: str | None
    duration_ms: float


class DeliveryOut(ORMModel):
    id: int
    channel: str
    webhook_id: int | None
    recipients: list[str] | None
    event: str
    status: DeliveryStatus
    attempts: int
    next_attempt_at: datetime | None
    delivered_at: datetime | None
    last_error: str | None
    created_at: datetime
    payload: dict[str, Any]
    attempt_log: list[DeliveryAttemptOut]


class ScheduleCreate(BaseModel):
    cron: str = Field(
        max_length=120,
        description="Five-field cron expression, e.g. '0 6 * * 1' (Mondays 06:00).",
    )
    timezone: str = Field(default="UTC", max_length=64, description="IANA time zone of cron.")
    name: str = Field(default="", max_length=200)
    enabled: bool = True
    next_run_at: datetime | None = Field(
        default=None,
        description="When to run first (then as cron says); default: the next cron time.",
    )


class ScheduleUpdate(BaseModel):
    cron: str | None = Field(default=None, max_length=120)
    timezone: str | None = Field(default=None, max_length=64)
    name: str | None = Field(default=None, max_length=200)
    enabled: bool | None = None
    next_run_at: datetime | None = None


class ScheduleOut(ORMModel):
    id: int
    site_id: int
    name: str
    cron: str
    timezone: str
    enabled: bool
    next_run_at: datetime
    last_run_at: datetime | None
    created_at: datetime


class SchedulePreview(BaseModel):
    cron: str
    timezone: str
    next_runs: list[datetime] = Field(description="The next times it runs, in UTC.")


class ReportCreate(BaseModel):
    comparison_id: RowId | None = Field(
        default=None, description="The comparison to report on; default: the site's latest."
    )
    language: str | None = Field(
        default=None,
        max_length=16,
        description="The language to write it in (a code of GET /api/v1/languages), e.g. the "
        "user's; default: the site's. `?lang=` says the same.",
    )

    _language = field_validator("language")(check_language_code)


class ReportOut(BaseModel):
    id: int
    site_id: int
    schedule_id: int | None
    scheduled_for: datetime | None
    comparison_id: int | None
    trigger: str
    language: str | None = Field(
        description="The language it is written in; null for a scheduled report not built "
        "yet (it takes the site's language when it is)."
    )
    status: JobState
    job_id: int | None = Field(
        default=None, description="The job that builds it: its stage, progress and events."
    )
    summary: dict[str, Any] | None
    error: str | None
    created_at: datetime
    finished_at: datetime | None
    pdf_url: str | None
    html_url: str | None
