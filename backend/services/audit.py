"""The audit log: who changed what, kept when the thing itself is gone.

Routes that change sites, alert settings, webhooks, schedules, members, tokens and users,
or delete anything, record one entry in the same transaction as the change.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.db.models import ApiToken, AuditEntry, Site
from backend.services.users import author_of


def record(
    session: Session,
    token: ApiToken,
    action: str,
    *,
    site: Site | None = None,
    organisation_id: int | None = None,
    target: str = "",
    details: dict[str, Any] | None = None,
) -> AuditEntry:
    entry = AuditEntry(
        actor=author_of(token),
        action=action,
        site_id=site.id if site is not None else None,
        organisation_id=site.organisation_id if site is not None else organisation_id,
        target=target[:200],
        details=details or {},
    )
    session.add(entry)
    return entry


def entries(
    session: Session, organisation_id: int, limit: int, before: int | None
) -> list[AuditEntry]:
    """The organisation's entries, newest first; `before`: entries older than that id."""
    query = select(AuditEntry).where(AuditEntry.organisation_id == organisation_id)
    if before is not None:
        query = query.where(AuditEntry.id < before)
    return list(session.scalars(query.order_by(AuditEntry.id.desc()).limit(limit)))
