"""The patch cells a CNN comparison found positive, for the map (GeoJSON, WGS84 lon/lat)."""

import json

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from backend.api.access import SiteViewer
from backend.api.deps import SessionDep, StorageDep
from backend.api.routes.comparisons import comparison_of_site
from backend.ids import RowId
from backend.storage_layout import comparison_file

router = APIRouter(prefix="/sites/{site_id}/comparisons", tags=["comparisons"])

# Written by the cnn method's detect stage (worker/pipeline/comparison.py, CELLS).
CELLS_FILE = "cells.geojson"


@router.get(
    "/{comparison_id}/cells",
    summary="Positive patch cells of a cnn comparison (empty for the threshold method)",
    response_class=JSONResponse,
    responses={200: {"content": {"application/geo+json": {}}}},
)
def get_cells(
    comparison_id: RowId, site: SiteViewer, session: SessionDep, storage: StorageDep
) -> JSONResponse:
    comparison = comparison_of_site(session, site, comparison_id)
    path = storage.absolute(comparison_file(comparison.id, CELLS_FILE))
    collection = (
        json.loads(path.read_text())
        if path.is_file()
        else {"type": "FeatureCollection", "features": []}
    )
    return JSONResponse(collection, media_type="application/geo+json")
