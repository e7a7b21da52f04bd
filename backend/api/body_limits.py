"""How large a request body each route takes: uploads stream to disk under their own limit,
every other route takes at most SLIDEWATCH_MAX_REQUEST_BYTES.

FastAPI reads a JSON body whole into memory before validating it, so without a limit a
30 MB description is read, parsed and stored. The middleware refuses a body over the
route's limit with 413: at once when Content-Length says so, else as soon as the bytes
that arrived pass it (a chunked body declares no length).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

from starlette.exceptions import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

Endpoint = TypeVar("Endpoint", bound=Callable[..., Any])
_STREAMED = "__streamed_upload__"


def streamed_upload(endpoint: Endpoint) -> Endpoint:
    """Mark a route that streams its body to storage and enforces the upload limit itself."""
    setattr(endpoint, _STREAMED, True)
    return endpoint


def _too_large(limit: int, length: int | None = None) -> HTTPException:
    told = f"of {length} bytes " if length is not None else ""
    return HTTPException(
        413,
        f"request body {told}is larger than the limit of {limit} bytes of this route "
        "(SLIDEWATCH_MAX_REQUEST_BYTES); uploads go to the upload routes",
    )


class BodyLimitMiddleware:
    """Holds every route not marked @streamed_upload to `limit` bytes of body.

    The route is known only once the router has matched it, which it records in the
    request's scope (`endpoint`); the body is read after that, so the check is made as
    the route reads its body: first the declared length, then the bytes as they arrive.
    """

    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit = self.limit
        received = 0

        async def counted() -> Message:
            nonlocal received
            if getattr(scope.get("endpoint"), _STREAMED, False):
                return await receive()
            if received == 0:
                length = _content_length(scope)
                if length is not None and length > limit:
                    # Raised inside the route's body read: answered as a 413.
                    raise _too_large(limit, length)
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise _too_large(limit)
            return message

        await self.app(scope, counted, send)


def _content_length(scope: Scope) -> int | None:
    for name, value in scope["headers"]:
        if name == b"content-length":
            text = value.decode("latin-1").strip()
            return int(text) if text.isdigit() and len(text) < 20 else None
    return None
