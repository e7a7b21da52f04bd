"""Typed dependencies shared by the routes: settings, database session, storage, auth."""

from collections.abc import Iterator
from typing import Annotated, TypeVar

from celery import Celery
from fastapi import Depends, HTTPException, Request, status
from fastapi.security import APIKeyQuery, HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from backend.config import Settings
from backend.db.models import ApiToken, Site
from backend.db.tokens import authenticate
from backend.ids import RowId
from backend.storage import LocalStorage

Owned = TypeVar("Owned")


# The dependencies that only read the app's state are coroutines: FastAPI runs a plain
# function in its thread pool, a hop that costs more than the read (a map tile asks for
# several of them).
async def get_settings_dep(request: Request) -> Settings:
    return request.app.state.settings


def public_base(request: Request) -> str:
    """Where users reach the API (SLIDEWATCH_PUBLIC_URL), for the absolute links of an
    answer: never the request's Host header, which whoever sends the request chooses."""
    return request.app.state.settings.resolved_public_url


def get_session(request: Request) -> Iterator[Session]:
    session: Session = request.app.state.sessionmaker()
    try:
        yield session
        session.commit()
    except BaseException:
        session.rollback()
        raise
    finally:
        session.close()


async def get_storage(request: Request) -> LocalStorage:
    return request.app.state.storage


async def get_celery(request: Request) -> Celery:
    return request.app.state.celery


SettingsDep = Annotated[Settings, Depends(get_settings_dep)]
SessionDep = Annotated[Session, Depends(get_session)]
StorageDep = Annotated[LocalStorage, Depends(get_storage)]
CeleryDep = Annotated[Celery, Depends(get_celery)]

_bearer = HTTPBearer(auto_error=False, description="An API token from `slidewatch create-token`.")
_api_key = APIKeyQuery(
    name="api_key",
    auto_error=False,
    description="The API token as a query parameter, for GIS clients that cannot send a "
    "header (QGIS XYZ and WMTS layers, GDAL /vsicurl/). Query strings end up in access "
    "logs and proxies: prefer the Authorization header where the client can send it.",
)


def token_secret(credentials: HTTPAuthorizationCredentials | None, api_key: str | None) -> str:
    """The secret from `Authorization: Bearer <token>`, else from `?api_key=<token>`."""
    secret = credentials.credentials if credentials is not None else api_key
    if not secret:
        raise HTTPException(
            status.HTTP_401_UNAUTHORIZED,
            "missing API token: send 'Authorization: Bearer <token>'",
            headers={"WWW-Authenticate": "Bearer"},
        )
    return secret


def token_for(session: Session, secret: str) -> ApiToken:
    """The valid token of `secret`, its last use committed; 401 otherwise."""
    token = authenticate(session, secret)
    if token is None:
        raise HTTPException(
            status.HTTP_401_UNAUTHORIZED,
            "invalid or revoked API token",
            headers={"WWW-Authenticate": "Bearer"},
        )
    # Commit the token's last use now: on SQLite a pending write holds the database's write
    # lock until commit, and a long request (an upload's body, an event stream) would
    # otherwise block every other writer, workers included, for as long as it lasts.
    session.commit()
    return token


BearerCredentials = Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]
ApiKey = Annotated[str | None, Depends(_api_key)]


def require_token(
    session: SessionDep, credentials: BearerCredentials, api_key: ApiKey = None
) -> ApiToken:
    """The token from `Authorization: Bearer <token>`, else from `?api_key=<token>`."""
    return token_for(session, token_secret(credentials, api_key))


CurrentToken = Annotated[ApiToken, Depends(require_token)]


def owned_by_site(
    session: Session, model: type[Owned], site: Site, item_id: RowId, noun: str
) -> Owned:
    """The `model` row `item_id` if it belongs to `site`; 404 otherwise, whoever owns it."""
    item = session.get(model, item_id)
    if item is None or item.site_id != site.id:  # type: ignore[attr-defined]
        raise HTTPException(
            status.HTTP_404_NOT_FOUND, f"{noun} {item_id} not found in site {site.id}"
        )
    return item
