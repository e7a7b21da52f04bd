"""A video read while it is still uploading: frames come as their bytes arrive, the result
is the same as from the finished file, and a stalled or removed upload is named."""

import os
import time
from pathlib import Path

import numpy as np
import pytest

from tests.reconstruction.test_ingest_media import make_video
from tests.reconstruction.test_slam_parts import write_panning_video
from tests.video_helpers import SlowWriter, faststart_copy, moov_before_mdat
from worker.pipeline.errors import InputError
from worker.pipeline.frames import FrameOptions, prepare_video_frames, read_frame_scan
from worker.pipeline.ingest.arriving import Arrival, ArrivingFile
from worker.pipeline.ingest.video import VideoReader


@pytest.fixture
def clip(tmp_path: Path) -> tuple[Path, Path]:
    """The same 60-frame clip as a camera writes it (index last) and index first."""
    camera = make_video(tmp_path / "camera.mp4", frames=60)
    return camera, faststart_copy(camera, tmp_path / "faststart.mp4")


def _frames_while_arriving(source: Path, part: Path, pieces: int = 12, pause_s: float = 0.15):
    data = source.read_bytes()
    part.write_bytes(b"")
    writer = SlowWriter(data, part, pieces, pause_s)
    writer.start()
    reader = VideoReader(part, Arrival(len(data), stall_timeout_s=10))
    frames, first_at = [], None
    for frame in reader.frames():
        first_at = first_at or time.monotonic()
        frames.append(frame)
    writer.join()
    return frames, first_at, writer.last_piece_at


def test_an_index_first_video_is_decoded_as_it_arrives(clip, tmp_path):
    camera, faststart = clip
    assert moov_before_mdat(faststart) and not moov_before_mdat(camera)
    open_files = len(os.listdir("/proc/self/fd"))
    frames, first_at, last_piece_at = _frames_while_arriving(faststart, tmp_path / "up.part")
    assert len(os.listdir("/proc/self/fd")) == open_files  # the upload's file is closed
    # Decoding began well before the last byte came (12 pieces 0.15 s apart).
    assert first_at < last_piece_at - 0.5
    complete = list(VideoReader(faststart).frames())
    assert [f.index for f in frames] == [f.index for f in complete] == list(range(60))
    assert [f.t for f in frames] == [f.t for f in complete]
    assert all(np.array_equal(a.image, b.image) for a, b in zip(frames, complete, strict=True))


def test_a_video_with_its_index_last_waits_for_the_end(clip, tmp_path):
    camera, _ = clip
    frames, first_at, last_piece_at = _frames_while_arriving(camera, tmp_path / "up.part")
    assert first_at >= last_piece_at  # nothing is decodable before the index arrives
    assert len(frames) == 60


def test_a_stalled_upload_fails_with_what_arrived(clip, tmp_path):
    _, faststart = clip
    data = faststart.read_bytes()
    part = tmp_path / "up.part"
    part.write_bytes(b"")
    SlowWriter(data, part, pieces=4, pause_s=0.05, stop_after=2).start()
    start = time.monotonic()
    with pytest.raises(InputError, match=rf"up.part: the upload stopped at \d+ of {len(data)} "):
        list(VideoReader(part, Arrival(len(data), stall_timeout_s=0.6)).frames())
    assert time.monotonic() - start < 5


def test_a_removed_upload_fails_at_once(clip, tmp_path):
    _, faststart = clip
    data = faststart.read_bytes()
    part = tmp_path / "up.part"
    part.write_bytes(data[: len(data) // 2])
    reader = ArrivingFile(part, Arrival(len(data), stall_timeout_s=60))
    assert reader.read(100) == data[:100]
    part.unlink()  # cancelled by the user, expired, or refused
    start = time.monotonic()
    with pytest.raises(InputError, match=r"the upload was removed after \d+ of"):
        reader.read(len(data))
    assert time.monotonic() - start < 1
    reader.close()


def test_a_finished_upload_may_be_moved_while_it_is_read(tmp_path):
    data = bytes(range(256)) * 40
    part = tmp_path / "up.part"
    part.write_bytes(data[:4000])
    reader = ArrivingFile(part, Arrival(len(data), stall_timeout_s=5))
    assert reader.read(4000) == data[:4000]
    with open(part, "ab") as fh:
        fh.write(data[4000:])
    part.rename(tmp_path / "survey-video.mp4")  # handed over to the survey
    assert reader.read() == data[4000:]
    assert reader.seek(-10, 2) == len(data) - 10 and reader.read() == data[-10:]
    reader.close()


def test_frames_stage_on_an_arriving_video_matches_the_finished_file(tmp_path):
    camera = tmp_path / "camera.mp4"
    write_panning_video(camera, blurred_frame=15)
    source = faststart_copy(camera, tmp_path / "pan.mp4")
    options = FrameOptions(width=320, height=180)
    whole = prepare_video_frames(source, tmp_path / "whole", options, track_step_px=12)
    data = source.read_bytes()
    part = tmp_path / "pan.part"
    part.write_bytes(b"")
    writer = SlowWriter(data, part, pieces=6, pause_s=0.1)
    writer.start()
    streamed = prepare_video_frames(
        part, tmp_path / "streamed", options, track_step_px=12, arrival=Arrival(len(data), 10)
    )
    writer.join()
    a = read_frame_scan(Path(whole.index_path))
    b = read_frame_scan(Path(streamed.index_path))
    assert np.array_equal(a.kept, b.kept) and np.array_equal(a.stored, b.stored)
    assert not b.kept[15] and b.kept.sum() == 29
    np.testing.assert_array_equal(a.motion_px_s, b.motion_px_s)
