"""API tokens: random secrets shown once, stored only as SHA-256 hashes."""

import hashlib
import secrets
from datetime import UTC, datetime

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.db.models import ApiToken

TOKEN_PREFIX = "sw_"


def hash_token(token: str) -> str:
    # Tokens are 256-bit random secrets, so a fast hash is enough (no dictionary attack).
    return hashlib.sha256(token.encode()).hexdigest()


def create_token(session: Session, name: str) -> str:
    """Store a new token and return its secret (the only time it is visible)."""
    token = TOKEN_PREFIX + secrets.token_urlsafe(32)
    session.add(ApiToken(name=name, token_hash=hash_token(token), prefix=token[:10]))
    session.flush()
    return token


def authenticate(session: Session, token: str) -> ApiToken | None:
    found = session.scalar(
        select(ApiToken).where(
            ApiToken.token_hash == hash_token(token), ApiToken.revoked_at.is_(None)
        )
    )
    if found is not None:
        found.last_used_at = datetime.now(UTC)
    return found


def has_tokens(session: Session) -> bool:
    return session.scalar(select(ApiToken.id).limit(1)) is not None
