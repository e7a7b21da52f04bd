"""Reading a file while it is still being written: an upload in progress.

A survey can be processed while its video is still uploading: the frames stage decodes
what has arrived and waits for the rest. `ArrivingFile` is a read-only binary file whose
length is known in advance (`Arrival.total_bytes`, the length the upload announced); a
read past what is on disk waits for those bytes instead of seeing the end of the file.

It reads through a descriptor opened once, so the file may be renamed (a finished upload
is moved into the survey's folder) while it is read. It gives up with an `InputError`
that says what happened when no byte has arrived for `stall_timeout_s` (the upload
stopped), or when the path is removed before every byte arrived (the upload was
cancelled, expired or refused).

A video whose index comes last in the file (MP4 as most cameras write it, the `moov`
box after the media data) cannot be decoded before the end arrives: the reader then
waits, and the decoding starts when the upload ends. The map uploads such files with
the index first (the media data untouched), so their frames are decoded as they come.
"""

from __future__ import annotations

import io
import os
import time
from dataclasses import dataclass
from pathlib import Path

from worker.pipeline.errors import InputError


@dataclass(frozen=True)
class Arrival:
    """A file still arriving: the size it will have, and how long to wait for bytes."""

    total_bytes: int
    stall_timeout_s: float = 600.0
    poll_s: float = 0.05


class ArrivingFile(io.RawIOBase):
    """A binary file that grows to `arrival.total_bytes` (see the module doc)."""

    def __init__(self, path: Path | str, arrival: Arrival) -> None:
        super().__init__()
        if arrival.total_bytes <= 0:
            raise InputError(f"{Path(path).name}: an arriving file needs its length in bytes")
        self.path = Path(path)
        self.arrival = arrival
        try:
            self._fd = os.open(self.path, os.O_RDONLY)
        except FileNotFoundError:
            raise InputError(f"{self.path.name}: the file is not there (yet)") from None
        self._pos = 0
        self.waited_s = 0.0  # time spent waiting for bytes, for the stage's report

    # -- io.RawIOBase ---------------------------------------------------------------------
    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def tell(self) -> int:
        return self._pos

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        if whence == io.SEEK_SET:
            pos = offset
        elif whence == io.SEEK_CUR:
            pos = self._pos + offset
        elif whence == io.SEEK_END:
            pos = self.arrival.total_bytes + offset
        else:
            raise ValueError(f"unknown whence {whence}")
        if pos < 0:
            raise OSError(f"seek to {pos} before the start of {self.path.name}")
        self._pos = pos
        return pos

    def readinto(self, buffer: bytearray | memoryview) -> int:  # type: ignore[override]
        want = min(len(buffer), self.arrival.total_bytes - self._pos)
        if want <= 0:
            return 0
        self._wait_for(self._pos + want)
        data = os.pread(self._fd, want, self._pos)
        buffer[: len(data)] = data
        self._pos += len(data)
        return len(data)

    def close(self) -> None:
        if not self.closed:
            os.close(self._fd)
        super().close()

    # -- waiting --------------------------------------------------------------------------
    def arrived_bytes(self) -> int:
        return os.fstat(self._fd).st_size

    def _wait_for(self, end: int) -> None:
        """Return once the file holds bytes up to `end` (see the module doc for errors)."""
        size = self.arrived_bytes()
        if size >= end:
            return
        started = last_growth = time.monotonic()
        while size < end:
            if not self.path.exists() and self.arrived_bytes() < self.arrival.total_bytes:
                raise InputError(
                    f"{self.path.name}: the upload was removed after {size} of "
                    f"{self.arrival.total_bytes} bytes (cancelled, expired or refused)"
                )
            now = time.monotonic()
            if now - last_growth > self.arrival.stall_timeout_s:
                raise InputError(
                    f"{self.path.name}: the upload stopped at {size} of "
                    f"{self.arrival.total_bytes} bytes: no data for "
                    f"{self.arrival.stall_timeout_s:.0f} s; resume the upload, then retry"
                )
            time.sleep(self.arrival.poll_s)
            grown = self.arrived_bytes()
            if grown > size:
                size, last_growth = grown, time.monotonic()
        self.waited_s += time.monotonic() - started
