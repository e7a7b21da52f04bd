"""User accounts of the map: create them, sign in (a session token that expires), sign out.

A session is an ordinary API token (backend/db/tokens.py) tied to the user, with an expiry;
so every route that takes a platform token takes a signed-in user's token too.
"""

import re
import secrets
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.db.models import ApiToken, User
from backend.db.tokens import TOKEN_PREFIX, hash_token
from backend.passwords import hash_password, password_problem, verify_password

USERNAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._@-]{0,99}$")
# Spent on an unknown user name too, so that the answer time does not tell which names exist.
_DUMMY_HASH = hash_password(secrets.token_urlsafe(16))


class UserRejected(ValueError):
    """The account cannot be created as asked; the message says why."""


class SignInFailed(Exception):
    pass


@dataclass(frozen=True)
class SignedIn:
    token: str
    user: User
    expires_at: datetime


def create_user(session: Session, username: str, password: str, display_name: str = "") -> User:
    if not USERNAME_PATTERN.match(username):
        raise UserRejected(
            "the user name must be 1 to 100 letters, digits or . _ @ -, starting with a "
            "letter or digit"
        )
    problem = password_problem(password, username)
    if problem:
        raise UserRejected(problem)
    if session.scalar(select(User.id).where(User.username == username)) is not None:
        raise UserRejected(f"a user named {username!r} exists")
    user = User(username=username, display_name=display_name, password_hash=hash_password(password))
    session.add(user)
    session.flush()
    return user


def set_password(session: Session, user: User, password: str) -> None:
    problem = password_problem(password, user.username)
    if problem:
        raise UserRejected(problem)
    user.password_hash = hash_password(password)
    # Every session of the old password ends.
    for token in session.scalars(select(ApiToken).where(ApiToken.user_id == user.id)):
        token.revoked_at = token.revoked_at or datetime.now(UTC)


def change_password(session: Session, user: User, current: str, new: str) -> None:
    """Set a new password if `current` is the user's; every session and token of the
    user ends (SignInFailed for a wrong current password, UserRejected for a weak one)."""
    if not verify_password(current, user.password_hash):
        raise SignInFailed
    if current == new:
        raise UserRejected("the new password must differ from the current one")
    set_password(session, user, new)


def disable_user(session: Session, user: User) -> None:
    """The user can no longer sign in, and every session and token of theirs ends."""
    now = datetime.now(UTC)
    user.disabled_at = user.disabled_at or now
    for token in session.scalars(select(ApiToken).where(ApiToken.user_id == user.id)):
        token.revoked_at = token.revoked_at or now


def enable_user(user: User) -> None:
    user.disabled_at = None


def sign_in(session: Session, username: str, password: str, hours: float) -> SignedIn:
    """A new session token for the user; SignInFailed for a wrong name or password."""
    user = session.scalar(select(User).where(User.username == username))
    if user is None:
        verify_password(password, _DUMMY_HASH)
        raise SignInFailed
    if not verify_password(password, user.password_hash) or user.disabled_at is not None:
        raise SignInFailed
    now = datetime.now(UTC)
    secret = TOKEN_PREFIX + secrets.token_urlsafe(32)
    expires_at = now + timedelta(hours=hours)
    session.add(
        ApiToken(
            name=f"map session of {user.username}",
            token_hash=hash_token(secret),
            prefix=secret[:10],
            user_id=user.id,
            expires_at=expires_at,
            kind="session",
        )
    )
    user.last_login_at = now
    session.flush()
    return SignedIn(secret, user, expires_at)


def sign_out(session: Session, token: ApiToken) -> None:
    """End a user's session. A platform API token used to sign in is only forgotten by the
    page, never revoked here: it may serve GIS clients and scripts too."""
    if token.user_id is not None:
        token.revoked_at = datetime.now(UTC)


def author_of(token: ApiToken) -> str:
    """Who did something, as recorded with it: the user name, or the API token's name."""
    if token.user is not None:
        return token.user.username
    return f"token {token.name}"
