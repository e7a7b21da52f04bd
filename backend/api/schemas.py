"""Request and response bodies of the REST API."""

from datetime import datetime
from typing import Any
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from pydantic import BaseModel, ConfigDict, Field, field_validator

from backend.db.models import JobState, StageState, SurveyKind, SurveyStatus
from backend.geojson_input import check_area_of_interest
from backend.ids import RowId
from worker.pipeline.detection_methods import detection_methods
from worker.reports.i18n import DEFAULT_LANGUAGE, UnknownLanguage, check_language


class ORMModel(BaseModel):
    model_config = ConfigDict(from_attributes=True)


def check_area(value: dict[str, Any] | None) -> dict[str, Any] | None:
    return None if value is None else check_area_of_interest(value)


def check_timezone(name: str | None) -> str | None:
    if name is None:
        return name
    try:
        ZoneInfo(name)
    except (ZoneInfoNotFoundError, ValueError):
        raise ValueError(
            f"unknown time zone {name!r}: use an IANA name such as Europe/Rome or Asia/Kathmandu"
        ) from None
    return name


def check_language_code(code: str | None) -> str | None:
    if code is None:
        return code
    try:
        return check_language(code)
    except UnknownLanguage as exc:
        raise ValueError(str(exc)) from None


def check_language_given(code: str | None) -> str:
    # Only a value sent is checked: a site keeps a language, null is no change to make.
    if code is None:
        raise ValueError("a site's language cannot be null: leave it out to keep it")
    return check_language_code(code) or code


LANGUAGE_HELP = (
    "The language of the site's scheduled reports and alert e-mails: a code of GET "
    "/api/v1/languages."
)


class SiteCreate(BaseModel):
    name: str = Field(min_length=1, max_length=200)
    organisation_id: RowId | None = Field(
        default=None,
        description="The organisation it belongs to (the token must be a manager there); "
        "default: the only one the token manages.",
    )
    description: str = Field(default="", max_length=10_000)
    area_of_interest: dict[str, Any] | None = Field(
        default=None, description="GeoJSON Polygon or MultiPolygon in WGS84 lon/lat."
    )
    timezone: str = Field(
        default="UTC", max_length=64, description="IANA time zone the map shows times in."
    )
    language: str = Field(default=DEFAULT_LANGUAGE, max_length=16, description=LANGUAGE_HELP)

    _timezone = field_validator("timezone")(check_timezone)
    _language = field_validator("language")(check_language_code)
    _area = field_validator("area_of_interest")(check_area)


class SiteUpdate(BaseModel):
    name: str | None = Field(default=None, min_length=1, max_length=200)
    description: str | None = Field(default=None, max_length=10_000)
    area_of_interest: dict[str, Any] | None = None
    timezone: str | None = Field(default=None, max_length=64)
    language: str | None = Field(default=None, max_length=16, description=LANGUAGE_HELP)

    _timezone = field_validator("timezone")(check_timezone)
    _language = field_validator("language")(check_language_given)
    _area = field_validator("area_of_interest")(check_area)


class SiteOut(ORMModel):
    id: int
    organisation_id: int
    name: str
    description: str
    area_of_interest: dict[str, Any] | None
    timezone: str
    language: str
    created_at: datetime


class LanguageOut(BaseModel):
    code: str = Field(description='What `language` of a site or a report takes: "ja".')
    name: str = Field(description='The language\'s name in itself: "日本語".')
    default: bool = Field(description="What a site made without a language gets.")


class StoredFileOut(ORMModel):
    size_bytes: int
    sha256: str
    media_type: str
    original_name: str | None


class ProductOut(ORMModel):
    id: int
    kind: str
    survey_id: int | None
    comparison_id: int | None
    crs: str | None
    file: StoredFileOut
    download_url: str
    created_at: datetime


class QualityTextOut(BaseModel):
    key: str = Field(description="e.g. `accuracy.horizontal`, `overlap.short`.")
    figures: dict[str, str] = Field(description="The message's figures, as it writes them.")


class QualityCheckOut(BaseModel):
    """One check of a survey's quality verdict (worker/pipeline/quality.py)."""

    name: str = Field(
        description="`georeference_accuracy`, `georeference_residual`, `overlap_coverage`, "
        "`segments_dropped`, `photo_outliers`, `georeference_shape`, `height_agreement` or "
        "`time_offset`."
    )
    value: float | None = Field(description="The survey's figure (metres, share or count).")
    bound: float | None = Field(description="The bound it is held to; None for a count.")
    passed: bool
    message: str = Field(description="The figure and its bound, in plain words.")
    text: QualityTextOut | None = Field(
        default=None,
        description="The message as a key of the page's catalogues (`qualityText.<key>`) "
        "and its figures, for a page in another language than the server's English; "
        "none on checks made before it was recorded.",
    )


class QualityOut(BaseModel):
    """Whether a reconstructed survey met the bounds its DSM is trusted by."""

    passed: bool = Field(description="False when any check failed.")
    checks: list[QualityCheckOut] = Field(
        description="The checks that apply to the survey (a photo set's outliers, a "
        "stated accuracy's fit ...), each failed one also among the survey's `warnings`."
    )


class SurveyOut(ORMModel):
    id: int
    site_id: int
    name: str
    captured_at: datetime
    kind: SurveyKind
    status: SurveyStatus
    crs: str | None
    footprint: dict[str, Any] | None
    resolution_m: float | None
    source_file: StoredFileOut | None
    error: str | None = None
    warnings: list[str] = Field(
        default_factory=list,
        description="What reading its files and reconstructing it had to skip or assume, "
        "each once: the files' warnings (a flight log's skipped blocks with their lines, "
        "the recording of a joined SRT that is used), then the reconstruction report's, "
        "each quality check the survey failed among them.",
    )
    quality: QualityOut | None = Field(
        default=None,
        description="The reconstruction's quality verdict, from its latest report; None "
        "before a report exists (and for an uploaded DSM).",
    )
    created_at: datetime


class SurveyUpdate(BaseModel):
    name: str | None = Field(default=None, min_length=1, max_length=200)


class SourceSurveyCreate(BaseModel):
    kind: SurveyKind = Field(description="`video` (a video with its flight log) or `images`.")
    name: str = Field(min_length=1, max_length=200)
    captured_at: datetime
    options: dict[str, Any] | None = Field(
        default=None,
        description='Reconstruction options, e.g. {"method": "sfm"}, '
        '{"camera": {"model": "FC6310"}}, a rolling-shutter video camera\'s readout '
        '{"camera": {"readout_ms": 30}}, {"time_offset_s": 1.5}, or an RTK drone\'s '
        "position accuracy to check the georeference against: "
        '{"georef": {"georef": {"position_sigma_m": [0.02, 0.02, 0.04]}}}.',
    )


class SurveyFileOut(ORMModel):
    id: int
    survey_id: int
    role: str
    name: str
    file: StoredFileOut
    warnings: list[str] = Field(
        default_factory=list,
        description="What reading the file had to skip or assume, e.g. a flight log's "
        "unreadable blocks with their line numbers.",
    )
    created_at: datetime


# The methods' one-line summaries come from the library, so the API's documentation
# says what GET /methods and the page say.
_METHODS_DOC = " ".join(f"`{m.name}`: {m.summary}" for m in detection_methods())


class ComparisonCreate(BaseModel):
    pre_survey_id: RowId
    post_survey_id: RowId
    method: str | None = Field(
        default=None,
        max_length=64,
        description=f"Detection method. {_METHODS_DOC} Without one, the default of "
        "`GET /methods`. A cnn comparison runs the default detection model unless its "
        'parameters name one: {"cnn": {"model": "name@version"}} (see GET /models); a '
        "scored comparison runs the shipped scorer.",
    )
    parameters: dict[str, Any] = Field(
        default_factory=dict, description="Options of the comparison stages (see docs)."
    )
    name: str = Field(default="", max_length=200, description="A name to tell it apart.")
    run_again: bool = Field(
        default=False,
        description="Make a new comparison even when one of the same surveys, method and "
        "parameters exists (not failed). Without it, that one is answered (200, "
        "`existing` true) and nothing is queued.",
    )


class ComparisonUpdate(BaseModel):
    name: str = Field(max_length=200, description="Empty: named by its surveys again.")


class MethodOut(BaseModel):
    name: str
    summary: str = Field(description="What the method does, in one line.")
    stages: list[str] = Field(description="Its job's stages, in order.")
    default: bool = Field(description="Whether a comparison without a method runs this one.")


class DetectionOut(BaseModel):
    """How a comparison detects: its method, the level of detection it applied and the
    model version behind its detections."""

    method: str
    lod_m: float | None = Field(
        default=None,
        description="Median per-pixel LoD95 applied, in metres (None until the difference "
        "stage has run).",
    )
    lod_p10_m: float | None = Field(default=None, description="10th percentile of the LoD95.")
    lod_p90_m: float | None = Field(default=None, description="90th percentile of the LoD95.")
    error_model: str | None = Field(
        default=None, description="`heteroscedastic`, `uniform` or `fixed` (a given lod_m)."
    )
    model: str | None = Field(
        default=None,
        description='"name@version": the scorer (scored, once its score stage has run) or '
        "the detection model (cnn); None for threshold.",
    )


class ComparisonOut(ORMModel):
    id: int
    site_id: int
    name: str
    pre_survey_id: int
    post_survey_id: int
    method: str
    parameters: dict[str, Any]
    status: JobState
    summary: dict[str, Any] | None
    error: str | None
    created_at: datetime
    finished_at: datetime | None
    job_id: int | None = None
    detection: DetectionOut | None = None
    warnings: list[str] = Field(
        default_factory=list,
        description="What to bear in mind reading its results: each quality check its "
        "pre- or post-event survey failed (see the survey's `quality`), naming the survey.",
    )


class StageRunOut(ORMModel):
    stage: str
    help: str = Field(default="", description="What the stage does, in one line.")
    state: StageState
    progress: float
    attempts: int
    started_at: datetime | None
    finished_at: datetime | None
    error: str | None
    result: dict[str, Any] | None
    log: list[str] = Field(
        default_factory=list,
        description="What happened while it ran, over all its attempts: one line each, "
        "'HH:MM:SS LEVEL message' (UTC); the last 200 lines.",
    )


class JobOut(ORMModel):
    id: int
    site_id: int
    kind: str
    comparison_id: int | None
    survey_id: int | None
    state: JobState
    progress: float
    error: str | None
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    stages: list[StageRunOut]


class ComparisonCreated(BaseModel):
    comparison: ComparisonOut
    job: JobOut | None
    existing: bool = Field(
        default=False,
        description="True when the comparison was made before (same surveys, method and "
        "parameters) and is answered instead of a new one; `job` is its latest job.",
    )


class TokenCreated(BaseModel):
    name: str
    token: str
