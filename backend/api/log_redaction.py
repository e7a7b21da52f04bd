"""Tokens never reach the logs: the access log's request lines are written without them.

GIS clients that cannot send a header pass the token as `?api_key=`; uvicorn's access log
writes each request's path with its query string. A filter on that logger replaces the
value of `api_key` (and any slidewatch token, `sw_…`, wherever it appears) before the line
is written.
"""

from __future__ import annotations

import logging
import re

_API_KEY = re.compile(r"(?i)(api_key=)[^&\s\"]*")
_TOKEN = re.compile(r"sw_[A-Za-z0-9_-]{16,}")
REDACTED = "[redacted]"
ACCESS_LOGGERS = ("uvicorn.access",)


def redact(text: str) -> str:
    return _TOKEN.sub(REDACTED, _API_KEY.sub(rf"\g<1>{REDACTED}", text))


class RedactTokens(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.msg, str):
            record.msg = redact(record.msg)
        if isinstance(record.args, tuple):
            record.args = tuple(redact(a) if isinstance(a, str) else a for a in record.args)
        return True


def redact_access_logs() -> None:
    """Install the filter once per process (apps may be made several times in one)."""
    for name in ACCESS_LOGGERS:
        logger = logging.getLogger(name)
        if not any(isinstance(f, RedactTokens) for f in logger.filters):
            logger.addFilter(RedactTokens())
