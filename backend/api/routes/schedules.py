"""Monitoring schedules of a site: a report at every time a cron expression names."""

from typing import Annotated

from fastapi import APIRouter, HTTPException, Query, Response, status
from sqlalchemy import select

from backend.api.access import SignedIn, SiteManager, SiteViewer
from backend.api.deps import SessionDep, owned_by_site
from backend.api.schemas_monitoring import (
    ScheduleCreate,
    ScheduleOut,
    SchedulePreview,
    ScheduleUpdate,
)
from backend.db.models import Schedule
from backend.ids import RowId
from backend.services.audit import record
from backend.services.schedules import ScheduleRejected, check, next_run, next_runs, utcnow

router = APIRouter(prefix="/sites/{site_id}/schedules", tags=["schedules"])


def _checked(cron: str, timezone: str) -> None:
    try:
        check(cron, timezone)
    except ScheduleRejected as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None


def _first_run(body_next_run_at, cron: str, timezone: str):
    if body_next_run_at is None:
        return next_run(cron, timezone, utcnow())
    if body_next_run_at.tzinfo is None:
        raise HTTPException(
            status.HTTP_422_UNPROCESSABLE_CONTENT,
            "next_run_at needs a time zone offset, e.g. 2026-06-01T06:00:00Z",
        )
    return body_next_run_at


@router.post("", response_model=ScheduleOut, status_code=status.HTTP_201_CREATED)
def create_schedule(
    body: ScheduleCreate, site: SiteManager, session: SessionDep, token: SignedIn
) -> Schedule:
    """Beat runs it: each run makes a report of the site's latest comparison."""
    _checked(body.cron, body.timezone)
    schedule = Schedule(
        site_id=site.id,
        name=body.name,
        cron=body.cron,
        timezone=body.timezone,
        enabled=body.enabled,
        next_run_at=_first_run(body.next_run_at, body.cron, body.timezone),
    )
    session.add(schedule)
    session.flush()
    record(session, token, "schedule.create", site=site, target=f"schedule {schedule.id}",
           details={"cron": schedule.cron, "timezone": schedule.timezone})  # fmt: skip
    session.commit()
    return schedule


@router.get("", response_model=list[ScheduleOut])
def list_schedules(site: SiteViewer, session: SessionDep) -> list[Schedule]:
    query = select(Schedule).where(Schedule.site_id == site.id).order_by(Schedule.id)
    return list(session.scalars(query))


@router.get(
    "/preview",
    response_model=SchedulePreview,
    summary="The next times a cron expression names, before it is saved",
)
def preview_schedule(
    site: SiteViewer,
    cron: Annotated[str, Query(max_length=120, description="Five-field cron expression.")],
    timezone: Annotated[str, Query(max_length=64, description="IANA time zone.")] = "UTC",
    count: Annotated[int, Query(ge=1, le=20)] = 5,
) -> SchedulePreview:
    """The page's cron builder shows these; the times are computed by the same code that
    runs the schedule, so what is shown is what will run. An expression that cannot run is
    answered 422 with the reason."""
    _checked(cron, timezone)
    return SchedulePreview(
        cron=cron, timezone=timezone, next_runs=next_runs(cron, timezone, utcnow(), count)
    )


@router.get("/{schedule_id}", response_model=ScheduleOut)
def get_schedule(schedule_id: RowId, site: SiteViewer, session: SessionDep) -> Schedule:
    return owned_by_site(session, Schedule, site, schedule_id, "schedule")


@router.patch("/{schedule_id}", response_model=ScheduleOut)
def update_schedule(
    schedule_id: RowId,
    body: ScheduleUpdate,
    site: SiteManager,
    session: SessionDep,
    token: SignedIn,
) -> Schedule:
    """A new cron or time zone moves the next run to the next time it names."""
    schedule = owned_by_site(session, Schedule, site, schedule_id, "schedule")
    changes = body.model_dump(exclude_unset=True)
    cron = changes.get("cron") or schedule.cron
    timezone = changes.get("timezone") or schedule.timezone
    _checked(cron, timezone)
    for field in ("name", "enabled"):
        if changes.get(field) is not None:
            setattr(schedule, field, changes[field])
    if "cron" in changes or "timezone" in changes or changes.get("next_run_at"):
        schedule.cron, schedule.timezone = cron, timezone
        schedule.next_run_at = _first_run(changes.get("next_run_at"), cron, timezone)
    record(session, token, "schedule.update", site=site, target=f"schedule {schedule.id}",
           details={k: str(v) for k, v in changes.items()})  # fmt: skip
    session.commit()
    return schedule


@router.delete("/{schedule_id}", status_code=status.HTTP_204_NO_CONTENT)
def delete_schedule(
    schedule_id: RowId, site: SiteManager, session: SessionDep, token: SignedIn
) -> Response:
    """Delete the schedule; its reports stay."""
    schedule = owned_by_site(session, Schedule, site, schedule_id, "schedule")
    record(session, token, "schedule.delete", site=site, target=f"schedule {schedule.id}",
           details={"cron": schedule.cron})  # fmt: skip
    session.delete(schedule)
    session.commit()
    return Response(status_code=status.HTTP_204_NO_CONTENT)
