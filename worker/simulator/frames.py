"""Rendering many frames, in worker processes when more than one core is available.

The scene arrays are handed to the workers once per survey as ``.npy`` files that they
memory-map; each task renders a short run of consecutive frames and returns the images
in order. Workers are fresh interpreters (``python -m worker.simulator.render_worker``)
talking length-prefixed pickles over their standard input and output: no fork of a
process that already runs OpenCV or encoder threads, and no re-import of the caller's
main module.
Frames are pure functions of (scene, pose, frame index), so the output does not depend
on the number of workers.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from worker.simulator.camera import CameraModel
from worker.simulator.georef import Grid
from worker.simulator.render import HeightFieldRenderer, RenderOptions

_CACHE: dict[str, HeightFieldRenderer] = {}


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


def _render_chunk(ref: SceneRef, items: list, exposure: float):
    r = _renderer(ref)
    t0, c0 = r.stats.seconds, r.stats.cpu_seconds
    out = [r.render(p, rot, frame_index=i, exposure=exposure).image for i, p, rot in items]
    return out, r.stats.seconds - t0, r.stats.cpu_seconds - c0


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
            ref, items, exposure = _recv(inp)
        except EOFError:
            return
        try:
            _send(out, ("ok", _render_chunk(ref, items, exposure)))
        except Exception as exc:  # report, keep serving
            _send(out, ("error", repr(exc)))


class FramePool:
    """Renders frame sequences with `workers` processes (in this process if 1)."""

    def __init__(self, workers: int, scratch: Path) -> None:
        self.workers = max(1, int(workers))
        self.scratch = Path(scratch)
        self._procs: list[subprocess.Popen] = []
        self._local: dict[str, HeightFieldRenderer] = {}

    def __enter__(self) -> FramePool:
        if self.workers > 1:
            env = dict(os.environ)
            root = str(Path(__file__).resolve().parents[2])
            env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
            for _ in range(self.workers):
                self._procs.append(
                    subprocess.Popen(
                        [sys.executable, "-m", "worker.simulator.render_worker"],
                        stdin=subprocess.PIPE,
                        stdout=subprocess.PIPE,
                        env=env,
                    )
                )
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        for p in self._procs:
            if exc_type is not None:
                p.kill()  # it may be blocked writing a result nobody will read
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
            self._local = {
                key: HeightFieldRenderer(dsm, grid, ortho, camera, options, noise_seed=noise_seed)
            }
        return SceneRef(key, str(dsm_path), str(ortho_path), grid, camera, options, noise_seed)

    def render(
        self,
        ref: SceneRef,
        positions: np.ndarray,
        rotations: np.ndarray,
        exposure: float = 1.0,
        first_index: int = 0,
        chunk: int = 6,
        stats: RenderRun | None = None,
    ) -> Iterator[np.ndarray]:
        """Yield the rendered images in order."""
        stats = stats if stats is not None else RenderRun()
        t_start = time.perf_counter()
        n = len(positions)
        items = [
            (first_index + i, np.asarray(positions[i]), np.asarray(rotations[i])) for i in range(n)
        ]
        if not self._procs:
            r = self._local[ref.key]
            for i, p, rot in items:
                t0, c0 = r.stats.seconds, r.stats.cpu_seconds
                img = r.render(p, rot, frame_index=i, exposure=exposure).image
                stats.render_seconds += r.stats.seconds - t0
                stats.cpu_seconds += r.stats.cpu_seconds - c0
                stats.frames += 1
                yield img
            stats.wall_seconds += time.perf_counter() - t_start
            return
        chunks = [items[i : i + chunk] for i in range(0, n, chunk)]
        nw = len(self._procs)
        sent = 0
        ahead = 2 * nw
        for i in range(len(chunks)):
            while sent < len(chunks) and sent < i + ahead:
                _send(self._procs[sent % nw].stdin, (ref, chunks[sent], exposure))
                sent += 1
            try:
                status, payload = _recv(self._procs[i % nw].stdout)
            except EOFError as exc:
                raise RuntimeError("a render worker exited unexpectedly (see stderr)") from exc
            if status != "ok":
                raise RuntimeError(f"render worker failed: {payload}")
            images, secs, cpu = payload
            stats.render_seconds += secs
            stats.cpu_seconds += cpu
            stats.frames += len(images)
            yield from images
        stats.wall_seconds += time.perf_counter() - t_start
