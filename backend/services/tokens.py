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

from backend.db.models import ApiToken
from backend.db.tokens import as_utc, create_token, hash_token


class TokenRejected(ValueError):
    """A token that cannot be made as asked; the message says why."""


def _of_holder(caller: ApiToken) -> Select:
    query = select(ApiToken)
    if caller.user_id is None:
        return query.where(ApiToken.user_id.is_(None))
    return query.where(ApiToken.user_id == caller.user_id)


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
    session: Session, caller: ApiToken, name: str, days: float, max_days: float
) -> tuple[ApiToken, str]:
    """A new API token of the caller's holder, valid `days`; its row and its secret."""
    if not 0 < days <= max_days:
        raise TokenRejected(
            f"a token may be valid for up to {max_days:g} days (SLIDEWATCH_TOKEN_MAX_DAYS), "
            f"not {days:g}"
        )
    secret = create_token(
        session,
        name,
        expires_at=datetime.now(UTC) + timedelta(days=days),
        user_id=caller.user_id,
    )
    token = session.scalars(select(ApiToken).where(ApiToken.token_hash == hash_token(secret))).one()
    return token, secret


def revoke_token(session: Session, caller: ApiToken, token_id: int) -> ApiToken:
    """Revoke one of the holder's tokens (the caller's own too); LookupError if it has
    none of that id."""
    token = session.scalar(_of_holder(caller).where(ApiToken.id == token_id))
    if token is None:
        raise LookupError(f"token {token_id} not found")
    token.revoked_at = token.revoked_at or datetime.now(UTC)
    return token
