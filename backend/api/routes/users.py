"""Users of the map, as an administrator manages them: list, create, disable, enable."""

from fastapi import APIRouter, HTTPException, status
from sqlalchemy import select

from backend.api.access import PlatformAdmin
from backend.api.deps import SessionDep
from backend.api.schemas_tokens import UserAccountOut, UserCreate
from backend.db.models import User
from backend.ids import RowId
from backend.services.audit import record
from backend.services.users import UserRejected, create_user, disable_user, enable_user

router = APIRouter(prefix="/users", tags=["users"])


def _user(session: SessionDep, user_id: int) -> User:
    user = session.get(User, user_id)
    if user is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"user {user_id} not found")
    return user


@router.get("", response_model=list[UserAccountOut], summary="Every user of the map")
def list_users(_admin: PlatformAdmin, session: SessionDep) -> list[User]:
    return list(session.scalars(select(User).order_by(User.id)))


@router.post(
    "",
    response_model=UserAccountOut,
    status_code=status.HTTP_201_CREATED,
    summary="Create a user (then give them a role in an organisation: its members)",
)
def create(body: UserCreate, admin: PlatformAdmin, session: SessionDep) -> User:
    try:
        user = create_user(session, body.username, body.password, body.display_name)
    except UserRejected as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None
    record(session, admin, "user.create", target=user.username)
    session.commit()
    return user


@router.post(
    "/{user_id}/disable",
    response_model=UserAccountOut,
    summary="Disable a user: no more sign-in, and every session and token of theirs ends",
)
def disable(user_id: RowId, admin: PlatformAdmin, session: SessionDep) -> User:
    user = _user(session, user_id)
    disable_user(session, user)
    record(session, admin, "user.disable", target=user.username)
    session.commit()
    return user


@router.post("/{user_id}/enable", response_model=UserAccountOut, summary="Let a user sign in again")
def enable(user_id: RowId, admin: PlatformAdmin, session: SessionDep) -> User:
    user = _user(session, user_id)
    enable_user(user)
    record(session, admin, "user.enable", target=user.username)
    session.commit()
    return user
