from fastapi import APIRouter, HTTPException, Response, status
from sqlalchemy import select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from backend.api.access import SignedIn, SiteAnalyst, SiteManager, SiteViewer
from backend.api.deps import SessionDep, SettingsDep, StorageDep
from backend.api.routes.uploads import upload_out
from backend.api.schemas import SiteCreate, SiteOut, SiteUpdate
from backend.api.schemas_map import UploadOut
from backend.db.access import organisation_ids, role_in_organisation, visible_site_ids
from backend.db.models import (
    ApiToken,
    Organisation,
    Role,
    Site,
    Upload,
    UploadState,
    default_organisation,
)
from backend.services.audit import record
from backend.services.deletion import delete_site
from backend.services.uploads import remove_expired

router = APIRouter(prefix="/sites", tags=["sites"])


@router.get("", response_model=list[SiteOut], summary="The sites this token may see")
def list_sites(session: SessionDep, token: SignedIn) -> list[Site]:
    query = select(Site).order_by(Site.id)
    visible = visible_site_ids(session, token)
    if visible is not None:
        query = query.where(Site.id.in_(visible))
    return list(session.scalars(query))


def _organisation_for(session: Session, token: ApiToken, asked: int | None) -> Organisation:
    """Where a new site goes: the organisation asked for, where the token is a manager; or,
    unasked, the only one it manages (the platform administrator's: the default one)."""
    if asked is not None:
        organisation = session.get(Organisation, asked)
        role = role_in_organisation(session, token, asked) if organisation else None
        if organisation is None or role is None or token.site_id is not None:
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"organisation {asked} not found")
        if role.rank < Role.manager.rank:
            raise HTTPException(
                status.HTTP_403_FORBIDDEN,
                f"making a site needs the role manager in organisation {asked}",
            )
        return organisation
    candidates = organisation_ids(session, token)
    if candidates is None:
        return default_organisation(session)
    managed = sorted(
        o
        for o in candidates
        if token.site_id is None
        and (role := role_in_organisation(session, token, o)) is not None
        and role.rank >= Role.manager.rank
    )
    if not managed:
        raise HTTPException(
            status.HTTP_403_FORBIDDEN, "making a site needs the role manager in an organisation"
        )
    if len(managed) > 1:
        raise HTTPException(
            status.HTTP_422_UNPROCESSABLE_CONTENT,
            f"say which organisation the site belongs to (organisation_id): one of {managed}",
        )
    return session.get(Organisation, managed[0])  # type: ignore[return-value]


@router.post(
    "",
    response_model=SiteOut,
    status_code=status.HTTP_201_CREATED,
    summary="Make a site in an organisation where this token is a manager",
)
def create_site(body: SiteCreate, session: SessionDep, token: SignedIn) -> Site:
    organisation = _organisation_for(session, token, body.organisation_id)
    site = Site(**body.model_dump(exclude={"organisation_id"}), organisation=organisation)
    session.add(site)
    try:
        session.flush()
    except IntegrityError:
        session.rollback()
        raise HTTPException(
            status.HTTP_409_CONFLICT, f"a site named {body.name!r} exists"
        ) from None
    record(session, token, "site.create", site=site, target=f"site {site.id} ({site.name})")
    session.commit()
    return site


@router.get("/{site_id}", response_model=SiteOut)
def get_site(site: SiteViewer) -> Site:
    return site


@router.patch("/{site_id}", response_model=SiteOut)
def update_site(body: SiteUpdate, site: SiteManager, session: SessionDep, token: SignedIn) -> Site:
    changes = body.model_dump(exclude_unset=True)
    for field, value in changes.items():
        setattr(site, field, value)
    try:
        session.flush()
    except IntegrityError:
        session.rollback()
        raise HTTPException(
            status.HTTP_409_CONFLICT, f"a site named {body.name!r} exists"
        ) from None
    record(
        session, token, "site.update", site=site, target=f"site {site.id}",
        details={"fields": sorted(changes)},
    )  # fmt: skip
    session.commit()
    return site


@router.delete("/{site_id}", status_code=status.HTTP_204_NO_CONTENT)
def remove_site(
    site: SiteManager,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    token: SignedIn,
) -> Response:
    """Delete the site with its surveys, comparisons, detections, jobs and files."""
    record(session, token, "site.delete", site=site, target=f"site {site.id} ({site.name})")
    delete_site(session, storage, site, tile_cache_dir=settings.tile_cache_dir)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.get(
    "/{site_id}/uploads",
    response_model=list[UploadOut],
    summary="The site's unfinished resumable uploads",
    description="Uploads still receiving bytes, oldest first, with the offset reached: the "
    "page lists them on return to resume (choose the same file again) or cancel (DELETE "
    "/uploads/{id}). They are removed after SLIDEWATCH_UPLOAD_EXPIRY_HOURS.",
)
def list_unfinished_uploads(
    site: SiteAnalyst, session: SessionDep, storage: StorageDep
) -> list[UploadOut]:
    remove_expired(session, storage)
    query = (
        select(Upload)
        .where(Upload.site_id == site.id, Upload.state == UploadState.receiving)
        .order_by(Upload.created_at, Upload.id)
    )
    return [upload_out(session, storage, u) for u in session.scalars(query)]
