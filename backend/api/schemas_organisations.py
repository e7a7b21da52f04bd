"""Request and response bodies of organisations, members and the audit log."""

from datetime import datetime
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from backend.db.models import Role


class OrganisationCreate(BaseModel):
    name: str = Field(min_length=1, max_length=200)


class OrganisationOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    name: str
    is_default: bool
    role: Role | None = Field(default=None, description="This token's role in it.")


class MemberSet(BaseModel):
    role: Role = Field(description="viewer, analyst, manager or admin.")


class MemberOut(BaseModel):
    username: str
    display_name: str
    role: Role
    created_at: datetime


class AuditEntryOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    at: datetime
    actor: str
    site_id: int | None
    action: str
    target: str
    details: dict[str, Any]
