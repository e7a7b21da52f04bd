"""Throttling of password guessing: failed sign-ins per account and per client address.

Each refused sign-in is recorded (backend/db/models.py: SignInFailure). When an account has
had SLIDEWATCH_SIGN_IN_MAX_FAILURES failures within SLIDEWATCH_SIGN_IN_LOCKOUT_S, or an
address SLIDEWATCH_SIGN_IN_MAX_FAILURES_PER_ADDRESS, further sign-ins are refused without
looking at the password (even the right one: that is what stops guessing) until enough of
those failures have aged out of the window. A name that is no account counts like one, so
that the answers do not tell which names exist. A successful sign-in clears its account's
failures and tells the person how many there were.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from backend.config import Settings
from backend.db.models import SignInFailure
from backend.db.tokens import as_utc


@dataclass(frozen=True)
class Lockout:
    """Sign-ins refused for `retry_after_s` more seconds, for the account or the address."""

    scope: str  # "account" | "address"
    retry_after_s: int
    until: datetime

    def message(self, username: str) -> str:
        who = f"the account {username!r}" if self.scope == "account" else "your address"
        return (
            f"too many failed sign-ins to {who}: sign-in is locked until "
            f"{self.until:%Y-%m-%d %H:%M:%S} UTC (in {self.retry_after_s} s)"
        )


def _window(settings: Settings) -> timedelta:
    return timedelta(seconds=settings.sign_in_lockout_s)


def lockout(
    session: Session, settings: Settings, username: str, address: str, now: datetime
) -> Lockout | None:
    """Whether sign-ins to `username` or from `address` are locked out now."""
    session.execute(delete(SignInFailure).where(SignInFailure.at < now - _window(settings)))
    for scope, column, value, limit in (
        ("account", SignInFailure.username, username, settings.sign_in_max_failures),
        ("address", SignInFailure.address, address, settings.sign_in_max_failures_per_address),
    ):
        recent = session.scalars(
            select(SignInFailure.at)
            .where(column == value, SignInFailure.at >= now - _window(settings))
            .order_by(SignInFailure.at.desc())
            .limit(limit)
        ).all()
        if len(recent) >= limit:
            # Open again when the oldest of the last `limit` failures leaves the window.
            until = as_utc(recent[-1]) + _window(settings)
            wait = max(1, math.ceil((until - now).total_seconds()))
            return Lockout(scope, wait, until)
    return None


def record_failure(session: Session, username: str, address: str, now: datetime) -> None:
    session.add(SignInFailure(username=username[:100], address=address[:64], at=now))


def clear_account(session: Session, username: str) -> str | None:
    """Forget the account's failures; a notice of them for the person now signed in."""
    failures = session.scalars(
        select(SignInFailure).where(SignInFailure.username == username).order_by(SignInFailure.at)
    ).all()
    if not failures:
        return None
    last = failures[-1]
    session.execute(delete(SignInFailure).where(SignInFailure.username == username))
    count = len(failures)
    return (
        f"{count} failed sign-in{'s' if count != 1 else ''} to your account since "
        f"{as_utc(failures[0].at):%Y-%m-%d %H:%M} UTC, the last from {last.address} at "
        f"{as_utc(last.at):%H:%M} UTC; if that was not you, change your password"
    )


def utcnow() -> datetime:
    return datetime.now(UTC)
