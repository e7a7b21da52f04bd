"""Sign in to the map with a user name and password; sign out; who am I."""

from fastapi import APIRouter, HTTPException, Request, Response, status

from backend.api.access import SignedIn
from backend.api.deps import SessionDep, SettingsDep
from backend.api.schemas_map import SignInOut, SignInRequest, UserOut, WhoAmI
from backend.api.schemas_tokens import PasswordChange
from backend.services.sign_in_throttle import clear_account, lockout, record_failure, utcnow
from backend.services.users import (
    SignInFailed,
    UserRejected,
    change_password,
    sign_in,
    sign_out,
)
from backend.urls import api_url

router = APIRouter(prefix="/auth", tags=["sign-in"])


@router.post(
    "/sign-in",
    response_model=SignInOut,
    summary="Sign in with a user name and password: a token that expires",
    description="The only endpoint that needs no token. Users are made with "
    "`slidewatch create-user`. API tokens of `slidewatch create-token` need no sign-in. "
    "Failed sign-ins are throttled per account and per client address: past the limit, "
    "429 with `Retry-After` (seconds) until the window has passed, whatever the password.",
    responses={429: {"description": "Locked out: too many failed sign-ins."}},
)
def sign_in_route(
    body: SignInRequest, request: Request, session: SessionDep, settings: SettingsDep
) -> SignInOut:
    address, now = _address(request), utcnow()
    locked = lockout(session, settings, body.username, address, now)
    if locked is not None:
        session.commit()
        raise HTTPException(
            status.HTTP_429_TOO_MANY_REQUESTS,
            locked.message(body.username),
            headers={"Retry-After": str(locked.retry_after_s)},
        )
    try:
        signed_in = sign_in(session, body.username, body.password, settings.session_hours)
    except SignInFailed:
        record_failure(session, body.username, address, now)
        session.commit()
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "wrong user name or password") from None
    notice = clear_account(session, body.username)
    session.commit()
    return SignInOut(
        token=signed_in.token,
        expires_at=signed_in.expires_at,
        user=UserOut.model_validate(signed_in.user),
        notice=notice,
    )


@router.post(
    "/sign-out",
    status_code=status.HTTP_204_NO_CONTENT,
    responses={409: {"description": "An API token, not a sign-in: revoke it instead."}},
)
def sign_out_route(token: SignedIn, session: SessionDep) -> Response:
    """End this sign-in: its token stops working at once. An API token is not a sign-in:
    it is revoked with DELETE /auth/tokens/{id}, and answered 409 here rather than left
    valid behind a 204."""
    if token.kind != "session":
        raise HTTPException(
            status.HTTP_409_CONFLICT,
            f"this is an API token, not a sign-in: revoke it with DELETE "
            f"{api_url('auth', 'tokens', token.id)}",
        )
    sign_out(session, token)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.post(
    "/password",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Change your password: every session and token of yours ends (sign in again)",
    responses={429: {"description": "Locked out: too many failed sign-ins."}},
)
def change_password_route(
    body: PasswordChange,
    request: Request,
    token: SignedIn,
    session: SessionDep,
    settings: SettingsDep,
) -> Response:
    if token.user is None:
        raise HTTPException(status.HTTP_409_CONFLICT, "an API token has no password to change")
    username, address, now = token.user.username, _address(request), utcnow()
    # A wrong current password counts as a failed sign-in: a stolen session must not
    # become a way to guess the password.
    locked = lockout(session, settings, username, address, now)
    if locked is not None:
        session.commit()
        raise HTTPException(
            status.HTTP_429_TOO_MANY_REQUESTS,
            locked.message(username),
            headers={"Retry-After": str(locked.retry_after_s)},
        )
    try:
        change_password(session, token.user, body.current_password, body.new_password)
    except SignInFailed:
        record_failure(session, username, address, now)
        session.commit()
        raise HTTPException(status.HTTP_403_FORBIDDEN, "the current password is wrong") from None
    except UserRejected as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None
    session.commit()
    return Response(status_code=status.HTTP_204_NO_CONTENT)


def _address(request: Request) -> str:
    return request.client.host if request.client else "unknown"


@router.get("/me", response_model=WhoAmI)
def who_am_i(token: SignedIn) -> WhoAmI:
    if token.user is not None:
        return WhoAmI(
            kind="user",
            name=token.user.username,
            user=UserOut.model_validate(token.user),
            expires_at=token.expires_at,
        )
    return WhoAmI(kind="token", name=token.name, user=None, expires_at=None)
