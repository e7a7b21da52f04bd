"""Request and response bodies of API tokens, passwords and users."""

from datetime import datetime

from pydantic import BaseModel, ConfigDict, Field, field_validator

from backend.db.models import Role
from backend.db.tokens import as_utc
from backend.ids import RowId


class TokenOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    name: str
    prefix: str = Field(description="The first characters of the secret, to recognise it.")
    kind: str = Field(description="`session` (a sign-in to the map) or `api` (for a program).")
    created_at: datetime
    last_used_at: datetime | None
    expires_at: datetime | None = Field(description="None: made before tokens expired.")
    revoked_at: datetime | None
    role: Role | None = Field(default=None, description="The role it is held to, if any.")
    site_id: int | None = Field(default=None, description="The one site it reaches, if any.")
    organisation_id: int | None = Field(
        default=None, description="A service's token: its organisation."
    )
    current: bool = Field(default=False, description="Whether this request was made with it.")

    @field_validator("created_at", "last_used_at", "expires_at", "revoked_at")
    @classmethod
    def _utc(cls, moment: datetime | None) -> datetime | None:
        return None if moment is None else as_utc(moment)  # SQLite gives them back naive


class TokenCreate(BaseModel):
    name: str = Field(min_length=1, max_length=200, description="What the token is for.")
    days: float | None = Field(
        default=None,
        gt=0,
        description="How long it is valid; default SLIDEWATCH_TOKEN_DAYS, at most "
        "SLIDEWATCH_TOKEN_MAX_DAYS.",
    )
    role: Role | None = Field(
        default=None, description="Hold it to this role (never more than the caller's)."
    )
    site_id: RowId | None = Field(default=None, description="Hold it to this site.")
    organisation_id: RowId | None = Field(
        default=None,
        description="The platform administrator only: a service's token of this "
        "organisation (with `role`, default viewer).",
    )


class TokenIssued(TokenOut):
    token: str = Field(description="The secret: shown only now. Send it as a Bearer token.")


class PasswordChange(BaseModel):
    current_password: str = Field(min_length=1, max_length=1024)
    new_password: str = Field(min_length=1, max_length=1024)


class UserAccountOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    username: str
    display_name: str
    created_at: datetime
    last_login_at: datetime | None
    disabled_at: datetime | None


class UserCreate(BaseModel):
    username: str = Field(min_length=1, max_length=100)
    password: str = Field(min_length=1, max_length=200, description="At least 8 characters.")
    display_name: str = Field(default="", max_length=200)
