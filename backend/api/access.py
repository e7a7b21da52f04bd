"""The one dependency every route declares: what it needs, checked against the token.

A route states its permission by the dependency it takes:

    SiteViewer / SiteAnalyst / SiteManager / SiteAdmin   that role on the site in the path
    OrganisationManager / OrganisationAdmin              that role in the organisation
    UploadAnalyst                                        analyst on the upload's site
    SignedIn                                             any valid token (what it lists is
                                                         filtered by what the token sees)
    PlatformAdmin                                        the platform administrator

Each dependency carries its permission (`PERMISSION_ATTRIBUTE`), and a test fails when a
route takes none of them (tests/api/test_permissions.py), so a new route cannot forget
to say who may use it. A site, organisation or upload the token has no role on answers
404, as if it did not exist; a role too small answers 403 naming the role needed.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any

from fastapi import Depends, HTTPException, status
from sqlalchemy.orm import Session

from backend.api.deps import CurrentToken, SessionDep
from backend.db.access import is_platform_admin, role_in_organisation, role_on_site
from backend.db.models import ApiToken, Organisation, Role, Site, Upload
from backend.ids import RowId

PERMISSION_ATTRIBUTE = "__permission__"


def declares(permission: str) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    def mark(dependency: Callable[..., Any]) -> Callable[..., Any]:
        setattr(dependency, PERMISSION_ATTRIBUTE, permission)
        return dependency

    return mark


def _check(role: Role | None, need: Role, what: str) -> None:
    if role is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"{what} not found")
    if role.rank < need.rank:
        raise HTTPException(
            status.HTTP_403_FORBIDDEN,
            f"this needs the role {need.value} on {what}; this token has {role.value}",
        )


def site_for(session: Session, token: ApiToken, site_id: int, need: Role) -> Site:
    """Site `site_id` if the token has at least `need` on it; 404 or 403 otherwise."""
    site = session.get(Site, site_id)
    role = role_on_site(session, token, site) if site is not None else None
    _check(role, need, f"site {site_id}")
    return site  # type: ignore[return-value]


def site_access(need: Role) -> Callable[..., Site]:
    @declares(f"site:{need.value}")
    def dependency(site_id: RowId, session: SessionDep, token: CurrentToken) -> Site:
        return site_for(session, token, site_id, need)

    return dependency


def organisation_access(need: Role) -> Callable[..., Organisation]:
    @declares(f"organisation:{need.value}")
    def dependency(
        organisation_id: RowId, session: SessionDep, token: CurrentToken
    ) -> Organisation:
        organisation = session.get(Organisation, organisation_id)
        role = (
            role_in_organisation(session, token, organisation_id)
            if organisation is not None and token.site_id is None
            else None
        )
        _check(role, need, f"organisation {organisation_id}")
        return organisation  # type: ignore[return-value]

    return dependency


@declares("upload:analyst")
def upload_access(upload_id: str, session: SessionDep, token: CurrentToken) -> Upload:
    upload = session.get(Upload, upload_id) if upload_id.isalnum() else None
    site = session.get(Site, upload.site_id) if upload is not None else None
    role = role_on_site(session, token, site) if site is not None else None
    _check(role, Role.analyst, f"upload {upload_id}")
    return upload  # type: ignore[return-value]


@declares("signed-in")
def signed_in(token: CurrentToken) -> ApiToken:
    return token


@declares("platform-admin")
def platform_admin(token: CurrentToken) -> ApiToken:
    if not is_platform_admin(token):
        raise HTTPException(
            status.HTTP_403_FORBIDDEN,
            "this needs the platform administrator's API token (slidewatch create-token)",
        )
    return token


SiteViewer = Annotated[Site, Depends(site_access(Role.viewer))]
SiteAnalyst = Annotated[Site, Depends(site_access(Role.analyst))]
SiteManager = Annotated[Site, Depends(site_access(Role.manager))]
SiteAdmin = Annotated[Site, Depends(site_access(Role.admin))]
OrganisationManager = Annotated[Organisation, Depends(organisation_access(Role.manager))]
OrganisationAdmin = Annotated[Organisation, Depends(organisation_access(Role.admin))]
UploadAnalyst = Annotated[Upload, Depends(upload_access)]
SignedIn = Annotated[ApiToken, Depends(signed_in)]
PlatformAdmin = Annotated[ApiToken, Depends(platform_admin)]
