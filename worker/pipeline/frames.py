"""Frames: resize, reject blurred frames, measure image motion, choose keyframes.

- `sharpness`: variance of the Laplacian of a grey frame.
- `BlurFilter`: rejects a frame whose sharpness is below `blur_ratio` times the median
  of the last `blur_window` frames (relative, so texture-poor scenes are not all
  rejected; a fixed floor `min_sharpness` catches frames that are blank).
- `MotionMeter`: median KLT displacement of a sparse grid between consecutive frames
  (measured at half size), in pixels per second (the image-motion signal the
  time-offset estimate correlates with the log speed).
- `KeyframePolicy`: a new keyframe when the median parallax since the last keyframe
  exceeds `parallax_px`, when fewer than `min_survival` of the last keyframe's tracks
  survive, or when fewer than `min_tracked_points` map points are tracked.
- `prepare_video_frames`: the `frames` stage for video: decode once at the processing
  size (640x360 as in the paper), filter, measure, and store the kept frames as a
  near-lossless H.264 file (CRF 12, ~1.5 ms per frame to write, ~1 ms to read) with a
  CSV index, so reconstruction does not decode the original (often 4K H.265) again.
  Given the tracker's frame step, only the frames the tracker will use are stored
  (about half of a 30 fps video): the others would be encoded and decoded for nothing.
  Asked for a colour size, the same frames are also stored in colour at that size
  (`colour.mkv`, CRF 18), for the orthophoto: its views are keyframes, chosen among
  these, and without this copy the orthophoto decoded the original once more (at
  2560 px, 7.5 of its 18 s).
- `extract_still_frames`: frames at a fixed rate and a larger size as JPEGs (the `sfm`
  method's input, as the paper gave OpenDroneMap 3 fps at 2560 px).
"""

from __future__ import annotations

import csv
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import ExitStack
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import av
import cv2
import numpy as np

from worker.pipeline.atomic import atomic_path
from worker.pipeline.errors import InputError
from worker.pipeline.ingest.arriving import Arrival
from worker.pipeline.ingest.video import VideoFrame, VideoReader, yuv420p_planes
from worker.pipeline.progress import ProgressFn, no_progress


@dataclass
class FrameOptions:
    width: int = 640
    height: int = 360
    every: int = 1  # keep every n-th decoded frame (1: all)
    blur_ratio: float = 0.5
    blur_window: int = 31
    min_sharpness: float = 2.0
    crf: int = 12
    colour_crf: int = 18  # the orthophoto's colour copy: see the module doc


@dataclass
class KeyframePolicy:
    parallax_px: float = 45.0
    # In turns the view rotates and tracks leave it at a few pixels of parallax: at 0.7
    # every tracked frame of a turn became a keyframe (77 of 188 on the paper's mounds),
    # each with its bundle adjustment and SGBM pair. 0.5 gave 138 keyframes and a DSM
    # error no worse (measured on two simulated mound surveys, seeds 1 and 2).
    min_survival: float = 0.5
    min_tracked_points: int = 60

    def is_keyframe(self, parallax_px: float, survival: float, tracked_points: int) -> bool:
        return (
            parallax_px >= self.parallax_px
            or survival < self.min_survival
            or tracked_points < self.min_tracked_points
        )


def sharpness(gray: np.ndarray) -> float:
    """Variance of the Laplacian (higher is sharper)."""
    return float(cv2.Laplacian(gray, cv2.CV_32F, ksize=3).var())


class BlurFilter:
    def __init__(self, ratio: float = 0.5, window: int = 31, min_sharpness: float = 2.0):
        self.ratio = ratio
        self.min_sharpness = min_sharpness
        self.history: deque[float] = deque(maxlen=window)

    def accept(self, score: float) -> bool:
        self.history.append(score)
        if score < self.min_sharpness:
            return False
        if len(self.history) < 5:
            return True
        return score >= self.ratio * float(np.median(self.history))


class MotionMeter:
    """Median image motion between consecutive frames (pixels per second).

    KLT follows a grid of points every `step` pixels from one frame to the next, on the
    frames at 1 / `scale` of their size with the window and the pyramid scaled alike
    (21 px and 4 levels at full size). At half size it costs half as much; on the mounds
    survey the motion moved by 0.3 % (median) and the same frames were chosen."""

    def __init__(self, shape: tuple[int, int], step: int = 40, scale: int = 2):
        h, w = shape
        self.scale = max(1, int(scale))
        self.size = (max(1, w // self.scale), max(1, h // self.scale))
        ys, xs = np.mgrid[step // 2 : h : step, step // 2 : w : step]
        grid = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float32)
        self.grid = (grid / self.scale).astype(np.float32)
        self.window = round(21 / self.scale) | 1
        self.levels = max(1, 4 - (self.scale.bit_length() - 1))
        self.prev: np.ndarray | None = None
        self.prev_t: float | None = None

    def update(self, t: float, gray: np.ndarray) -> float:
        if self.scale > 1:
            gray = cv2.resize(gray, self.size, interpolation=cv2.INTER_AREA)
        speed = float("nan")
        if self.prev is not None and self.prev_t is not None and t > self.prev_t:
            nxt, status, _ = cv2.calcOpticalFlowPyrLK(
                self.prev,
                gray,
                self.grid,
                None,
                winSize=(self.window, self.window),
                maxLevel=self.levels,
            )
            ok = status.ravel() == 1
            if ok.sum() >= 5:
                d = np.linalg.norm(nxt[ok] - self.grid[ok], axis=1)
                speed = float(np.median(d)) * self.scale / (t - self.prev_t)
        self.prev, self.prev_t = gray, t
        return speed


@dataclass
class FrameScan:
    """What the frames stage measured per decoded frame."""

    t: np.ndarray
    index: np.ndarray
    sharpness: np.ndarray
    motion_px_s: np.ndarray
    kept: np.ndarray
    stored: np.ndarray  # in frames.mkv (the kept frames, or those the tracker uses)

    def to_dict(self) -> dict[str, Any]:
        return {
            "frames": int(self.t.size),
            "kept": int(self.kept.sum()),
            "stored": int(self.stored.sum()),
            "blurred": int((~self.kept).sum()),
            "duration_s": float(self.t[-1] - self.t[0]) if self.t.size else 0.0,
        }


@dataclass
class FramesResult:
    video_path: str
    index_path: str
    width: int
    height: int
    fps: float
    scan: FrameScan
    seconds: float
    warnings: list[str] = field(default_factory=list)
    # The stored frames in colour (see the module doc), when asked for.
    colour_video_path: str | None = None
    colour_size: tuple[int, int] | None = None

    def to_dict(self) -> dict[str, Any]:
        d = {k: v for k, v in asdict(self).items() if k != "scan"}
        d.update(self.scan.to_dict())
        return d


class TrackingSelector:
    """Chooses, frame by frame, the kept frames at least `min_step_px` of image motion
    (or `max_gap_s` seconds) apart (the online form of `tracking_frames`, which adds the
    last kept frame at the end).

    A 30 fps video from 90 m moves a pixel or two per frame: tracking every frame costs
    time and gains nothing over tracking every fourth, which KLT follows just as well.
    """

    def __init__(self, min_step_px: float, max_gap_s: float) -> None:
        self.min_step_px = min_step_px
        self.max_gap_s = max_gap_s
        self.travelled = 0.0
        self.prev_t: float | None = None
        self.last: tuple[float, float] | None = None  # (travelled, t) at the last choice

    def update(self, t: float, motion_px_s: float, kept: bool) -> bool:
        """Feed every decoded frame in order; True when this one is chosen."""
        dt = t - self.prev_t if self.prev_t is not None else 0.0
        self.prev_t = t
        # Unknown motion (first frame, failed flow) counts as a full step: keep such frames.
        finite = np.isfinite(motion_px_s)
        self.travelled += motion_px_s * dt if finite else self.min_step_px
        if not kept:
            return False
        if self.min_step_px <= 0 or self.last is None:
            chosen = True
        else:
            travelled, last_t = self.last
            chosen = self.travelled - travelled >= self.min_step_px or t - last_t >= self.max_gap_s
        if chosen:
            self.last = (self.travelled, t)
        return chosen


def tracking_frames(scan: FrameScan, min_step_px: float, max_gap_s: float) -> np.ndarray:
    """Frame indices the tracker needs: see `TrackingSelector`, and the last kept frame."""
    selector = TrackingSelector(min_step_px, max_gap_s)
    chosen = [
        i
        for i, (t, speed, kept) in enumerate(
            zip(scan.t.tolist(), scan.motion_px_s.tolist(), scan.kept.tolist(), strict=True)
        )
        if selector.update(t, speed, kept)
    ]
    kept = np.flatnonzero(scan.kept)
    if kept.size and chosen[-1] != kept[-1]:
        chosen.append(int(kept[-1]))
    return scan.index[np.array(chosen, dtype=int)]


T = TypeVar("T")

FRAMES_VIDEO = "frames.mkv"
FRAMES_INDEX = "frames.csv"
COLOUR_VIDEO = "colour.mkv"
# Frames waiting for the encoder at most: decoding waits beyond (memory stays bounded
# whatever the video's size).
_ENCODE_QUEUE = 8


class _H264File:
    """Frames appended to an H.264 Matroska file at `rate` frames per second, each
    frame's time stamp its order (readers map them back through frames.csv). The file
    is opened at the first frame, which says whether the video is full range (JPEG)."""

    def __init__(self, path: Path, rate: int, size: tuple[int, int], crf: int, layout: str):
        self.path, self.rate, self.size, self.crf = path, rate, size, crf
        self.layout = layout  # how the arrays given are laid out: "gray" or "yuv420p"
        self.full_range = False
        self.container: av.container.OutputContainer | None = None
        self.written = 0

    def _open(self, full_range: bool) -> av.video.stream.VideoStream:
        self.container = av.open(str(self.path), "w", format="matroska")
        stream = self.container.add_stream("libx264", rate=self.rate)
        stream.width, stream.height = self.size
        stream.pix_fmt = "yuv420p"
        stream.options = {"crf": str(self.crf), "preset": "ultrafast", "tune": "fastdecode"}
        if full_range:
            stream.codec_context.color_range = 2  # AVCOL_RANGE_JPEG
        self.full_range = full_range
        return stream

    def write(self, image: np.ndarray, full_range: bool = False) -> None:
        stream = self._open(full_range) if self.container is None else self.container.streams[0]
        frame = av.VideoFrame.from_ndarray(image, format=self.layout)
        if self.full_range:
            frame.color_range = 2
        frame.pts = self.written
        self.written += 1
        for packet in stream.encode(frame):
            self.container.mux(packet)

    def close(self) -> None:
        stream = self._open(False) if self.container is None else self.container.streams[0]
        for packet in stream.encode():
            self.container.mux(packet)
        self.container.close()


def prepare_video_frames(
    video_path: Path,
    out_dir: Path,
    options: FrameOptions | None = None,
    progress: ProgressFn = no_progress,
    track_step_px: float = 0.0,
    track_max_gap_s: float = 0.5,
    arrival: Arrival | None = None,
    colour_size: tuple[int, int] | None = None,
) -> FramesResult:
    """Decode, filter and store the frames for reconstruction (see the module doc).

    With `track_step_px` > 0 only the frames `tracking_frames` chooses with these
    arguments are stored; with 0 every kept frame is. With `colour_size` (width, height,
    both even) the stored frames are also written in colour at that size (COLOUR_VIDEO).
    With `arrival`, the video is still uploading: frames are decoded as its bytes
    arrive."""
    start = time.perf_counter()
    options = options or FrameOptions()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    reader = VideoReader(video_path, arrival)
    info = reader.info
    total = info.frames or 0
    blur = BlurFilter(options.blur_ratio, options.blur_window, options.min_sharpness)
    motion = MotionMeter((options.height, options.width))
    selector = TrackingSelector(track_step_px, track_max_gap_s)
    rows: list[list[str]] = []
    rate = max(1, round(info.fps / options.every))
    colour_path = out_dir / COLOUR_VIDEO
    colour_path.unlink(missing_ok=True)  # never a copy of an earlier run's frames
    with ExitStack() as outputs:
        grey = _H264File(
            outputs.enter_context(atomic_path(out_dir / FRAMES_VIDEO)),
            rate,
            (options.width, options.height),
            options.crf,
            "gray",
        )
        colour = None
        if colour_size is not None:
            colour = _H264File(
                outputs.enter_context(atomic_path(colour_path)),
                rate,
                colour_size,
                options.colour_crf,
                "yuv420p",
            )

        def encode(frame: VideoFrame) -> None:
            grey.write(frame.image)
            if colour is not None and colour_size is not None and frame.source is not None:
                colour.write(*yuv420p_planes(frame.source, *colour_size))

        # x264 encoding (with muxing), and sharpness with KLT motion, each run in a worker
        # thread of their own while this one decodes the next frame (PyAV and OpenCV
        # release the GIL). Each worker takes its calls in the order given, so the files
        # and frames.csv are what one thread would write.
        with (
            ThreadPoolExecutor(1, thread_name_prefix="encode") as encoder,
            ThreadPoolExecutor(1, thread_name_prefix="measure") as measurer,
        ):
            encoding: deque[Future[None]] = deque()

            def store(frame: VideoFrame) -> None:
                encoding.append(encoder.submit(encode, frame))
                while encoding and (encoding[0].done() or len(encoding) > _ENCODE_QUEUE):
                    encoding.popleft().result()  # raises what the encoder raised

            pending: tuple[list[str], VideoFrame] | None = None  # last kept, not stored

            def measure(frame: VideoFrame) -> tuple[float, float]:
                return sharpness(frame.image), motion.update(frame.t, frame.image)

            def take(frame: VideoFrame, measured: Future[tuple[float, float]]) -> None:
                nonlocal pending
                score, speed = measured.result()
                keep = blur.accept(score)
                row = [
                    str(frame.index),
                    f"{frame.t:.6f}",
                    f"{score:.3f}",
                    f"{speed:.3f}",
                    str(int(keep)),
                    "0",
                ]
                rows.append(row)
                # Choose from the values frames.csv keeps, as the reconstruct stage will.
                if selector.update(float(row[1]), float(row[3]), keep):
                    row[5] = "1"
                    store(frame)
                    pending = None
                elif keep:
                    pending = (row, frame)
                else:
                    frame.source = None  # the decoded frame is not needed any more
                if total and frame.index % 50 == 0:
                    progress(min(frame.index / total, 0.99))

            # Frame i is taken once frame i + 1 is decoded, and measured meanwhile.
            previous: tuple[VideoFrame, Future[tuple[float, float]]] | None = None
            size = (options.width, options.height)
            frames = reader.frames(
                size=size, every=options.every, keep_source=colour_size is not None
            )
            for frame in frames:
                current = (frame, measurer.submit(measure, frame))
                if previous is not None:
                    take(*previous)
                previous = current
            if previous is not None:
                take(*previous)
            if pending is not None:  # the tracker also takes the last kept frame
                pending[0][5] = "1"
                store(pending[1])
            while encoding:
                encoding.popleft().result()
        grey.close()
        if colour is not None:
            colour.close()
        if grey.written == 0:
            raise InputError(f"{Path(video_path).name}: every frame is blurred or blank")
    index_path = out_dir / FRAMES_INDEX
    with atomic_path(index_path) as tmp, open(tmp, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["index", "t", "sharpness", "motion_px_s", "kept", "stored"])
        writer.writerows(rows)
    progress(1.0)
    scan = _scan_from_rows([_parse_row(r) for r in rows])
    return FramesResult(
        video_path=str(out_dir / FRAMES_VIDEO),
        index_path=str(index_path),
        width=options.width,
        height=options.height,
        fps=info.fps / options.every,
        scan=scan,
        seconds=time.perf_counter() - start,
        warnings=list(reader.warnings),
        colour_video_path=str(colour_path) if colour is not None else None,
        colour_size=colour_size if colour is not None else None,
    )


_Row = tuple[int, float, float, float, bool, bool]


def _parse_row(row: list[str]) -> _Row:
    return (int(row[0]), float(row[1]), float(row[2]), float(row[3]), row[4] == "1", row[5] == "1")


def _scan_from_rows(rows: list[_Row]) -> FrameScan:
    a = np.array([(*r[:4], float(r[4]), float(r[5])) for r in rows], dtype=float).reshape(-1, 6)
    return FrameScan(
        t=a[:, 1],
        index=a[:, 0].astype(int),
        sharpness=a[:, 2],
        motion_px_s=a[:, 3],
        kept=a[:, 4] > 0.5,
        stored=a[:, 5] > 0.5,
    )


def read_frame_scan(index_path: Path) -> FrameScan:
    with open(index_path, newline="") as fh:
        reader = csv.DictReader(fh)
        # Work folders from before the "stored" column stored every kept frame.
        names = ("index", "t", "sharpness", "motion_px_s", "kept")
        return _scan_from_rows(
            [_parse_row([*(r[k] for k in names), r.get("stored", r["kept"])]) for r in reader]
        )


def iter_prepared_frames(
    out_dir: Path, colour: bool = False, wanted: Callable[[float], bool] | None = None
) -> Iterator[VideoFrame]:
    """The frames stored by `prepare_video_frames`, with their original times: grey at
    the processing size, or with `colour` BGR from its colour copy; with `wanted`, only
    the frames whose original time it accepts (the others are decoded, not converted)."""
    scan = read_frame_scan(Path(out_dir) / FRAMES_INDEX)
    stored_t = scan.t[scan.stored]
    stored_index = scan.index[scan.stored]
    reader = VideoReader(Path(out_dir) / (COLOUR_VIDEO if colour else FRAMES_VIDEO))
    position = -1  # of the frame being decoded: the reader asks about every frame in order

    def take(_stamp: float) -> bool:
        nonlocal position
        position += 1
        return position < stored_t.size and (wanted is None or wanted(float(stored_t[position])))

    for frame in reader.frames(gray=not colour, wanted=take):
        if position >= stored_t.size:
            break
        yield VideoFrame(
            index=int(stored_index[position]), t=float(stored_t[position]), image=frame.image
        )


def prefetched(items: Iterable[T], depth: int = 4) -> Iterator[T]:
    """`items` in order, the next `depth` of them produced ahead in a worker thread (a
    decoder releases the GIL: the next frames are decoded while this one is used)."""
    source = iter(items)
    end = object()

    def pull() -> Any:
        return next(source, end)

    with ThreadPoolExecutor(1, thread_name_prefix="prefetch") as pool:
        ahead = deque(pool.submit(pull) for _ in range(max(1, depth)))
        while (item := ahead.popleft().result()) is not end:
            ahead.append(pool.submit(pull))
            yield item


@dataclass
class StillFrames:
    paths: list[str]
    times: list[float]
    width: int
    height: int

    def to_dict(self) -> dict[str, Any]:
        return {"frames": len(self.paths), "width": self.width, "height": self.height}


def extract_still_frames(
    video_path: Path,
    out_dir: Path,
    fps: float = 3.0,
    max_width: int = 2560,
    blur_ratio: float = 0.5,
    progress: ProgressFn = no_progress,
    arrival: Arrival | None = None,
) -> StillFrames:
    """JPEG frames at `fps` (the sharpest of each interval), at most `max_width` wide."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    reader = VideoReader(video_path, arrival)
    info = reader.info
    width = min(max_width, info.width)
    height = round(info.height * width / info.width / 2) * 2
    interval = 1.0 / fps
    paths: list[str] = []
    times: list[float] = []
    best: tuple[float, VideoFrame] | None = None
    slot = 0
    blur = BlurFilter(ratio=blur_ratio)
    total = info.duration_s or 0.0

    def flush(candidate: tuple[float, VideoFrame] | None) -> None:
        if candidate is None:
            return
        _, frame = candidate
        path = out_dir / f"frame_{len(paths):05d}.jpg"
        with atomic_path(path) as tmp:
            ok, data = cv2.imencode(".jpg", frame.image, [cv2.IMWRITE_JPEG_QUALITY, 92])
            if not ok:
                raise RuntimeError("JPEG encoding failed")
            tmp.write_bytes(data.tobytes())
        paths.append(str(path))
        times.append(frame.t)

    for frame in reader.frames(size=(width, height), gray=False):
        k = int(frame.t // interval)
        if k != slot:
            flush(best)
            best, slot = None, k
            if total:
                progress(min(frame.t / total, 0.99))
        score = sharpness(cv2.cvtColor(frame.image, cv2.COLOR_BGR2GRAY)[::2, ::2])
        if blur.accept(score) and (best is None or score > best[0]):
            best = (score, frame)
    flush(best)
    progress(1.0)
    return StillFrames(paths=paths, times=times, width=width, height=height)
