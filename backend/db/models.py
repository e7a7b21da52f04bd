"""Database models. The schema itself changes only through Alembic migrations.

Geometries are stored as GeoJSON (WGS84 lon/lat) in JSON columns, with a bounding box in
plain float columns for filtering, so the same schema works on SQLite and PostgreSQL.
"""

from __future__ import annotations

import enum
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    CheckConstraint,
    DateTime,
    Enum,
    Float,
    ForeignKey,
    Integer,
    MetaData,
    String,
    Text,
    UniqueConstraint,
    event,
    select,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, Session, mapped_column, relationship

NAMING_CONVENTION = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}


def utcnow() -> datetime:
    return datetime.now(UTC)


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING_CONVENTION)
    type_annotation_map = {datetime: DateTime(timezone=True), dict[str, Any]: JSON}


class SurveyKind(enum.StrEnum):
    dsm = "dsm"
    video = "video"
    images = "images"


class SurveyStatus(enum.StrEnum):
    receiving = "receiving"  # a video or image-set survey whose files are still coming
    uploaded = "uploaded"
    processing = "processing"
    ready = "ready"
    failed = "failed"


class JobState(enum.StrEnum):
    queued = "queued"
    running = "running"
    succeeded = "succeeded"
    failed = "failed"


class StageState(enum.StrEnum):
    pending = "pending"
    running = "running"
    succeeded = "succeeded"
    failed = "failed"


def _enum(cls: type[enum.StrEnum], name: str) -> Enum:
    # Stored as VARCHAR with a CHECK constraint: portable and easy to migrate.
    return Enum(cls, name=name, native_enum=False, length=16, validate_strings=True)


class Role(enum.StrEnum):
    """What a member may do in an organisation; each role may do what the ones before it may."""

    viewer = "viewer"  # read
    analyst = "analyst"  # + upload, compare, confirm detections, reports
    manager = "manager"  # + sites, alerts, schedules, members, deletions
    admin = "admin"  # + everything, managers and admins among the members

    @property
    def rank(self) -> int:
        return list(Role).index(self)


class Organisation(Base):
    """A body whose staff watch its slopes (a municipality, an agency): it owns sites."""

    __tablename__ = "organisations"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200), unique=True)
    # Sites made without naming an organisation belong to the default one.
    is_default: Mapped[bool] = mapped_column(Boolean, default=False, server_default="0")
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Membership(Base):
    """A user's role in an organisation."""

    __tablename__ = "memberships"
    __table_args__ = (
        UniqueConstraint("organisation_id", "user_id", name="uq_memberships_organisation_user"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    organisation_id: Mapped[int] = mapped_column(
        ForeignKey("organisations.id", ondelete="CASCADE"), index=True
    )
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"), index=True)
    role: Mapped[Role] = mapped_column(_enum(Role, "member_role"))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)

    user: Mapped[User] = relationship()
    organisation: Mapped[Organisation] = relationship()


class AuditEntry(Base):
    """Who changed what: sites, alerts, schedules, members, deletions, tokens, users."""

    __tablename__ = "audit_log"

    id: Mapped[int] = mapped_column(primary_key=True)
    at: Mapped[datetime] = mapped_column(default=utcnow, index=True)
    actor: Mapped[str] = mapped_column(String(200))  # user name, or "token NAME"
    # Plain ids, no foreign keys: the record outlives what it speaks of.
    organisation_id: Mapped[int | None] = mapped_column(Integer, index=True)
    site_id: Mapped[int | None] = mapped_column(Integer, index=True)
    action: Mapped[str] = mapped_column(String(64))  # e.g. "site.update", "member.remove"
    target: Mapped[str] = mapped_column(String(200), default="")
    details: Mapped[dict[str, Any]] = mapped_column(default=dict)


class ApiToken(Base):
    __tablename__ = "api_tokens"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200))
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    prefix: Mapped[str] = mapped_column(String(16))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    last_used_at: Mapped[datetime | None]
    revoked_at: Mapped[datetime | None]
    # Set on the tokens that signing in gives a user (the map's sessions); NULL for the
    # platform's API tokens, which belong to no user and do not expire.
    user_id: Mapped[int | None] = mapped_column(
        ForeignKey("users.id", ondelete="CASCADE"), index=True
    )
    expires_at: Mapped[datetime | None]
    # "session": made by signing in to the map; "api": made to be given to a program.
    kind: Mapped[str] = mapped_column(String(16), default="api", server_default="api")
    # A token of no user is a service's: of one organisation with `role`, or, with no
    # organisation, the platform administrator's (every organisation, every role). A
    # user's token may be held to less than the user's roles: `role` caps them.
    organisation_id: Mapped[int | None] = mapped_column(
        ForeignKey("organisations.id", ondelete="CASCADE"), index=True
    )
    role: Mapped[Role | None] = mapped_column(_enum(Role, "token_role"))
    # Only this site, when set.
    site_id: Mapped[int | None] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"))

    user: Mapped[User | None] = relationship()


class Site(Base):
    __tablename__ = "sites"

    id: Mapped[int] = mapped_column(primary_key=True)
    organisation_id: Mapped[int] = mapped_column(ForeignKey("organisations.id"), index=True)
    name: Mapped[str] = mapped_column(String(200), unique=True)
    description: Mapped[str] = mapped_column(Text, default="")
    area_of_interest: Mapped[dict[str, Any] | None]
    # IANA time zone name: the map shows every time of the site in it.
    timezone: Mapped[str] = mapped_column(String(64), default="UTC", server_default="UTC")
    # The language of its scheduled reports and alert e-mails (worker/reports/catalogues).
    language: Mapped[str] = mapped_column(String(16), default="en", server_default="en")
    created_at: Mapped[datetime] = mapped_column(default=utcnow)

    surveys: Mapped[list[Survey]] = relationship(back_populates="site")
    organisation: Mapped[Organisation] = relationship()


class StoredFile(Base):
    __tablename__ = "stored_files"

    id: Mapped[int] = mapped_column(primary_key=True)
    path: Mapped[str] = mapped_column(String(1024), unique=True)
    size_bytes: Mapped[int] = mapped_column(BigInteger)
    sha256: Mapped[str] = mapped_column(String(64))
    media_type: Mapped[str] = mapped_column(String(100))
    original_name: Mapped[str | None] = mapped_column(String(512))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Survey(Base):
    __tablename__ = "surveys"

    id: Mapped[int] = mapped_column(primary_key=True)
    site_id: Mapped[int] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(200))
    captured_at: Mapped[datetime]
    kind: Mapped[SurveyKind] = mapped_column(_enum(SurveyKind, "survey_kind"))
    status: Mapped[SurveyStatus] = mapped_column(_enum(SurveyStatus, "survey_status"))
    crs: Mapped[str | None] = mapped_column(Text)
    footprint: Mapped[dict[str, Any] | None]
    resolution_m: Mapped[float | None] = mapped_column(Float)
    source_file_id: Mapped[int | None] = mapped_column(ForeignKey("stored_files.id"))
    # Reconstruction options of a video or image-set survey (method, camera, time offset).
    options: Mapped[dict[str, Any] | None]
    error: Mapped[str | None] = mapped_column(Text)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)

    site: Mapped[Site] = relationship(back_populates="surveys")
    source_file: Mapped[StoredFile | None] = relationship()
    products: Mapped[list[Product]] = relationship(back_populates="survey")
    files: Mapped[list[SurveyFile]] = relationship(
        back_populates="survey", cascade="all, delete-orphan", order_by="SurveyFile.id"
    )


class SurveyFile(Base):
    """One uploaded input of a video or image-set survey: the video, its log, an image."""

    __tablename__ = "survey_files"
    __table_args__ = (UniqueConstraint("survey_id", "name", name="uq_survey_files_survey_name"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    survey_id: Mapped[int] = mapped_column(ForeignKey("surveys.id", ondelete="CASCADE"), index=True)
    role: Mapped[str] = mapped_column(String(16))  # video | log | image
    name: Mapped[str] = mapped_column(String(255))  # the file name as uploaded, made safe
    file_id: Mapped[int] = mapped_column(ForeignKey("stored_files.id"))
    # What the check of the file had to warn about (e.g. a log's unreadable blocks skipped).
    warnings: Mapped[list[str]] = mapped_column(JSON, default=list, server_default="[]")
    created_at: Mapped[datetime] = mapped_column(default=utcnow)

    survey: Mapped[Survey] = relationship(back_populates="files")
    file: Mapped[StoredFile] = relationship()


class Comparison(Base):
    __tablename__ = "comparisons"

    id: Mapped[int] = mapped_column(primary_key=True)
    site_id: Mapped[int] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    pre_survey_id: Mapped[int] = mapped_column(ForeignKey("surveys.id"))
    post_survey_id: Mapped[int] = mapped_column(ForeignKey("surveys.id"))
    # Given by people to tell comparisons apart; empty until one is given (the page then
    # names it by its surveys).
    name: Mapped[str] = mapped_column(String(200), default="", server_default="")
    method: Mapped[str] = mapped_column(String(32))
    parameters: Mapped[dict[str, Any]] = mapped_column(default=dict)
    status: Mapped[JobState] = mapped_column(_enum(JobState, "comparison_status"))
    summary: Mapped[dict[str, Any] | None]
    error: Mapped[str | None] = mapped_column(Text)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    finished_at: Mapped[datetime | None]

    pre_survey: Mapped[Survey] = relationship(foreign_keys=[pre_survey_id])
    post_survey: Mapped[Survey] = relationship(foreign_keys=[post_survey_id])
    detections: Mapped[list[Detection]] = relationship(
        back_populates="comparison", cascade="all, delete-orphan", order_by="Detection.id"
    )
    products: Mapped[list[Product]] = relationship(back_populates="comparison")


class Product(Base):
    """A file made from a survey (its DSM, ...) or by a comparison (Δh, ...)."""

    __tablename__ = "products"
    __table_args__ = (
        CheckConstraint("(survey_id IS NULL) <> (comparison_id IS NULL)", name="one_owner"),
        UniqueConstraint("survey_id", "comparison_id", "kind", name="uq_products_owner_kind"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    site_id: Mapped[int] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    survey_id: Mapped[int | None] = mapped_column(
        ForeignKey("surveys.id", ondelete="CASCADE"), index=True
    )
    comparison_id: Mapped[int | None] = mapped_column(
        ForeignKey("comparisons.id", ondelete="CASCADE"), index=True
    )
    kind: Mapped[str] = mapped_column(String(32))
    file_id: Mapped[int] = mapped_column(ForeignKey("stored_files.id"))
    crs: Mapped[str | None] = mapped_column(Text)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)

    file: Mapped[StoredFile] = relationship()
    survey: Mapped[Survey | None] = relationship(back_populates="products")
    comparison: Mapped[Comparison | None] = relationship(back_populates="products")


class Detection(Base):
    __tablename__ = "detections"

    id: Mapped[int] = mapped_column(primary_key=True)
    comparison_id: Mapped[int] = mapped_column(
        ForeignKey("comparisons.id", ondelete="CASCADE"), index=True
    )
    geometry: Mapped[dict[str, Any]]
    min_lon: Mapped[float] = mapped_column(Float)
    min_lat: Mapped[float] = mapped_column(Float)
    max_lon: Mapped[float] = mapped_column(Float)
    max_lat: Mapped[float] = mapped_column(Float)
    area_m2: Mapped[float] = mapped_column(Float)
    volume_loss_m3: Mapped[float] = mapped_column(Float)
    volume_gain_m3: Mapped[float] = mapped_column(Float)
    max_abs_dh_m: Mapped[float] = mapped_column(Float)
    score: Mapped[float] = mapped_column(Float)
    method: Mapped[str] = mapped_column(String(32))
    # "name@version" of the detection model (cnn method); NULL for the threshold method.
    model_version: Mapped[str | None] = mapped_column(String(200))
    # The feature's 95 % intervals and LoD, as the threshold and scored methods give them:
    # {"area_m2_ci95": [low, high], "volume_loss_m3_ci95": [...], "volume_gain_m3_ci95":
    # [...], "lod_m": median LoD95 over the polygon}; NULL where the method has none (cnn).
    uncertainty: Mapped[dict[str, Any] | None]
    created_at: Mapped[datetime] = mapped_column(default=utcnow)

    comparison: Mapped[Comparison] = relationship(back_populates="detections")
    feedback: Mapped[list[DetectionFeedback]] = relationship(
        cascade="all, delete-orphan", passive_deletes=True, order_by="DetectionFeedback.id"
    )


class Job(Base):
    """Background work run stage by stage (worker/jobs/runner.py) for one owner row: a
    comparison, a survey (reconstruction), a report or a training run."""

    __tablename__ = "jobs"

    id: Mapped[int] = mapped_column(primary_key=True)
    # NULL for the jobs of no site: model training (models are shared by every site).
    site_id: Mapped[int | None] = mapped_column(
        ForeignKey("sites.id", ondelete="CASCADE"), index=True
    )
    kind: Mapped[str] = mapped_column(String(32))
    comparison_id: Mapped[int | None] = mapped_column(
        ForeignKey("comparisons.id", ondelete="CASCADE"), index=True
    )
    survey_id: Mapped[int | None] = mapped_column(
        ForeignKey("surveys.id", ondelete="CASCADE"), index=True
    )
    # Unique: a report or a training run has one job, run again (retried) as a whole, so
    # that two monitoring ticks cannot both create one for the same report.
    report_id: Mapped[int | None] = mapped_column(
        ForeignKey("reports.id", ondelete="CASCADE"), index=True, unique=True
    )
    training_run_id: Mapped[int | None] = mapped_column(
        ForeignKey("training_runs.id", ondelete="CASCADE"), index=True, unique=True
    )
    state: Mapped[JobState] = mapped_column(_enum(JobState, "job_state"), index=True)
    error: Mapped[str | None] = mapped_column(Text)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    started_at: Mapped[datetime | None]
    finished_at: Mapped[datetime | None]

    stages: Mapped[list[StageRun]] = relationship(
        back_populates="job", cascade="all, delete-orphan", order_by="StageRun.position"
    )


class StageRun(Base):
    __tablename__ = "stage_runs"
    __table_args__ = (UniqueConstraint("job_id", "stage", name="uq_stage_runs_job_stage"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    job_id: Mapped[int] = mapped_column(ForeignKey("jobs.id", ondelete="CASCADE"), index=True)
    stage: Mapped[str] = mapped_column(String(32))
    position: Mapped[int] = mapped_column(Integer)
    state: Mapped[StageState] = mapped_column(_enum(StageState, "stage_state"))
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    queued_at: Mapped[datetime | None]
    started_at: Mapped[datetime | None]
    finished_at: Mapped[datetime | None]
    heartbeat_at: Mapped[datetime | None]
    error: Mapped[str | None] = mapped_column(Text)
    result: Mapped[dict[str, Any] | None]
    # What happened while it ran, one line each ("HH:MM:SS LEVEL message"), over all its
    # attempts: what the page shows as the stage's log (worker/jobs/runner.py).
    log: Mapped[list[str]] = mapped_column(JSON, default=list, server_default="[]")

    job: Mapped[Job] = relationship(back_populates="stages")


# --- GIS users, alerts, monitoring schedules and reports ------------------------------------


class DeliveryStatus(enum.StrEnum):
    pending = "pending"
    retrying = "retrying"
    delivered = "delivered"
    failed = "failed"


class AlertSettings(Base):
    """When a site's comparison alerts: detections above every one of these thresholds."""

    __tablename__ = "alert_settings"

    site_id: Mapped[int] = mapped_column(
        ForeignKey("sites.id", ondelete="CASCADE"), primary_key=True
    )
    min_area_m2: Mapped[float] = mapped_column(Float, default=0.0)
    min_volume_m3: Mapped[float] = mapped_column(Float, default=0.0)
    min_score: Mapped[float] = mapped_column(Float, default=0.0)
    email_recipients: Mapped[list[str]] = mapped_column(JSON, default=list)
    notify_job_failures: Mapped[bool] = mapped_column(Boolean, default=True)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow)


class Webhook(Base):
    __tablename__ = "webhooks"

    id: Mapped[int] = mapped_column(primary_key=True)
    site_id: Mapped[int] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    url: Mapped[str] = mapped_column(String(2048))
    # Needed in clear to sign each call (HMAC); shown to the user once, at creation.
    secret: Mapped[str] = mapped_column(String(128))
    events: Mapped[list[str]] = mapped_column(JSON, default=list)
    active: Mapped[bool] = mapped_column(Boolean, default=True)
    description: Mapped[str] = mapped_column(String(200), default="")
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Schedule(Base):
    """A monitoring schedule: a report of the site at every time its cron expression names."""

    __tablename__ = "schedules"

    id: Mapped[int] = mapped_column(primary_key=True)
    site_id: Mapped[int] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(200), default="")
    cron: Mapped[str] = mapped_column(String(120))
    timezone: Mapped[str] = mapped_column(String(64), default="UTC")
    enabled: Mapped[bool] = mapped_column(Boolean, default=True)
    next_run_at: Mapped[datetime] = mapped_column(index=True)
    last_run_at: Mapped[datetime | None]
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Report(Base):
    __tablename__ = "reports"
    __table_args__ = (
        # A schedule's run at one time makes one report, however many ticks see it due.
        UniqueConstraint("schedule_id", "scheduled_for", name="uq_reports_schedule_run"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    site_id: Mapped[int] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    schedule_id: Mapped[int | None] = mapped_column(
        ForeignKey("schedules.id", ondelete="SET NULL"), index=True
    )
    scheduled_for: Mapped[datetime | None]
    comparison_id: Mapped[int | None] = mapped_column(
        ForeignKey("comparisons.id", ondelete="SET NULL")
    )
    trigger: Mapped[str] = mapped_column(String(16))
    # The language it is written in; None until built for a scheduled report, which
    # takes its site's language then.
    language: Mapped[str | None] = mapped_column(String(16))
    status: Mapped[JobState] = mapped_column(_enum(JobState, "report_status"))
    summary: Mapped[dict[str, Any] | None]
    pdf_file_id: Mapped[int | None] = mapped_column(ForeignKey("stored_files.id"))
    html_file_id: Mapped[int | None] = mapped_column(ForeignKey("stored_files.id"))
    error: Mapped[str | None] = mapped_column(Text)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    finished_at: Mapped[datetime | None]

    pdf_file: Mapped[StoredFile | None] = relationship(foreign_keys=[pdf_file_id])
    html_file: Mapped[StoredFile | None] = relationship(foreign_keys=[html_file_id])
    # The job that builds it (kind "report"); its stage runs say how far the build is.
    job: Mapped[Job | None] = relationship(viewonly=True)


class Delivery(Base):
    """One message to one webhook or one set of e-mail recipients, with its attempts."""

    __tablename__ = "deliveries"

    id: Mapped[int] = mapped_column(primary_key=True)
    site_id: Mapped[int] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    channel: Mapped[str] = mapped_column(String(16))  # webhook | email
    webhook_id: Mapped[int | None] = mapped_column(
        ForeignKey("webhooks.id", ondelete="CASCADE"), index=True
    )
    recipients: Mapped[list[str] | None] = mapped_column(JSON)
    report_id: Mapped[int | None] = mapped_column(ForeignKey("reports.id", ondelete="SET NULL"))
    event: Mapped[str] = mapped_column(String(32))
    # Identifies the event and target: an event is never delivered twice to one target.
    dedupe_key: Mapped[str] = mapped_column(String(200), unique=True)
    payload: Mapped[dict[str, Any]]
    status: Mapped[DeliveryStatus] = mapped_column(_enum(DeliveryStatus, "delivery_status"))
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    next_attempt_at: Mapped[datetime | None]
    delivered_at: Mapped[datetime | None]
    last_error: Mapped[str | None] = mapped_column(Text)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)

    attempt_log: Mapped[list[DeliveryAttempt]] = relationship(
        back_populates="delivery", cascade="all, delete-orphan", order_by="DeliveryAttempt.id"
    )


class DeliveryAttempt(Base):
    __tablename__ = "delivery_attempts"

    id: Mapped[int] = mapped_column(primary_key=True)
    delivery_id: Mapped[int] = mapped_column(
        ForeignKey("deliveries.id", ondelete="CASCADE"), index=True
    )
    attempt: Mapped[int] = mapped_column(Integer)
    at: Mapped[datetime] = mapped_column(default=utcnow)
    status_code: Mapped[int | None] = mapped_column(Integer)
    error: Mapped[str | None] = mapped_column(Text)
    duration_ms: Mapped[float] = mapped_column(Float, default=0.0)

    delivery: Mapped[Delivery] = relationship(back_populates="attempt_log")


# --- The map: users, resumable uploads, feedback on detections ------------------------------


class User(Base):
    """A person who signs in to the map with a password (stored as a scrypt hash)."""

    __tablename__ = "users"

    id: Mapped[int] = mapped_column(primary_key=True)
    username: Mapped[str] = mapped_column(String(100), unique=True)
    display_name: Mapped[str] = mapped_column(String(200), default="")
    password_hash: Mapped[str] = mapped_column(String(255))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    last_login_at: Mapped[datetime | None]
    disabled_at: Mapped[datetime | None]


class SignInFailure(Base):
    """A sign-in refused for a wrong user name or password: what throttles guessing."""

    __tablename__ = "sign_in_failures"

    id: Mapped[int] = mapped_column(primary_key=True)
    username: Mapped[str] = mapped_column(String(100), index=True)  # as typed, known or not
    address: Mapped[str] = mapped_column(String(64), index=True)  # the client's IP address
    at: Mapped[datetime] = mapped_column(default=utcnow, index=True)


class UploadState(enum.StrEnum):
    receiving = "receiving"
    complete = "complete"
    failed = "failed"


class Upload(Base):
    """A resumable (tus) upload: its bytes accumulate in storage until complete."""

    __tablename__ = "uploads"

    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    site_id: Mapped[int] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    purpose: Mapped[str] = mapped_column(String(16))  # dsm | survey_file
    filename: Mapped[str] = mapped_column(String(512))
    length: Mapped[int] = mapped_column(BigInteger)
    offset: Mapped[int] = mapped_column(BigInteger, default=0)
    sha256: Mapped[str | None] = mapped_column(String(64))  # expected, from the client
    details: Mapped[dict[str, Any]] = mapped_column(default=dict)  # validated metadata
    state: Mapped[UploadState] = mapped_column(_enum(UploadState, "upload_state"))
    error: Mapped[str | None] = mapped_column(Text)
    survey_id: Mapped[int | None] = mapped_column(ForeignKey("surveys.id", ondelete="SET NULL"))
    created_by: Mapped[str] = mapped_column(String(200), default="")
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    completed_at: Mapped[datetime | None]
    expires_at: Mapped[datetime] = mapped_column(index=True)


class Verdict(enum.StrEnum):
    confirmed = "confirmed"
    false_alarm = "false_alarm"


class DetectionFeedback(Base):
    """A person's verdict on one detection; the training labels of the detection model."""

    __tablename__ = "detection_feedback"
    __table_args__ = (
        # One verdict per detection and person: changing one's mind updates it.
        UniqueConstraint("detection_id", "author", name="uq_detection_feedback_author"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    detection_id: Mapped[int] = mapped_column(
        ForeignKey("detections.id", ondelete="CASCADE"), index=True
    )
    verdict: Mapped[Verdict] = mapped_column(_enum(Verdict, "verdict"))
    note: Mapped[str] = mapped_column(Text, default="")
    user_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    author: Mapped[str] = mapped_column(String(200))  # user name, or "token NAME"
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow)


# --- Detection models ------------------------------------------------------------------------


class ModelVersion(Base):
    """A detection model the cnn method can run: its weights file and its model card.

    `location` says where `weights_path` points: "package" (relative to the shipped
    weights folder, worker/pipeline/cnn/weights) or "storage" (relative to the storage
    root: models trained by the platform). The card (metrics, training data, decision
    rule) sits next to the weights as `<name>.json` and is copied here.
    """

    __tablename__ = "model_versions"
    __table_args__ = (UniqueConstraint("name", "version", name="uq_model_versions_name_version"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(100))
    version: Mapped[str] = mapped_column(String(64))
    kind: Mapped[str] = mapped_column(String(32))  # slidenet | patchnet
    location: Mapped[str] = mapped_column(String(16))  # package | storage
    weights_path: Mapped[str] = mapped_column(String(1024))
    weights_sha256: Mapped[str] = mapped_column(String(64))
    card: Mapped[dict[str, Any]]
    is_default: Mapped[bool] = mapped_column(Boolean, default=False)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class TrainingRun(Base):
    """One training of a detection model in the worker: what was asked for and, once the
    model is registered, its "name@version". Its job (kind "training") says where it
    stands; the weights and checkpoints live in storage under models/<name>/<run>/."""

    __tablename__ = "training_runs"

    id: Mapped[int] = mapped_column(primary_key=True)
    run: Mapped[str] = mapped_column(String(32), unique=True)  # the id the API hands out
    name: Mapped[str] = mapped_column(String(100))
    model_kind: Mapped[str] = mapped_column(String(32))
    dataset: Mapped[str] = mapped_column(String(1024))  # manifest, relative to storage
    seed: Mapped[int] = mapped_column(Integer, default=0)
    options: Mapped[dict[str, Any]] = mapped_column(default=dict)
    make_default: Mapped[bool] = mapped_column(Boolean, default=False)
    model: Mapped[str | None] = mapped_column(String(200))
    metrics: Mapped[dict[str, Any] | None]  # validation metrics, seconds, epochs run
    created_at: Mapped[datetime] = mapped_column(default=utcnow)

    job: Mapped[Job | None] = relationship(viewonly=True)


# --- Organisations: a site made without one belongs to the default organisation -------------

DEFAULT_ORGANISATION = "Default organisation"


def default_organisation(session: Session) -> Organisation:
    """The organisation of the data that existed before organisations did (made by the
    migration), and of sites made without naming one; made again if it is missing."""
    with session.no_autoflush:
        found = session.scalar(select(Organisation).where(Organisation.is_default.is_(True)))
    if found is None:
        found = Organisation(name=DEFAULT_ORGANISATION, is_default=True)
        session.add(found)
    return found


@event.listens_for(Session, "before_flush")
def _sites_without_organisation(session: Session, _context: object, _instances: object) -> None:
    for item in session.new:
        if isinstance(item, Site) and item.organisation_id is None and item.organisation is None:
            item.organisation = default_organisation(session)
