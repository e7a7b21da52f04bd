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

import asyncio
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
        # Checks running now, by key: on the event loop of the API process that serves.
        self._running: dict[Hashable, asyncio.Future[Granted]] = {}

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
        HTTPException to refuse) and kept. Requests that ask for the same key while its
        check runs wait for that check: a map opening asks for a dozen tiles of a layer at
        once, and each checking for itself queued them all behind a dozen checks."""
        while (running := self._running.get(key)) is not None:
            try:
                return await asyncio.shield(running)
            except asyncio.CancelledError:
                task = asyncio.current_task()
                if not running.cancelled() or (task is not None and task.cancelling()):
                    raise
                # The request that was checking went away: check again.
        granted = self.get(key)
        if granted is not None:
            return granted
        future: asyncio.Future[Granted] = asyncio.get_running_loop().create_future()
        # A refusal nobody else waited for is not an unretrieved exception.
        future.add_done_callback(lambda done: done.cancelled() or done.exception())
        self._running[key] = future
        try:
            granted = await run_in_threadpool(check)
        except Exception as exc:
            future.set_exception(exc)  # the same refusal for those who waited
            raise
        except BaseException:
            future.cancel()
            raise
        finally:
            del self._running[key]
        self.put(key, granted)
        future.set_result(granted)
        return granted


def grant_key(secret: str, *parts: Hashable) -> tuple[Hashable, ...]:
    # The secret's hash, not the secret, is what stays in memory.
    return (hash_token(secret), *parts)
