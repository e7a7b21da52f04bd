"""Video decoding with PyAV: each frame with its presentation time, as a stream.

Frame times are seconds since the presentation time of the first frame, the same
clock as DJI SRT subtitles (whose first block starts at 0). Frames are resized by
area averaging while decoding, so 4K video costs little memory. Grey frames of 8-bit
YUV video are its luma plane, resized by OpenCV and expanded to full range by a
look-up table: what FFmpeg's scaler gives to within one grey level, at a third of its
cost (measured: 0.9 ms instead of 2.5 ms per 720p frame).

Unreadable input raises `InputError` naming the file: not a video, no video stream,
codec without a decoder, nothing decodable. Damage after the first frames (a truncated
upload) ends the stream early with a warning in `VideoReader.warnings` instead, so that
a streaming reconstruction keeps what it has.

A video still uploading is read with its `Arrival` (the length it will have): decoding
waits for bytes that have not arrived yet instead of ending (see `arriving.py`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from fractions import Fraction
from pathlib import Path
from typing import Any

import av
import cv2
import numpy as np

from worker.pipeline.errors import InputError
from worker.pipeline.ingest.arriving import Arrival, ArrivingFile


@dataclass
class VideoInfo:
    path: str
    container: str
    codec: str
    width: int
    height: int
    fps: float
    duration_s: float | None
    frames: int | None  # the container's count, else estimated from duration and rate
    creation_time: str | None  # ISO 8601 UTC as the container states it, or None
    frames_stated: bool = False  # `frames` is the container's count, not an estimate

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class VideoFrame:
    index: int  # index among all decoded frames (before any stride)
    t: float  # seconds since the first frame
    image: np.ndarray  # (H, W) uint8 grey or (H, W, 3) uint8 BGR
    # The decoded frame itself, when asked for (`VideoReader.frames(keep_source=True)`):
    # a caller that decides later whether it needs the frame at another size.
    source: av.VideoFrame | None = None


# Formats whose first plane is 8-bit luma, at full resolution.
_LUMA_FORMATS = frozenset(
    {"yuv420p", "yuvj420p", "yuv422p", "yuvj422p", "yuv444p", "yuvj444p", "nv12", "nv21"}
)
# Limited-range luma (16-235) to full-range grey, as FFmpeg's scaler converts it.
_LIMITED_TO_FULL = np.clip(np.round((np.arange(256) - 16) * 255 / 219), 0, 255).astype(np.uint8)


def _gray(frame: av.VideoFrame, width: int | None, height: int | None) -> np.ndarray:
    """The frame as a grey image of (width, height) (area averaging when smaller)."""
    name = frame.format.name
    if name not in _LUMA_FORMATS:
        return frame.reformat(
            width=width, height=height, format="gray", interpolation="AREA"
        ).to_ndarray()
    plane = frame.planes[0]
    luma = np.frombuffer(plane, np.uint8).reshape(plane.height, plane.line_size)
    luma = luma[:, : frame.width]
    size = (width or frame.width, height or frame.height)
    if size != (frame.width, frame.height):
        luma = cv2.resize(luma, size, interpolation=cv2.INTER_AREA)
    full_range = name.startswith("yuvj") or frame.color_range == 2  # AVCOL_RANGE_JPEG
    if full_range:
        return luma.copy() if luma.base is not None else luma  # not the decoder's buffer
    return cv2.LUT(luma, _LIMITED_TO_FULL)


def yuv420p_planes(frame: av.VideoFrame, width: int, height: int) -> tuple[np.ndarray, bool]:
    """The frame as YUV 4:2:0 of (width, height) (even), in the layout
    `av.VideoFrame.from_ndarray(..., format="yuv420p")` takes (the luma rows, then U and
    V), and whether it is full range (JPEG).

    4:2:0 video (what drones record) has its planes resized by OpenCV's area averaging,
    a fifth of the cost of FFmpeg's scaler, and keeps its range; other formats go
    through the scaler, to limited range."""
    full_range = frame.format.name == "yuvj420p" or frame.color_range == 2  # AVCOL_RANGE_JPEG
    if frame.format.name not in ("yuv420p", "yuvj420p"):
        scaled = frame.reformat(width=width, height=height, format="yuv420p", interpolation="AREA")
        return scaled.to_ndarray(), False
    planes = []
    chroma = (width // 2, height // 2)
    for plane, size in zip(frame.planes, ((width, height), chroma, chroma), strict=True):
        data = np.frombuffer(plane, np.uint8).reshape(plane.height, plane.line_size)
        data = data[:, : plane.width]
        if (plane.width, plane.height) != size:
            data = cv2.resize(data, size, interpolation=cv2.INTER_AREA)
        planes.append(data.reshape(-1))
    return np.concatenate(planes).reshape(height * 3 // 2, width), full_range


@contextmanager
def _opened(path: Path, arrival: Arrival | None = None) -> Iterator[av.container.InputContainer]:
    """The video opened for decoding (through an `ArrivingFile` while it is still
    arriving); container and file are closed on leaving."""
    name = path.name
    if not path.is_file():
        raise InputError(f"{name}: video not found")
    size = path.stat().st_size
    if size == 0 and arrival is None:
        raise InputError(f"{name}: the video file is empty")
    with ExitStack() as stack:
        source: ArrivingFile | str = str(path)
        if arrival is not None and size < arrival.total_bytes:
            source = stack.enter_context(ArrivingFile(path, arrival))
        try:
            container = stack.enter_context(av.open(source, mode="r"))
        except av.FFmpegError as exc:
            raise InputError(
                f"{name}: not a readable video ({exc.strerror or exc}); is the file complete?"
            ) from None
        if not container.streams.video:
            raise InputError(f"{name}: the file has no video stream")
        yield container


def _creation_time(container: av.container.InputContainer) -> str | None:
    text = container.metadata.get("creation_time") or container.streams.video[0].metadata.get(
        "creation_time"
    )
    if not text:
        return None
    try:
        dt = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        return None
    if dt.tzinfo is not None:
        dt = dt.astimezone(UTC).replace(tzinfo=None)
    return dt.isoformat()


def probe_video(path: Path | str, arrival: Arrival | None = None) -> VideoInfo:
    """Container, codec, size, frame rate, duration and creation time of a video."""
    path = Path(path)
    with _opened(path, arrival) as container:
        stream = container.streams.video[0]
        ctx = stream.codec_context
        if ctx is None or not ctx.name:
            raise InputError(f"{path.name}: the video codec is not supported")
        rate = stream.average_rate or stream.guessed_rate or Fraction(30)
        duration = None
        if stream.duration is not None and stream.time_base is not None:
            duration = float(stream.duration * stream.time_base)
        elif container.duration is not None:
            duration = container.duration / 1e6
        frames = stream.frames or (round(duration * float(rate)) if duration else None)
        return VideoInfo(
            path=str(path),
            container=container.format.name,
            codec=ctx.name,
            width=ctx.width,
            height=ctx.height,
            fps=float(rate),
            duration_s=duration,
            frames=frames,
            creation_time=_creation_time(container),
            frames_stated=bool(stream.frames),
        )


class VideoReader:
    """Decode a video as a stream of `VideoFrame`s (see the module doc for errors)."""

    def __init__(self, path: Path | str, arrival: Arrival | None = None) -> None:
        self.path = Path(path)
        self.arrival = arrival
        self.info = probe_video(self.path, arrival)
        self.warnings: list[str] = []
        self.frames_decoded = 0

    def frames(
        self,
        size: tuple[int, int] | None = None,
        gray: bool = True,
        every: int = 1,
        start_s: float = 0.0,
        end_s: float | None = None,
        threads: int = 2,
        wanted: Callable[[float], bool] | None = None,
        keep_source: bool = False,
    ) -> Iterator[VideoFrame]:
        """Yield every `every`-th frame in [start_s, end_s), resized to `size` (w, h);
        with `wanted`, only the frames whose time it accepts (the others are decoded,
        as they must be, but not converted); with `keep_source`, each with its decoded
        frame."""
        name = self.path.name
        index = -1
        with _opened(self.path, self.arrival) as container:
            stream = container.streams.video[0]
            stream.thread_type = "AUTO"
            stream.codec_context.thread_count = threads
            width, height = size if size else (None, None)
            first_pts: int | None = None
            time_base = stream.time_base or Fraction(1, 90000)
            fps = self.info.fps or 30.0
            decoded = container.decode(stream)
            while True:
                try:
                    frame = next(decoded)
                except StopIteration:
                    break
                except (av.FFmpegError, EOFError) as exc:
                    if index < 0:
                        raise InputError(
                            f"{name}: the video cannot be decoded ({exc}); the file is "
                            "damaged or uses an unsupported codec"
                        ) from None
                    self.warnings.append(
                        f"{name}: decoding stopped after {index + 1} frames ({exc}); "
                        "the rest of the file is damaged or missing"
                    )
                    break
                index += 1
                pts = frame.pts
                if pts is None:
                    t = index / fps
                else:
                    if first_pts is None:
                        first_pts = pts
                    t = float((pts - first_pts) * time_base)
                if t < start_s - 1e-6 or index % every:
                    continue
                if end_s is not None and t >= end_s:
                    break
                if wanted is not None and not wanted(t):
                    continue
                if gray:
                    image = _gray(frame, width, height)
                else:
                    image = frame.reformat(
                        width=width, height=height, format="bgr24", interpolation="AREA"
                    ).to_ndarray()
                self.frames_decoded += 1
                yield VideoFrame(
                    index=index, t=t, image=image, source=frame if keep_source else None
                )
        if index < 0:
            raise InputError(f"{name}: the video has no decodable frame")


def iter_frames(path: Path | str, **kwargs: Any) -> Iterator[VideoFrame]:
    """Shorthand for `VideoReader(path).frames(**kwargs)`."""
    return VideoReader(path).frames(**kwargs)
