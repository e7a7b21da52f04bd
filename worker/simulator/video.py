"""MP4 writing with PyAV (H.264 through libx264 of PyAV's bundled FFmpeg, else MPEG-4).

Frames get consecutive presentation timestamps in a 1/fps time base, so the video is
exactly constant frame rate: frame i is shown at i / fps seconds.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from fractions import Fraction
from pathlib import Path

import av
import numpy as np


def pick_codec(preferred: str = "auto") -> str:
    """libx264 when PyAV's FFmpeg has it, else mpeg4."""
    available = av.codecs_available
    if preferred != "auto":
        if preferred not in available:
            raise ValueError(f"codec {preferred!r} is not in PyAV's FFmpeg")
        return preferred
    return "libx264" if "libx264" in available else "mpeg4"


@dataclass(frozen=True)
class VideoOptions:
    fps: float = 30.0
    codec: str = "auto"
    crf: int = 20
    preset: str = "veryfast"
    threads: int = 1
    bitrate: int = 8_000_000
    """Only for mpeg4."""


@dataclass
class VideoResult:
    path: Path
    codec: str
    frames: int
    fps: float
    width: int
    height: int

    def to_dict(self) -> dict:
        return {
            "codec": self.codec,
            "frames": self.frames,
            "fps": self.fps,
            "width": self.width,
            "height": self.height,
            "duration_s": round(self.frames / self.fps, 6),
        }


class VideoWriter:
    """Context manager writing RGB uint8 frames (h, w, 3) to an MP4."""

    def __init__(
        self,
        path: Path,
        width: int,
        height: int,
        options: VideoOptions | None = None,
        creation_time: datetime | None = None,
    ) -> None:
        self.options = options or VideoOptions()
        self.path = Path(path)
        self.width = width
        self.height = height
        self.codec = pick_codec(self.options.codec)
        self._container = av.open(str(self.path), mode="w")
        if creation_time is not None:
            self._container.metadata["creation_time"] = creation_time.strftime(
                "%Y-%m-%dT%H:%M:%S.000000Z"
            )
        fps = Fraction(self.options.fps).limit_denominator(1001)
        self._fps = fps
        stream = self._container.add_stream(self.codec, rate=fps)
        stream.width = width
        stream.height = height
        stream.pix_fmt = "yuv420p"
        stream.codec_context.time_base = 1 / fps
        if self.codec == "libx264":
            stream.options = {
                "crf": str(self.options.crf),
                "preset": self.options.preset,
                "threads": str(self.options.threads),
            }
        else:
            stream.bit_rate = self.options.bitrate
            stream.options = {"threads": str(self.options.threads)}
        self._stream = stream
        self.frames = 0

    def write(self, rgb: np.ndarray) -> None:
        if rgb.shape != (self.height, self.width, 3):
            raise ValueError(f"frame shape {rgb.shape} != {(self.height, self.width, 3)}")
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
        frame.pts = self.frames
        frame.time_base = 1 / self._fps
        for packet in self._stream.encode(frame):
            self._container.mux(packet)
        self.frames += 1

    def close(self) -> VideoResult:
        for packet in self._stream.encode():
            self._container.mux(packet)
        self._container.close()
        return VideoResult(
            path=self.path,
            codec=self.codec,
            frames=self.frames,
            fps=float(self._fps),
            width=self.width,
            height=self.height,
        )

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.result = self.close()
        else:
            self._container.close()
