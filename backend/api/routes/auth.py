"""Sign in to the map with a user name and password; sign out; who am I."""

from fastapi import APIRouter, HTTPException, Request, Response, status

from backend.api.deps import CurrentToken, SessionDep, SettingsDep
from backend.api.schemas_map import SignInOut, SignInRequest, UserOut, WhoAmI
from backend.services.sign_in_throttle import clear_account, lockout, record_failure, utcnow
from backend.services.users import SignInFailed, sign_in, sign_out

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
    address = request.client.host if request.client else "unknown"
    now = utcnow()
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


@router.post("/sign-out", status_code=status.HTTP_204_NO_CONTENT)
def sign_out_route(token: CurrentToken, session: SessionDep) -> Response:
    """End this session (a user's token stops working; an API token is left alone)."""
    sign_out(session, token)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.get("/me", response_model=WhoAmI)
def who_am_i(token: CurrentToken) -> WhoAmI:
    if token.user is not None:
        return WhoAmI(
            kind="user",
            name=token.user.username,
            user=UserOut.model_validate(token.user),
            expires_at=token.expires_at,
        )
    return WhoAmI(kind="token", name=token.name, user=None, expires_at=None)
