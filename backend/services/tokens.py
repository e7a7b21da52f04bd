"""API tokens as their holders manage them: list, make (with an expiry), revoke.

Whoever calls sees the tokens of the same holder: a user their own (map sessions and
API tokens made for their programs), an API token of the platform (one that belongs to
no user, as `slidewatch create-token` makes) the platform's. Secrets are shown once, when
made; afterwards a token is known by its id, name and first characters (`prefix`).
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

from sqlalchemy import Select, select
from sqlalchemy.orm import Session

from backend.db.access import is_platform_admin, role_on_site
from backend.db.models import ApiToken, Organisation, Role, Site
from backend.db.tokens import as_utc, create_token, hash_token


class TokenRejected(ValueError):
    """A token that cannot be made as asked; the message says why."""


def _of_holder(caller: ApiToken) -> Select:
    """A user's tokens; a service's tokens (its organisation's); or, for the platform
    administrator, every token of no user (its own and the services')."""
    query = select(ApiToken)
    if caller.user_id is not None:
        return query.where(ApiToken.user_id == caller.user_id)
    query = query.where(ApiToken.user_id.is_(None))
    if caller.organisation_id is not None:
        return query.where(ApiToken.organisation_id == caller.organisation_id)
    return query


def list_tokens(session: Session, caller: ApiToken, include_ended: bool = False) -> list[ApiToken]:
    """The holder's tokens, newest first; without `include_ended`, only those still valid."""
    tokens = session.scalars(_of_holder(caller).order_by(ApiToken.id.desc())).all()
    if include_ended:
        return list(tokens)
    return [t for t in tokens if is_valid(t)]


def is_valid(token: ApiToken, now: datetime | None = None) -> bool:
    now = now or datetime.now(UTC)
    expired = token.expires_at is not None and as_utc(token.expires_at) <= now
    return token.revoked_at is None and not expired


def issue_token(
    session: Session,
    caller: ApiToken,
    name: str,
    days: float,
    max_days: float,
    *,
    role: Role | None = None,
    site_id: int | None = None,
    organisation_id: int | None = None,
) -> tuple[ApiToken, str]:
    """A new API token of the caller's holder, valid `days`; its row and its secret.

    `role` holds it to that role (never more than the caller's own), `site_id` to one
    site (one the caller sees; a token held to a site makes only tokens of that site).
    The platform administrator makes a service's token by naming its `organisation_id`.
    """
    if not 0 < days <= max_days:
        raise TokenRejected(
            f"a token may be valid for up to {max_days:g} days (SLIDEWATCH_TOKEN_MAX_DAYS), "
            f"not {days:g}"
        )
    if organisation_id is not None and not is_platform_admin(caller):
        raise TokenRejected("only the platform administrator makes a service's token")
    if caller.site_id is not None and site_id not in (None, caller.site_id):
        raise TokenRejected(f"this token reaches site {caller.site_id} only")
    site_id = site_id if site_id is not None else caller.site_id
    if site_id is not None:
        site = session.get(Site, site_id)
        if site is None or role_on_site(session, caller, site) is None:
            raise LookupError(f"site {site_id} not found")
        if organisation_id is not None and site.organisation_id != organisation_id:
            raise TokenRejected(f"site {site_id} is not of organisation {organisation_id}")
    if organisation_id is not None and session.get(Organisation, organisation_id) is None:
        raise LookupError(f"organisation {organisation_id} not found")
    if caller.role is not None:  # a capped token makes tokens capped as much
        role = caller.role if role is None else min(role, caller.role, key=lambda r: r.rank)
    if organisation_id is None and caller.user_id is None:
        organisation_id = caller.organisation_id
    if organisation_id is not None and caller.user_id is None and role is None:
        role = Role.viewer  # a service's token says what it may do
    secret = create_token(
        session,
        name,
        expires_at=datetime.now(UTC) + timedelta(days=days),
        user_id=caller.user_id,
    )
    token = session.scalars(select(ApiToken).where(ApiToken.token_hash == hash_token(secret))).one()
    token.role, token.site_id, token.organisation_id = role, site_id, organisation_id
    session.flush()
    return token, secret


def revoke_token(session: Session, caller: ApiToken, token_id: int) -> ApiToken:
    """Revoke one of the holder's tokens (the caller's own too); LookupError if it has
    none of that id."""
    token = session.scalar(_of_holder(caller).where(ApiToken.id == token_id))
    if token is None:
        raise LookupError(f"token {token_id} not found")
    token.revoked_at = token.revoked_at or datetime.now(UTC)
    return token
