"""API tokens: random secrets shown once, stored only as SHA-256 hashes.

The same tokens, with an expiry and a user, are the sessions of people signed in to the map
(backend/services/users.py); a token of a user who is disabled opens nothing.
"""

import hashlib
import secrets
from datetime import UTC, datetime, timedelta

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.db.models import ApiToken

TOKEN_PREFIX = "sw_"
LAST_USED_RESOLUTION = timedelta(minutes=1)


def hash_token(token: str) -> str:
    # Tokens are 256-bit random secrets, so a fast hash is enough (no dictionary attack).
    return hashlib.sha256(token.encode()).hexdigest()


def create_token(
    session: Session,
    name: str,
    *,
    expires_at: datetime | None = None,
    user_id: int | None = None,
    kind: str = "api",
) -> str:
    """Store a new token and return its secret (the only time it is visible)."""
    token = TOKEN_PREFIX + secrets.token_urlsafe(32)
    session.add(
        ApiToken(
            name=name,
            token_hash=hash_token(token),
            prefix=token[:10],
            expires_at=expires_at,
            user_id=user_id,
            kind=kind,
        )
    )
    session.flush()
    return token


def authenticate(session: Session, token: str) -> ApiToken | None:
    found = session.scalar(
        select(ApiToken).where(
            ApiToken.token_hash == hash_token(token), ApiToken.revoked_at.is_(None)
        )
    )
    if found is None:
        return None
    now = datetime.now(UTC)
    if found.expires_at is not None and as_utc(found.expires_at) <= now:
        return None  # run out: sign in again, or make a new token
    if found.user is not None and found.user.disabled_at is not None:
        return None
    # Written at most once a minute: the map asks for dozens of tiles a second with one
    # token, and a write per request would make them wait for each other on the token's
    # row (and on SQLite's single write lock, across the API's processes).
    if found.last_used_at is None or now - as_utc(found.last_used_at) >= LAST_USED_RESOLUTION:
        found.last_used_at = now
    return found


def as_utc(moment: datetime) -> datetime:
    """`moment` as an aware UTC datetime (SQLite gives back naive ones, meant as UTC)."""
    return moment.replace(tzinfo=UTC) if moment.tzinfo is None else moment.astimezone(UTC)


def has_tokens(session: Session) -> bool:
    return session.scalar(select(ApiToken.id).limit(1)) is not None
