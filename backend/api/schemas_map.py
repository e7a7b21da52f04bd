"""Request and response bodies of the map's own endpoints: sign-in, uploads, feedback."""

from datetime import datetime

from pydantic import BaseModel, ConfigDict, Field

from backend.db.models import UploadState, Verdict


class SignInRequest(BaseModel):
    username: str = Field(min_length=1, max_length=100)
    password: str = Field(min_length=1, max_length=1024)


class UserOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    username: str
    display_name: str


class SignInOut(BaseModel):
    token: str = Field(description="Send as `Authorization: Bearer <token>` until it expires.")
    expires_at: datetime
    user: UserOut
    notice: str | None = Field(
        default=None,
        description="Failed sign-ins to the account since its last sign-in, if any: how "
        "many, since when, the last one's address.",
    )


class WhoAmI(BaseModel):
    kind: str = Field(description="`user` (signed in with a password) or `token` (API token).")
    name: str = Field(description="The user name, or the API token's name.")
    user: UserOut | None
    expires_at: datetime | None


class UploadOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: str
    site_id: int
    purpose: str
    filename: str
    length: int
    offset: int
    state: UploadState
    error: str | None
    survey_id: int | None = Field(
        description="The survey the upload made (a DSM), or the survey its file belongs to."
    )
    role: str | None = Field(
        default=None, description="A survey's file: video, log or image; None for a DSM."
    )
    warnings: list[str] = Field(
        default_factory=list,
        description="A survey's file, once complete: what reading it had to skip or assume "
        "(the file's `warnings`, as GET .../surveys/{id}/files answers them).",
    )
    created_by: str
    created_at: datetime
    completed_at: datetime | None
    expires_at: datetime


class FeedbackIn(BaseModel):
    verdict: Verdict = Field(description="`confirmed` (a real landslide) or `false_alarm`.")
    note: str = Field(default="", max_length=2000)


class FeedbackOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    detection_id: int
    verdict: Verdict
    note: str
    author: str
    created_at: datetime
    updated_at: datetime


class MapConfig(BaseModel):
    """What the map needs before anyone signs in."""

    basemap_url: str | None
    basemap_attribution: str
    upload_chunk_bytes: int
    max_upload_bytes: int
    version: str


class DetectionHistoryOut(BaseModel):
    comparison_id: int
    detection_id: int
    label: int = Field(description="The detection's number in its comparison (1…n).")
    pre_captured_at: datetime
    post_captured_at: datetime
    area_m2: float
    volume_loss_m3: float
    volume_gain_m3: float
    max_abs_dh_m: float
    score: float
    overlap: float = Field(description="Share of the asked detection's area this one covers.")
    this: bool = Field(description="True for the asked detection itself.")
