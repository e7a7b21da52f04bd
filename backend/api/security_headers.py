"""Security headers on every response: what the browser may load, frame and send.

The map is one page of our own scripts (no inline script), so its Content-Security-Policy
allows scripts from this origin only; tiles arrive as blob: images fetched with the token
in a header, the basemap (SLIDEWATCH_BASEMAP_URL) from its own origin. Leaflet and the
page position elements with style attributes, so styles may be inline (scripts may not).
The API documentation (/docs) is Swagger UI served by the app from a package, started by
a script file of its own: it lives under the same policy as the map, and needs no CDN.
"""

from __future__ import annotations

from urllib.parse import urlsplit

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from backend.config import Settings


def map_policy(basemap_url: str | None) -> str:
    images = ["'self'", "data:", "blob:"]
    if basemap_url:
        parts = urlsplit(basemap_url.replace("{s}", "a"))
        if parts.scheme and parts.netloc:
            # The basemap's tiles come from its servers ({s}: any of its subdomains).
            host = parts.netloc.replace("a.", "*.", 1) if "{s}" in basemap_url else parts.netloc
            images.append(f"{parts.scheme}://{host}")
    return "; ".join(
        [
            "default-src 'self'",
            "script-src 'self'",
            "style-src 'self' 'unsafe-inline'",
            f"img-src {' '.join(images)}",
            "connect-src 'self'",
            "font-src 'self' data:",
            "object-src 'none'",
            "base-uri 'none'",
            "form-action 'self'",
            "frame-ancestors 'none'",
        ]
    )


class SecurityHeadersMiddleware:
    def __init__(self, app: ASGIApp, settings: Settings) -> None:
        self.app = app
        common = {
            "x-content-type-options": "nosniff",
            "x-frame-options": "DENY",
            "referrer-policy": "no-referrer",
            "cross-origin-opener-policy": "same-origin",
            "permissions-policy": "camera=(), microphone=(), geolocation=(), payment=()",
        }
        if settings.resolved_public_url.startswith("https://"):
            common["strict-transport-security"] = "max-age=31536000"
        self.headers = [
            (k.encode(), v.encode())
            for k, v in {
                **common,
                "content-security-policy": map_policy(settings.basemap_url),
            }.items()
        ]

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        added = self.headers

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                present = {name.lower() for name, _ in message.get("headers", [])}
                message["headers"] = [
                    *message.get("headers", []),
                    *((name, value) for name, value in added if name not in present),
                ]
            await send(message)

        await self.app(scope, receive, with_headers)
