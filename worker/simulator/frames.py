"""Rendering many frames, in worker processes when more than one core is available,
in the background of the caller.

The scene arrays are handed to the workers once per survey as ``.npy`` files that they
memory-map; each task renders a short run (chunk) of consecutive frames. Workers are
fresh interpreters (``python -m worker.simulator.render_worker``) taking small
length-prefixed pickles (task descriptions and replies) over their standard input and
output: no fork of a process that already runs OpenCV or encoder threads, and no
re-import of the caller's main module.

Images do not travel through the pipes: each worker writes them into its frame buffer,
an anonymous shared-memory file (``memfd``) that the parent created and both map. A
buffer holds `slots` chunks, so a worker renders up to `slots` chunks ahead of the
consumer (the video encoder) instead of blocking on a pipe until the parent reads a
4 MB pickle, and no image is pickled, piped and unpickled (four copies) on its way.

`FramePool.submit` renders a sequence in one background thread of the parent, jobs in
submission order, and hands the frames in order to a consumer (the video encoder, which
releases the GIL while it encodes): the caller goes on with other work (the next step's
truth) while the workers render. `FramePool.render` renders in the calling thread.

Frames are pure functions of (scene, pose, frame index), so the output does not depend
on the number of workers, the chunk size or the timing.
"""

from __future__ import annotations

import contextlib
import mmap
import os
import pickle
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, TypeVar

import numpy as np

from worker.simulator.camera import CameraModel
from worker.simulator.georef import Grid
from worker.simulator.render import HeightFieldRenderer, RenderOptions

T = TypeVar("T")

_CACHE: dict[str, HeightFieldRenderer] = {}
_BUFFER: dict[int, tuple[int, mmap.mmap]] = {}  # worker side: fd -> (size, map)

# Large numpy temporaries (a frame's worth of float32 is ~0.9 MB) are above glibc's
# initial mmap threshold: each would be mapped, page-faulted and unmapped again (system
# time was 14 % of a render benchmark's CPU time; 7 % with these). The caller's own
# settings win.
_WORKER_MALLOC_ENV = {
    "MALLOC_MMAP_THRESHOLD_": str(64 * 1024 * 1024),
    "MALLOC_TRIM_THRESHOLD_": str(256 * 1024 * 1024),
}


def default_workers() -> int:
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        n = os.cpu_count() or 1
    return max(1, min(2, n))


@dataclass(frozen=True)
class SceneRef:
    """Where a worker finds the arrays of one survey's scene."""

    key: str
    dsm_path: str
    ortho_path: str
    grid: Grid
    camera: CameraModel
    options: RenderOptions
    noise_seed: int


def _renderer(ref: SceneRef) -> HeightFieldRenderer:
    r = _CACHE.get(ref.key)
    if r is None:
        _CACHE.clear()
        dsm = np.load(ref.dsm_path, mmap_mode="r")
        ortho = np.load(ref.ortho_path, mmap_mode="r")
        r = HeightFieldRenderer(
            np.asarray(dsm),
            ref.grid,
            np.asarray(ortho),
            ref.camera,
            ref.options,
            noise_seed=ref.noise_seed,
        )
        _CACHE[ref.key] = r
    return r


def _worker_buffer(fd: int, size: int) -> mmap.mmap:
    """The worker's map of its frame buffer, remapped when the parent has grown it."""
    have = _BUFFER.get(fd)
    if have is None or have[0] != size:
        if have is not None:
            have[1].close()
        _BUFFER[fd] = (size, mmap.mmap(fd, size))
    return _BUFFER[fd][1]


def _render_chunk(ref: SceneRef, items: list, exposure: float, buf: tuple[int, int, int]):
    """Render `items` into the frame buffer at `buf` = (fd, buffer size, byte offset)."""
    r = _renderer(ref)
    fd, size, offset = buf
    h, w = ref.camera.height, ref.camera.width
    out = np.frombuffer(
        _worker_buffer(fd, size), np.uint8, count=len(items) * h * w * 3, offset=offset
    ).reshape(len(items), h, w, 3)
    t0, c0 = r.stats.seconds, r.stats.cpu_seconds
    for k, (i, p, rot) in enumerate(items):
        out[k] = r.render(p, rot, frame_index=i, exposure=exposure).image
    del out  # no view may outlive a remap of the buffer
    return len(items), r.stats.seconds - t0, r.stats.cpu_seconds - c0


@dataclass
class RenderRun:
    """Counters of one `FramePool.render` call."""

    frames: int = 0
    render_seconds: float = 0.0
    cpu_seconds: float = 0.0
    wall_seconds: float = 0.0


def _send(stream: BinaryIO, obj) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(struct.pack("<Q", len(data)))
    stream.write(data)
    stream.flush()


def _recv(stream: BinaryIO):
    head = stream.read(8)
    if len(head) < 8:
        raise EOFError
    (n,) = struct.unpack("<Q", head)
    data = stream.read(n)
    if len(data) < n:
        raise EOFError
    return pickle.loads(data)


def serve(inp: BinaryIO, out: BinaryIO) -> None:
    """Worker loop: render the chunks it is sent until its input closes."""
    import cv2

    cv2.setNumThreads(1)
    while True:
        try:
            ref, items, exposure, buf = _recv(inp)
        except EOFError:
            return
        try:
            _send(out, ("ok", _render_chunk(ref, items, exposure, buf)))
        except Exception as exc:  # report, keep serving
            _send(out, ("error", repr(exc)))


class _FrameBuffer:
    """The parent's side of one worker's frame buffer (an fd both processes map)."""

    def __init__(self, scratch: Path) -> None:
        if hasattr(os, "memfd_create"):
            # Anonymous: freed with the last process holding it, even after a crash.
            self.fd = os.memfd_create("slidewatch-frames")
        else:  # pragma: no cover - not Linux
            with tempfile.TemporaryFile(dir=scratch) as f:  # unlinked already
                self.fd = os.dup(f.fileno())
        self.size = 0
        self._map: mmap.mmap | None = None

    def ensure(self, size: int) -> None:
        """Grow to at least `size` bytes (only between jobs: no chunk is in flight)."""
        if size <= self.size:
            return
        if self._map is not None:
            self._map.close()
        os.ftruncate(self.fd, size)
        self.size = size
        self._map = mmap.mmap(self.fd, size)

    def images(self, offset: int, n: int, h: int, w: int) -> Iterator[np.ndarray]:
        """Copies of the n images at `offset` (the slot is reused after the next send)."""
        view = np.frombuffer(self._map, np.uint8, count=n * h * w * 3, offset=offset)
        view = view.reshape(n, h, w, 3)
        try:
            for k in range(n):
                yield view[k].copy()
        finally:
            del view

    def close(self) -> None:
        if self._map is not None:
            self._map.close()
            self._map = None
        os.close(self.fd)


class FramePool:
    """Renders frame sequences with `workers` processes (in this process if 1).

    `chunk` frames make one task; each worker holds `slots` tasks' images at a time.
    `submit` blocks while `max_jobs` jobs are queued or running: each holds its scene
    (files, or a renderer of 100+ MB in this process)."""

    def __init__(
        self, workers: int, scratch: Path, chunk: int = 6, slots: int = 2, max_jobs: int = 2
    ) -> None:
        self.workers = max(1, int(workers))
        self.scratch = Path(scratch)
        self.chunk = max(1, int(chunk))
        self.slots = max(1, int(slots))
        self._jobs = threading.BoundedSemaphore(max(1, int(max_jobs)))
        self._procs: list[subprocess.Popen] = []
        self._buffers: list[_FrameBuffer] = []
        self._local: dict[str, HeightFieldRenderer] = {}
        self._pending: dict[str, int] = {}  # background jobs per scene key
        self._latest: str | None = None
        self._state = threading.Lock()  # _local, _pending, _latest
        self._io = threading.Lock()  # one render at a time talks to the workers
        self._cancel = threading.Event()
        self._executor: ThreadPoolExecutor | None = None

    def __enter__(self) -> FramePool:
        if self.workers > 1:
            env = dict(os.environ)
            root = str(Path(__file__).resolve().parents[2])
            env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
            for k, v in _WORKER_MALLOC_ENV.items():
                env.setdefault(k, v)
            for _ in range(self.workers):
                buf = _FrameBuffer(self.scratch)
                self._buffers.append(buf)
                self._procs.append(
                    subprocess.Popen(
                        [sys.executable, "-m", "worker.simulator.render_worker"],
                        stdin=subprocess.PIPE,
                        stdout=subprocess.PIPE,
                        env=env,
                        pass_fds=(buf.fd,),
                    )
                )
        self._executor = ThreadPoolExecutor(1, thread_name_prefix="slidewatch-frames")
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            # Stop background jobs: they fail fast once the workers are gone.
            self._cancel.set()
            for p in self._procs:
                p.kill()  # it may be blocked writing a reply nobody will read
        if self._executor is not None:
            self._executor.shutdown(wait=True)  # normal exit: pending jobs complete
            self._executor = None
        for p in self._procs:
            with contextlib.suppress(OSError):
                p.stdin.close()
        for p in self._procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
            p.stdout.close()
        self._procs = []
        for b in self._buffers:
            b.close()
        self._buffers = []

    def scene(
        self,
        key: str,
        dsm: np.ndarray,
        grid: Grid,
        ortho: np.ndarray,
        camera: CameraModel,
        options: RenderOptions,
        noise_seed: int,
    ) -> SceneRef:
        """Register the arrays of a scene to render from."""
        self.scratch.mkdir(parents=True, exist_ok=True)
        dsm_path = self.scratch / f"{key}-dsm.npy"
        ortho_path = self.scratch / f"{key}-ortho.npy"
        if self._procs:
            np.save(dsm_path, np.ascontiguousarray(dsm, dtype=np.float32))
            np.save(ortho_path, np.ascontiguousarray(ortho))
        else:
            r = HeightFieldRenderer(dsm, grid, ortho, camera, options, noise_seed=noise_seed)
            with self._state:
                self._local[key] = r
                self._latest = key
                self._drop_idle_scenes()
        return SceneRef(key, str(dsm_path), str(ortho_path), grid, camera, options, noise_seed)

    def _drop_idle_scenes(self) -> None:
        """Forget local renderers (100+ MB each) no job needs and no caller can ask
        for any more (all but the latest registered). Call with `_state` held."""
        for k in list(self._local):
            if k != self._latest and self._pending.get(k, 0) == 0:
                del self._local[k]

    def submit(
        self,
        ref: SceneRef,
        positions: np.ndarray,
        rotations: np.ndarray,
        consume: Callable[[Iterator[np.ndarray]], T],
        exposure: float = 1.0,
        stats: RenderRun | None = None,
    ) -> Future[T]:
        """Render in the background: `consume(images)` runs in the pool's thread on the
        images in order, after earlier jobs; the future gives what it returns."""
        if self._executor is None:
            raise RuntimeError("FramePool.submit outside its with block")
        positions = np.array(positions, dtype=np.float64)
        rotations = np.array(rotations, dtype=np.float64)
        self._jobs.acquire()
        with self._state:
            self._pending[ref.key] = self._pending.get(ref.key, 0) + 1

        def job() -> T:
            frames = self.render(ref, positions, rotations, exposure=exposure, stats=stats)
            try:
                return consume(frames)
            finally:
                frames.close()
                with self._state:
                    self._pending[ref.key] -= 1
                    self._drop_idle_scenes()
                self._jobs.release()

        return self._executor.submit(job)

    def render(
        self,
        ref: SceneRef,
        positions: np.ndarray,
        rotations: np.ndarray,
        exposure: float = 1.0,
        first_index: int = 0,
        stats: RenderRun | None = None,
    ) -> Iterator[np.ndarray]:
        """Yield the rendered images in order (after any background job)."""
        stats = stats if stats is not None else RenderRun()
        n = len(positions)
        items = [
            (first_index + i, np.asarray(positions[i]), np.asarray(rotations[i])) for i in range(n)
        ]
        with self._io:
            t_start = time.perf_counter()
            if not self._procs:
                with self._state:
                    r = self._local[ref.key]
                for i, p, rot in items:
                    if self._cancel.is_set():
                        raise RuntimeError("rendering cancelled")
                    t0, c0 = r.stats.seconds, r.stats.cpu_seconds
                    img = r.render(p, rot, frame_index=i, exposure=exposure).image
                    stats.render_seconds += r.stats.seconds - t0
                    stats.cpu_seconds += r.stats.cpu_seconds - c0
                    stats.frames += 1
                    yield img
            else:
                yield from self._render_workers(ref, items, exposure, stats)
            stats.wall_seconds += time.perf_counter() - t_start

    def _render_workers(
        self, ref: SceneRef, items: list, exposure: float, stats: RenderRun
    ) -> Iterator[np.ndarray]:
        h, w = ref.camera.height, ref.camera.width
        slot_bytes = self.chunk * h * w * 3
        for b in self._buffers:
            b.ensure(slot_bytes * self.slots)
        chunks = [items[i : i + self.chunk] for i in range(0, len(items), self.chunk)]
        nw = len(self._procs)
        # Chunk c goes to worker c % nw, slot (c // nw) % slots. Chunk c + ahead reuses
        # that slot, and is sent only once chunk c has been consumed.
        ahead = nw * self.slots
        sent = received = 0

        def place(c: int) -> tuple[int, int]:
            return c % nw, ((c // nw) % self.slots) * slot_bytes

        try:
            for i in range(len(chunks)):
                while sent < len(chunks) and sent < i + ahead:
                    k, off = place(sent)
                    b = self._buffers[k]
                    task = (ref, chunks[sent], exposure, (b.fd, b.size, off))
                    _send(self._procs[k].stdin, task)
                    sent += 1
                k, off = place(i)
                try:
                    status, payload = _recv(self._procs[k].stdout)
                except EOFError as exc:
                    raise RuntimeError("a render worker exited unexpectedly (see stderr)") from exc
                received += 1
                if status != "ok":
                    raise RuntimeError(f"render worker failed: {payload}")
                if self._cancel.is_set():
                    raise RuntimeError("rendering cancelled")
                count, secs, cpu = payload
                stats.render_seconds += secs
                stats.cpu_seconds += cpu
                stats.frames += count
                yield from self._buffers[k].images(off, count, h, w)
        finally:
            # Stopped early (error in the consumer, or closed): collect the replies
            # still due, so that the next render starts in step with the workers.
            if not self._cancel.is_set():
                for c in range(received, sent):
                    with contextlib.suppress(EOFError):
                        _recv(self._procs[place(c)[0]].stdout)
