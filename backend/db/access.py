"""Who may do what where: the role a token holds on a site or in an organisation.

    a platform administrator's token  (no user, no organisation)   admin everywhere
    a service's token                 (no user, an organisation)   its `role` there
    a user's token                    (a session or the user's own API token)
                                      the user's role in the site's organisation,
                                      held to the token's `role` when it has one

A token with a `site_id` reaches that site only. None means no role at all: the site is
not to be seen (the API answers 404, as if it did not exist).
"""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.db.models import ApiToken, Membership, Role, Site


def is_platform_admin(token: ApiToken) -> bool:
    return token.user_id is None and token.organisation_id is None and token.site_id is None


def role_in_organisation(session: Session, token: ApiToken, organisation_id: int) -> Role | None:
    if token.user_id is None:
        if token.organisation_id is None:
            return Role.admin
        return (token.role or Role.viewer) if token.organisation_id == organisation_id else None
    held = session.scalar(
        select(Membership.role).where(
            Membership.organisation_id == organisation_id, Membership.user_id == token.user_id
        )
    )
    if held is None:
        return None
    return min(held, token.role, key=lambda r: r.rank) if token.role else held


def role_on_site(session: Session, token: ApiToken, site: Site) -> Role | None:
    if token.site_id is not None and token.site_id != site.id:
        return None
    return role_in_organisation(session, token, site.organisation_id)


def visible_site_ids(session: Session, token: ApiToken) -> set[int] | None:
    """The ids of the sites the token may see; None for all of them."""
    if is_platform_admin(token):
        return None
    if token.site_id is not None:
        site = session.get(Site, token.site_id)
        return {site.id} if site and role_on_site(session, token, site) else set()
    if token.user_id is None:
        organisations = [token.organisation_id]
    else:
        organisations = list(
            session.scalars(
                select(Membership.organisation_id).where(Membership.user_id == token.user_id)
            )
        )
    return set(session.scalars(select(Site.id).where(Site.organisation_id.in_(organisations))))


def organisation_ids(session: Session, token: ApiToken) -> set[int] | None:
    """The organisations the token has a role in; None for all."""
    if is_platform_admin(token):
        return None
    if token.user_id is None:
        return {token.organisation_id} if token.organisation_id else set()
    return set(
        session.scalars(
            select(Membership.organisation_id).where(Membership.user_id == token.user_id)
        )
    )
