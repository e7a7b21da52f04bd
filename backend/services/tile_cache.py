"""Rendered map tiles kept in memory, and the identity of the files they were made from.

A tile is the same PNG for as long as its product's file and its style stay the same, so a
tile is keyed by the file's identity (path, device, inode, size and modification time, read
with one `stat` per request) and by everything that styles it (layer, tile, rescale,
colormap, and `RENDER_VERSION` for changes of the rendering code). A product replaced by a
new file (a comparison run again writes its products anew) has another identity, so its
old tiles are never served again; they age out of the LRU.

The key also gives the tile's ETag before anything is read: a browser that sends it back
in `If-None-Match` gets 304 without the tile being rendered or looked up.

Two levels, both LRU and bounded in bytes: the memory of each API process
(SLIDEWATCH_TILE_CACHE_BYTES) and, shared by all the API's processes (which would otherwise
each render every tile once), the workers that render a product's tiles before anyone asks
(backend/services/tile_prerender.py) and kept across restarts, a folder of PNG files
(SLIDEWATCH_TILE_DISK_CACHE_BYTES, under the data directory), written atomically and pruned
of the files read longest ago once it outgrows its bound.

On disk a tile lies in the folder of its group (the survey or comparison whose look it
shows: `comparisons-12`) and of its file's identity, so that deleting a survey or a
comparison removes its tiles at once (`forget_groups`), and a product replaced by a new
file leaves no tiles of the old one behind (`keep_only`).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

# Bump when the same file and style render differently (colours, encoding, resampling),
# so that caches and browsers do not keep tiles of the old code.
RENDER_VERSION = 3


@dataclass(frozen=True)
class FileIdentity:
    """What changes when a file is replaced or rewritten: a new inode (an atomic rename),
    or a new size or modification time (written in place)."""

    path: str
    device: int
    inode: int
    size: int
    mtime_ns: int


def file_identity(path: Path | str) -> FileIdentity:
    stat = os.stat(path)
    return FileIdentity(str(path), stat.st_dev, stat.st_ino, stat.st_size, stat.st_mtime_ns)


@dataclass(frozen=True)
class TileKey:
    file: FileIdentity
    layer: str  # the layer's name and style, e.g. "dh/difference"
    z: int
    x: int
    y: int
    rescale: tuple[float, float] | None
    colormap: str | None
    # The survey or comparison whose look the tile shows ("comparisons/12"): its tiles on
    # disk go with it.
    group: str = ""

    @property
    def etag(self) -> str:
        # A strong validator: the same bytes for as long as the key holds.
        digest = hashlib.blake2b(repr((RENDER_VERSION, self)).encode(), digest_size=16)
        return f'"{digest.hexdigest()}"'


def etag_matches(if_none_match: str | None, etag: str) -> bool:
    """Whether `If-None-Match` names `etag` (or is `*`); weak validators match too, as
    RFC 9110 asks for If-None-Match."""
    if not if_none_match:
        return False
    for candidate in if_none_match.split(","):
        candidate = candidate.strip()
        if candidate == "*" or candidate.removeprefix("W/") == etag:
            return True
    return False


class TileCache:
    """A thread-safe LRU of PNG bytes in memory, bounded by their total size, over an
    optional `DiskTileCache` shared with the other processes."""

    def __init__(self, max_bytes: int, disk: DiskTileCache | None = None) -> None:
        self.max_bytes = max_bytes
        self.disk = disk
        self._tiles: OrderedDict[TileKey, bytes] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()
        self.hits = 0  # from memory
        self.disk_hits = 0
        self.misses = 0

    def get(self, key: TileKey) -> bytes | None:
        """From memory, else from disk (which reads a file: call it off the event loop,
        or `get_memory` on it and this in a thread)."""
        png = self.get_memory(key)
        return png if png is not None else self.get_disk(key)

    def get_memory(self, key: TileKey) -> bytes | None:
        with self._lock:
            png = self._tiles.get(key)
            if png is not None:
                self._tiles.move_to_end(key)
                self.hits += 1
            elif self.disk is None:
                self.misses += 1
            return png

    def get_disk(self, key: TileKey) -> bytes | None:
        if self.disk is None:
            return None
        png = self.disk.get(key)
        with self._lock:
            if png is None:
                self.misses += 1
                return None
            self.disk_hits += 1
        self._remember(key, png)
        return png

    def put(self, key: TileKey, png: bytes) -> None:
        """Keep `png` in memory and on disk (a file write: off the event loop)."""
        self._remember(key, png)
        if self.disk is not None:
            self.disk.put(key, png)

    def _remember(self, key: TileKey, png: bytes) -> None:
        if len(png) > self.max_bytes:
            return  # also what a cache of size 0 (turned off) does
        with self._lock:
            old = self._tiles.pop(key, None)
            if old is not None:
                self._bytes -= len(old)
            self._tiles[key] = png
            self._bytes += len(png)
            while self._bytes > self.max_bytes:
                _, evicted = self._tiles.popitem(last=False)
                self._bytes -= len(evicted)

    @property
    def size_bytes(self) -> int:
        return self._bytes

    def __len__(self) -> int:
        return len(self._tiles)


def group_name(owner: str, owner_id: int) -> str:
    """The group of the tiles of a survey's or a comparison's layers ("surveys", 3)."""
    return f"{owner}/{owner_id}"


def _identity_name(identity: FileIdentity) -> str:
    return hashlib.blake2b(repr(identity).encode(), digest_size=8).hexdigest()


class DiskTileCache:
    """PNG files named by their tile's ETag in `folder`, shared by processes:
    `folder/<group>/<file identity>/<etag>.png`.

    A hit touches the file's modification time, so that pruning, which removes the files
    touched longest ago until the folder is back under 90 % of `max_bytes`, keeps the tiles
    in use. Each process prunes after it has written a tenth of the bound (and at its first
    write, which also learns what earlier runs left); files another process removes
    meanwhile are simply gone."""

    def __init__(self, folder: Path, max_bytes: int) -> None:
        self.folder = folder
        self.max_bytes = max_bytes
        self._written = 0
        self._pruned_once = False
        self._lock = threading.Lock()

    def _group_folder(self, group: str) -> Path:
        return self.folder / (group.replace("/", "-") or "other")

    def path(self, key: TileKey) -> Path:
        name = key.etag.strip('"')
        return self._group_folder(key.group) / _identity_name(key.file) / f"{name}.png"

    def contains(self, key: TileKey) -> bool:
        return self.path(key).is_file()

    def _note_path(self, group: str, identity: FileIdentity, name: str) -> Path:
        return self._group_folder(group) / _identity_name(identity) / f"{name}.json"

    def get_note(self, group: str, identity: FileIdentity, name: str) -> object | None:
        """What was noted about a file beside its tiles (its default stretch), or None."""
        try:
            return json.loads(self._note_path(group, identity, name).read_text())
        except (OSError, ValueError):
            return None

    def put_note(self, group: str, identity: FileIdentity, name: str, value: object) -> None:
        """Note `value` (JSON) beside the file's tiles; it goes with them."""
        path = self._note_path(group, identity, name)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            handle, temporary = tempfile.mkstemp(dir=path.parent, suffix=".part")
            with os.fdopen(handle, "w") as out:
                json.dump(value, out)
            os.replace(temporary, path)
        except OSError:
            return

    def get(self, key: TileKey) -> bytes | None:
        path = self.path(key)
        try:
            png = path.read_bytes()
            os.utime(path)
        except OSError:
            return None
        return png

    def put(self, key: TileKey, png: bytes) -> None:
        if len(png) > self.max_bytes:
            return
        path = self.path(key)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            # Written beside its place and renamed: a reader never sees half a tile.
            handle, temporary = tempfile.mkstemp(dir=path.parent, suffix=".part")
            with os.fdopen(handle, "wb") as out:
                out.write(png)
            os.replace(temporary, path)
        except OSError:
            return  # a full or read-only disk costs renders, not answers
        with self._lock:
            self._written += len(png)
            due = not self._pruned_once or self._written > self.max_bytes // 10
            if due:
                self._written, self._pruned_once = 0, True
        if due:
            self.prune()

    def forget_groups(self, groups: list[str]) -> None:
        """Remove every tile of `groups` (their survey or comparison is gone)."""
        for group in groups:
            shutil.rmtree(self._group_folder(group), ignore_errors=True)

    def keep_only(self, group: str, identities: set[FileIdentity]) -> int:
        """Remove the tiles of `group` made from files other than `identities` (products
        replaced by new files, or no longer there); how many folders went."""
        keep = {_identity_name(identity) for identity in identities}
        removed = 0
        try:
            folders = list(self._group_folder(group).iterdir())
        except OSError:
            return 0
        for folder in folders:
            if folder.name not in keep:
                shutil.rmtree(folder, ignore_errors=True)
                removed += 1
        return removed

    def prune(self) -> None:
        files = []
        total = 0
        for path in self.folder.glob("*/*/*.png"):
            try:
                stat = path.stat()
            except OSError:
                continue
            files.append((stat.st_mtime_ns, stat.st_size, path))
            total += stat.st_size
        if total <= self.max_bytes:
            return
        files.sort()
        for _mtime, size, path in files:
            if total <= self.max_bytes * 0.9:
                break
            path.unlink(missing_ok=True)
            total -= size


def forget_tiles(folder: Path, groups: list[str]) -> None:
    """Remove the cached tiles of `groups` from the disk cache in `folder`."""
    DiskTileCache(folder, 0).forget_groups(groups)
