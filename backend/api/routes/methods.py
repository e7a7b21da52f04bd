"""The detection methods a comparison can use, as the library defines them."""

from fastapi import APIRouter

from backend.api.access import SignedIn
from backend.api.schemas import MethodOut
from backend.services.comparisons import list_methods

router = APIRouter(prefix="/methods", tags=["comparisons"])


@router.get(
    "",
    response_model=list[MethodOut],
    summary="Detection methods: what each does, its stages, and which is the default",
)
def get_methods(_token: SignedIn) -> list[MethodOut]:
    """Exactly one is the default: what a comparison created without a method runs."""
    return [MethodOut(**method) for method in list_methods()]
