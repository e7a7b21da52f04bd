"""The languages reports and alert e-mails can be written in: one per message catalogue
of worker/reports/catalogues."""

from fastapi import APIRouter

from backend.api.access import SignedIn
from backend.api.schemas import LanguageOut
from worker.reports.i18n import DEFAULT_LANGUAGE, available_languages, catalogue

router = APIRouter(prefix="/languages", tags=["reports"])


@router.get(
    "",
    response_model=list[LanguageOut],
    summary="Languages of reports and alert e-mails: a site's `language`, a report's",
)
def get_languages(_token: SignedIn) -> list[LanguageOut]:
    """Each by its code and its own name; exactly one is the default."""
    return [
        LanguageOut(code=code, name=catalogue(code).name, default=code == DEFAULT_LANGUAGE)
        for code in available_languages()
    ]
