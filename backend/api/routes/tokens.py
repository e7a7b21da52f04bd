"""API tokens of the caller's holder: list, make with an expiry, revoke."""

from fastapi import APIRouter, HTTPException, Query, Response, status

from backend.api.access import SignedIn
from backend.api.deps import SessionDep, SettingsDep
from backend.api.schemas_tokens import TokenCreate, TokenIssued, TokenOut
from backend.ids import RowId
from backend.services.audit import record
from backend.services.tokens import TokenRejected, issue_token, list_tokens, revoke_token

router = APIRouter(prefix="/auth/tokens", tags=["sign-in"])


def _out(token, caller) -> TokenOut:
    return TokenOut.model_validate(token).model_copy(update={"current": token.id == caller.id})


@router.get(
    "",
    response_model=list[TokenOut],
    summary="Tokens of whoever calls: a user's own, or the platform's",
)
def get_tokens(
    caller: SignedIn,
    session: SessionDep,
    include_ended: bool = Query(False, description="Also those revoked or expired."),
) -> list[TokenOut]:
    return [_out(t, caller) for t in list_tokens(session, caller, include_ended)]


@router.post(
    "",
    response_model=TokenIssued,
    status_code=status.HTTP_201_CREATED,
    summary="A new API token that expires; its secret is in this answer only",
)
def create_api_token(
    body: TokenCreate, caller: SignedIn, session: SessionDep, settings: SettingsDep
) -> TokenIssued:
    days = body.days or settings.token_days
    try:
        token, secret = issue_token(
            session, caller, body.name, days, settings.token_max_days,
            role=body.role, site_id=body.site_id, organisation_id=body.organisation_id,
        )  # fmt: skip
    except TokenRejected as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None
    except LookupError as exc:
        raise HTTPException(status.HTTP_404_NOT_FOUND, str(exc)) from None
    record(
        session, caller, "token.create", organisation_id=token.organisation_id,
        target=f"token {token.id} ({token.name})",
        details={"role": token.role, "site_id": token.site_id, "days": days},
    )  # fmt: skip
    session.commit()
    return TokenIssued(**_out(token, caller).model_dump(), token=secret)


@router.delete(
    "/{token_id}", status_code=status.HTTP_204_NO_CONTENT, summary="Revoke a token at once"
)
def delete_api_token(token_id: RowId, caller: SignedIn, session: SessionDep) -> Response:
    try:
        token = revoke_token(session, caller, token_id)
    except LookupError as exc:
        raise HTTPException(status.HTTP_404_NOT_FOUND, str(exc)) from None
    record(session, caller, "token.revoke", organisation_id=token.organisation_id,
           target=f"token {token.id} ({token.name})")  # fmt: skip
    session.commit()
    return Response(status_code=status.HTTP_204_NO_CONTENT)
