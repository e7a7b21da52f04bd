"""The API documentation at /docs: Swagger UI served by the app itself, never from a CDN.

Swagger UI's files come from the `swagger-ui-py` package (pinned in requirements.lock), so
/docs works on a network with no internet, as in the field. The page loads only this
origin's scripts (its start-up is api-docs.js, not an inline script), so it lives under
the map's Content-Security-Policy. FastAPI's own /docs and /redoc load their files from a
CDN and are switched off; /redoc answers with a redirect here, for old bookmarks.
"""

from pathlib import Path

import swagger_ui
from fastapi import APIRouter, FastAPI
from fastapi.responses import FileResponse, HTMLResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles

SWAGGER_UI = Path(swagger_ui.__file__).parent / "static"
START = Path(__file__).resolve().parents[1] / "static" / "api-docs.js"

router = APIRouter(include_in_schema=False)

PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>slidewatch API</title>
<link rel="stylesheet" href="/docs/assets/swagger-ui.css">
<link rel="icon" type="image/png" href="/docs/assets/favicon-32x32.png">
</head><body>
<div id="swagger-ui"></div>
<script src="/docs/assets/swagger-ui-bundle.js"></script>
<script src="/docs/assets/swagger-ui-standalone-preset.js"></script>
<script src="/docs/api-docs.js"></script>
</body></html>"""


@router.get("/docs")
def docs_page() -> HTMLResponse:
    return HTMLResponse(PAGE, headers={"Cache-Control": "no-cache"})


@router.get("/docs/api-docs.js")
def docs_start() -> FileResponse:
    return FileResponse(START, media_type="text/javascript")


@router.get("/redoc")
def redoc() -> RedirectResponse:
    return RedirectResponse("/docs", status_code=308)


def mount_docs(app: FastAPI) -> None:
    app.include_router(router)
    app.mount("/docs/assets", StaticFiles(directory=SWAGGER_UI), name="docs-assets")
