"""Who may read which layer's tiles, remembered for a few seconds by each API process.

A map asks for dozens of tiles a second with one token. Checking each one in full (the
token, the role on the site, the layer's product: four queries, a session and a hop to the
thread pool) cost more than serving the tile from its cache, and with 20 people panning,
the queue of those checks was most of a tile's latency. So a check that passed is kept
for `ttl_s` seconds (SLIDEWATCH_TILE_GRANT_TTL_S) under its token and layer: a revoked
token, a removed role or a deleted product stops opening tiles at most that long after
the change. A check that failed is never kept, so a role just granted opens tiles at once.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

from starlette.concurrency import run_in_threadpool

from backend.db.tokens import hash_token

Granted = TypeVar("Granted")

# Enough for every layer of a few hundred people's maps; the oldest go first beyond it.
MAX_GRANTS = 4096


class TileGrants(Generic[Granted]):
    """Checks that passed, by key, each for `ttl_s` seconds (0: none kept)."""

    def __init__(self, ttl_s: float, max_entries: int = MAX_GRANTS) -> None:
        self.ttl_s = ttl_s
        self.max_entries = max_entries
        self._entries: OrderedDict[Hashable, tuple[float, Granted]] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: Hashable) -> Granted | None:
        with self._lock:
            entry = self._entries.get(key)
            if entry is None:
                return None
            expires, granted = entry
            if time.monotonic() >= expires:
                del self._entries[key]
                return None
            return granted

    def put(self, key: Hashable, granted: Granted) -> None:
        if self.ttl_s <= 0:
            return
        with self._lock:
            self._entries[key] = (time.monotonic() + self.ttl_s, granted)
            self._entries.move_to_end(key)
            while len(self._entries) > self.max_entries:
                self._entries.popitem(last=False)

    async def resolve(self, key: Hashable, check: Callable[[], Granted]) -> Granted:
        """The kept grant of `key`, else `check()` run in the thread pool (it raises
        HTTPException to refuse) and kept."""
        granted = self.get(key)
        if granted is None:
            granted = await run_in_threadpool(check)
            self.put(key, granted)
        return granted


def grant_key(secret: str, *parts: Hashable) -> tuple[Hashable, ...]:
    # The secret's hash, not the secret, is what stays in memory.
    return (hash_token(secret), *parts)
