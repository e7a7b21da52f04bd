from fastapi import APIRouter, HTTPException, Response, status
from sqlalchemy import select
from sqlalchemy.exc import IntegrityError

from backend.api.deps import CurrentToken, SessionDep, SiteDep, StorageDep
from backend.api.schemas import SiteCreate, SiteOut, SiteUpdate
from backend.db.models import Site
from backend.services.deletion import delete_site

router = APIRouter(prefix="/sites", tags=["sites"])


@router.get("", response_model=list[SiteOut])
def list_sites(session: SessionDep, _token: CurrentToken) -> list[Site]:
    return list(session.scalars(select(Site).order_by(Site.id)))


@router.post("", response_model=SiteOut, status_code=status.HTTP_201_CREATED)
def create_site(body: SiteCreate, session: SessionDep, _token: CurrentToken) -> Site:
    site = Site(**body.model_dump())
    session.add(site)
    try:
        session.commit()
    except IntegrityError:
        session.rollback()
        raise HTTPException(
            status.HTTP_409_CONFLICT, f"a site named {body.name!r} exists"
        ) from None
    return site


@router.get("/{site_id}", response_model=SiteOut)
def get_site(site: SiteDep) -> Site:
    return site


@router.patch("/{site_id}", response_model=SiteOut)
def update_site(body: SiteUpdate, site: SiteDep, session: SessionDep) -> Site:
    for field, value in body.model_dump(exclude_unset=True).items():
        setattr(site, field, value)
    try:
        session.commit()
    except IntegrityError:
        session.rollback()
        raise HTTPException(
            status.HTTP_409_CONFLICT, f"a site named {body.name!r} exists"
        ) from None
    return site


@router.delete("/{site_id}", status_code=status.HTTP_204_NO_CONTENT)
def remove_site(site: SiteDep, session: SessionDep, storage: StorageDep) -> Response:
    """Delete the site with its surveys, comparisons, detections, jobs and files."""
    delete_site(session, storage, site)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
