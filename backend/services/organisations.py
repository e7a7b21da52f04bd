"""Organisations and their members: who holds which role.

A manager adds, changes and removes members up to manager; only an admin makes or
unmakes admins, and the last admin of an organisation cannot be removed or demoted (so
that someone can always manage it). Every change goes to the audit log.
"""

from __future__ import annotations

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from backend.db.models import ApiToken, Membership, Organisation, Role, User
from backend.services.audit import record


class MemberRejected(ValueError):
    """The change cannot be made; `status` is the HTTP answer, the message says why."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


def create_organisation(session: Session, token: ApiToken, name: str) -> Organisation:
    if session.scalar(select(Organisation.id).where(Organisation.name == name)) is not None:
        raise MemberRejected(409, f"an organisation named {name!r} exists")
    organisation = Organisation(name=name)
    session.add(organisation)
    session.flush()
    record(session, token, "organisation.create", organisation_id=organisation.id, target=name)
    return organisation


def members(session: Session, organisation: Organisation) -> list[Membership]:
    return list(
        session.scalars(
            select(Membership)
            .where(Membership.organisation_id == organisation.id)
            .order_by(Membership.id)
        )
    )


def _membership(
    session: Session, organisation: Organisation, username: str
) -> tuple[User, Membership | None]:
    user = session.scalar(select(User).where(User.username == username))
    if user is None:
        raise MemberRejected(404, f"no user named {username!r}")
    held = session.scalar(
        select(Membership).where(
            Membership.organisation_id == organisation.id, Membership.user_id == user.id
        )
    )
    return user, held


def _admins(session: Session, organisation: Organisation) -> int:
    return (
        session.scalar(
            select(func.count()).where(
                Membership.organisation_id == organisation.id, Membership.role == Role.admin
            )
        )
        or 0
    )


def _check_rank(acting: Role, *roles: Role | None) -> None:
    if acting != Role.admin and Role.admin in roles:
        raise MemberRejected(403, "only an admin of the organisation makes or unmakes admins")


def set_member(
    session: Session,
    token: ApiToken,
    acting: Role,
    organisation: Organisation,
    username: str,
    role: Role,
) -> Membership:
    user, held = _membership(session, organisation, username)
    _check_rank(acting, role, held.role if held else None)
    demoted = held is not None and held.role == Role.admin and role != Role.admin
    if demoted and _admins(session, organisation) <= 1:
        raise MemberRejected(409, f"{username} is the last admin of {organisation.name}")
    before = held.role.value if held else None
    if held is None:
        held = Membership(organisation_id=organisation.id, user_id=user.id, role=role)
        session.add(held)
    held.role = role
    session.flush()
    record(
        session, token, "member.set", organisation_id=organisation.id, target=username,
        details={"role": role.value, "before": before},
    )  # fmt: skip
    return held


def remove_member(
    session: Session, token: ApiToken, acting: Role, organisation: Organisation, username: str
) -> None:
    _, held = _membership(session, organisation, username)
    if held is None:
        raise MemberRejected(404, f"{username} is not a member of {organisation.name}")
    _check_rank(acting, held.role)
    if held.role == Role.admin and _admins(session, organisation) <= 1:
        raise MemberRejected(409, f"{username} is the last admin of {organisation.name}")
    session.delete(held)
    record(
        session, token, "member.remove", organisation_id=organisation.id, target=username,
        details={"role": held.role.value},
    )  # fmt: skip
