"""Paths of the REST API, spelled in one place: where the app mounts its routers and what
serializers, STAC, alerts and tile templates link to.

It sits in `backend`, not in `backend.api`, because services build links too and
`backend.api` already imports the services.
"""

API_PREFIX = "/api/v1"


def api_url(*parts: str | int) -> str:
    """The API path of `parts`: api_url("sites", 3, "surveys") is "/api/v1/sites/3/surveys".

    A part may hold several segments ("surveys/4"); nothing is escaped, as every caller
    passes ids and fixed names.
    """
    return "/".join([API_PREFIX, *(str(part) for part in parts)])
