"""Organisations, their members with their roles, and their audit log."""

from fastapi import APIRouter, HTTPException, Query, Response, status
from sqlalchemy import select

from backend.api.access import OrganisationManager, PlatformAdmin, SignedIn
from backend.api.deps import SessionDep
from backend.api.schemas_organisations import (
    AuditEntryOut,
    MemberOut,
    MemberSet,
    OrganisationCreate,
    OrganisationOut,
)
from backend.db.access import organisation_ids, role_in_organisation
from backend.db.models import Membership, Organisation, Role
from backend.ids import RowId
from backend.services.audit import entries
from backend.services.organisations import (
    MemberRejected,
    create_organisation,
    members,
    remove_member,
    set_member,
)

router = APIRouter(prefix="/organisations", tags=["organisations"])


def _rejected(exc: MemberRejected) -> HTTPException:
    return HTTPException(exc.status, str(exc))


def _member_out(membership: Membership) -> MemberOut:
    user = membership.user
    return MemberOut(
        username=user.username,
        display_name=user.display_name,
        role=membership.role,
        created_at=membership.created_at,
    )


@router.get("", response_model=list[OrganisationOut], summary="Organisations of this token")
def list_organisations(session: SessionDep, token: SignedIn) -> list[OrganisationOut]:
    query = select(Organisation).order_by(Organisation.id)
    held = organisation_ids(session, token)
    if held is not None:
        query = query.where(Organisation.id.in_(held))
    return [
        OrganisationOut.model_validate(o).model_copy(
            update={"role": role_in_organisation(session, token, o.id)}
        )
        for o in session.scalars(query)
    ]


@router.post(
    "",
    response_model=OrganisationOut,
    status_code=status.HTTP_201_CREATED,
    summary="Make an organisation (the platform administrator)",
)
def make_organisation(
    body: OrganisationCreate, session: SessionDep, token: PlatformAdmin
) -> Organisation:
    try:
        organisation = create_organisation(session, token, body.name)
    except MemberRejected as exc:
        raise _rejected(exc) from None
    session.commit()
    return organisation


@router.get("/{organisation_id}/members", response_model=list[MemberOut])
def list_members(organisation: OrganisationManager, session: SessionDep) -> list[MemberOut]:
    return [_member_out(m) for m in members(session, organisation)]


@router.put(
    "/{organisation_id}/members/{username}",
    response_model=MemberOut,
    summary="Give a user a role in the organisation (managers up to manager; admins any)",
)
def put_member(
    username: str,
    body: MemberSet,
    organisation: OrganisationManager,
    session: SessionDep,
    token: SignedIn,
) -> MemberOut:
    acting = role_in_organisation(session, token, organisation.id) or Role.viewer
    try:
        membership = set_member(session, token, acting, organisation, username, body.role)
    except MemberRejected as exc:
        raise _rejected(exc) from None
    session.commit()
    return _member_out(membership)


@router.delete("/{organisation_id}/members/{username}", status_code=status.HTTP_204_NO_CONTENT)
def delete_member(
    username: str, organisation: OrganisationManager, session: SessionDep, token: SignedIn
) -> Response:
    acting = role_in_organisation(session, token, organisation.id) or Role.viewer
    try:
        remove_member(session, token, acting, organisation, username)
    except MemberRejected as exc:
        raise _rejected(exc) from None
    session.commit()
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.get(
    "/{organisation_id}/audit",
    response_model=list[AuditEntryOut],
    summary="Who changed what in the organisation, newest first",
)
def audit_log(
    organisation: OrganisationManager,
    session: SessionDep,
    limit: int = Query(100, ge=1, le=1000),
    before: RowId | None = Query(None, description="Entries older than this id (paging)."),
) -> list:
    return entries(session, organisation.id, limit, before)
