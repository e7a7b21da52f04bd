"""Webhook signatures: HMAC-SHA256 over the timestamp and the raw request body.

Every webhook call carries

    X-Slidewatch-Timestamp: 1767225600                  (Unix seconds when it was sent)
    X-Slidewatch-Signature: sha256=<hex digest>

where the digest is HMAC-SHA256(secret, f"{timestamp}.".encode() + raw_body) with the
webhook's secret (shown once, when the webhook is created). A receiver recomputes it over
the bytes it received, compares in constant time, and refuses timestamps older than a few
minutes, so that a captured call cannot be replayed later. `verify_signature` does all of
it and has no dependency beyond the standard library: copy it into a receiver.
"""

import hashlib
import hmac
import time

SIGNATURE_HEADER = "X-Slidewatch-Signature"
TIMESTAMP_HEADER = "X-Slidewatch-Timestamp"
DEFAULT_TOLERANCE_S = 300


def sign(secret: str, timestamp: int, body: bytes) -> str:
    digest = hmac.new(secret.encode(), f"{timestamp}.".encode() + body, hashlib.sha256)
    return f"sha256={digest.hexdigest()}"


def verify_signature(
    secret: str,
    timestamp: str | int,
    body: bytes,
    signature: str,
    tolerance_s: float = DEFAULT_TOLERANCE_S,
    now: float | None = None,
) -> bool:
    """True if `signature` was made with `secret` over `body` at a recent `timestamp`."""
    try:
        sent_at = int(timestamp)
    except (TypeError, ValueError):
        return False
    if abs((time.time() if now is None else now) - sent_at) > tolerance_s:
        return False
    return hmac.compare_digest(sign(secret, sent_at, body), signature)
