"""Sign in to the map with a user name and password; sign out; who am I."""

from fastapi import APIRouter, HTTPException, Response, status

from backend.api.deps import CurrentToken, SessionDep, SettingsDep
from backend.api.schemas_map import SignInOut, SignInRequest, UserOut, WhoAmI
from backend.services.users import SignInFailed, sign_in, sign_out

router = APIRouter(prefix="/auth", tags=["sign-in"])


@router.post(
    "/sign-in",
    response_model=SignInOut,
    summary="Sign in with a user name and password: a token that expires",
    description="The only endpoint that needs no token. Users are made with "
    "`slidewatch create-user`. API tokens of `slidewatch create-token` need no sign-in.",
)
def sign_in_route(body: SignInRequest, session: SessionDep, settings: SettingsDep) -> SignInOut:
    try:
        signed_in = sign_in(session, body.username, body.password, settings.session_hours)
    except SignInFailed:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "wrong user name or password") from None
    session.commit()
    return SignInOut(
        token=signed_in.token,
        expires_at=signed_in.expires_at,
        user=UserOut.model_validate(signed_in.user),
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
