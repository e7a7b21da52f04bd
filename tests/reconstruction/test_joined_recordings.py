"""An SRT joined from several recordings: the one that matches the video is used (its
length, frame count and start), or, when none matches clearly, the best for now with a
warning naming every recording; the user may choose one, and a choice the file does not
hold is refused naming the recordings.

`joined_same_length.srt`: two recordings of one flight at 30 fps, both about as long as
any video of 0.3-0.5 s: 1 from 2026-07-01 09:00:00 (10 frames, latitude 35.1234...), 2
from 09:04:30 (16 frames, latitude 35.2234...), clocks in local time.
"""

from datetime import datetime
from pathlib import Path

import av
import numpy as np
import pytest

from worker.pipeline.errors import InputError
from worker.pipeline.ingest.read_log import read_flight_log
from worker.pipeline.ingest.recordings import VideoClues
from worker.pipeline.ingest.video import probe_video
from worker.pipeline.reconstruction import ReconstructionOptions

FIXTURE = Path(__file__).parent / "fixtures" / "flight_logs" / "joined_same_length.srt"
RECORDING_1 = "1: from 2026-07-01 09:00:00, 0.3 s, 10 frames, 10 blocks, lines 1-59"
RECORDING_2 = "2: from 2026-07-01 09:04:30, 0.5 s, 16 frames, 16 blocks, lines 61-155"
# The local clock is UTC+2: the container's creation time of recording 2, in UTC.
CREATED_2 = datetime(2026, 7, 1, 7, 4, 30)


def joined_warning(log) -> str:
    (warning,) = [w for w in log.warnings if "joins 2 recordings" in w]
    return warning


def first_latitude(log) -> float:
    return round(float(log.lat[0]), 4)


def test_lengths_tie_and_the_frame_count_picks():
    for frames, kept, latitude in ((10, 1, 35.1234), (16, 2, 35.2234)):
        log = read_flight_log(FIXTURE, video=VideoClues(duration_s=0.4, frames=frames))
        assert log.meta["recording_kept"] == kept and log.meta["recording_choice"] == "matched"
        assert first_latitude(log) == latitude and len(log) == frames
        warning = joined_warning(log)
        assert f"kept recording {kept}, which matches the video (0.4 s, {frames} frames)" in warning
        assert "its length and frame count match" in warning
    assert [r["frames"] for r in log.meta["recordings"]] == [10, 16]


def test_the_start_time_picks_across_time_zones_and_at_the_end():
    log = read_flight_log(FIXTURE, video=VideoClues(duration_s=0.4, creation_time=CREATED_2))
    assert log.meta["recording_kept"] == 2 and first_latitude(log) == 35.2234
    assert "its length and start match" in joined_warning(log)
    # Stamped at the end of recording 1 (0.33 s after 09:00:00), in local time.
    end_of_1 = datetime(2026, 7, 1, 9, 0, 0, 333000)
    log = read_flight_log(FIXTURE, video=VideoClues(duration_s=0.4, creation_time=end_of_1))
    assert log.meta["recording_kept"] == 1 and first_latitude(log) == 35.1234


def test_ambiguous_recordings_are_all_named_and_the_choice_is_used():
    log = read_flight_log(FIXTURE, video=VideoClues(duration_s=0.5))
    assert log.meta["recording_choice"] == "ambiguous"
    warning = joined_warning(log)
    for words in (
        RECORDING_1,
        RECORDING_2,
        "recordings 1 and 2 both match the video (0.5 s) clearly",
        "kept recording 2 for now (its length matches; the nearest in length)",
        "choose one with the option recording (1-2)",
    ):
        assert words in warning, warning
    chosen = read_flight_log(FIXTURE, video=VideoClues(duration_s=0.5), recording=1)
    assert chosen.meta["recording_kept"] == 1 and chosen.meta["recording_choice"] == "chosen"
    assert first_latitude(chosen) == 35.1234 and len(chosen) == 10
    assert "kept recording 1, as chosen; against the video (0.5 s): its length matches" in (
        joined_warning(chosen)
    )


def test_clues_that_disagree_are_not_a_clear_match():
    # The frame count says 1, the start says 2: kept for now, with the reasons.
    video = VideoClues(duration_s=0.4, frames=10, creation_time=CREATED_2)
    log = read_flight_log(FIXTURE, video=video)
    assert log.meta["recording_choice"] == "ambiguous"
    assert "none matches the video (0.4 s, 10 frames, created 2026-07-01 07:04:30)" in (
        joined_warning(log)
    )


def test_a_recording_the_file_does_not_hold_is_refused_naming_them():
    with pytest.raises(InputError) as error:
        read_flight_log(FIXTURE, video=VideoClues(duration_s=0.4), recording=3)
    message = str(error.value)
    assert "joined_same_length.srt: recording 3 was chosen, but the file holds 2" in message
    assert RECORDING_1 in message and RECORDING_2 in message and "choose one of 1-2" in message
    one = Path(__file__).parent / "fixtures" / "flight_logs" / "mavic3_sample.srt"
    assert len(read_flight_log(one, recording=1)) == 10
    with pytest.raises(InputError, match="recording 2 was chosen, but the file holds one"):
        read_flight_log(one, recording=2)
    for bad in (0, "2", True):
        with pytest.raises(InputError, match="recording's number"):
            ReconstructionOptions.from_dict({"recording": bad})


def test_the_video_container_gives_its_frame_count_and_creation_time(tmp_path):
    """What ingest passes: a 16-frame video created at recording 2's start (UTC)."""
    path = tmp_path / "DJI_0002.MP4"
    with av.open(str(path), mode="w") as container:
        container.metadata["creation_time"] = "2026-07-01T07:04:30.000000Z"
        stream = container.add_stream("libx264", rate=30)
        stream.width, stream.height, stream.pix_fmt = 64, 48, "yuv420p"
        for i in range(16):
            image = np.full((48, 64, 3), 10 * i, np.uint8)
            frame = av.VideoFrame.from_ndarray(image, format="rgb24")
            container.mux(stream.encode(frame))
        container.mux(stream.encode(None))
    clues = VideoClues.from_video_info(probe_video(path).to_dict())
    assert clues.frames == 16 and clues.creation_time == CREATED_2
    log = read_flight_log(FIXTURE, video=clues)
    assert log.meta["recording_kept"] == 2 and log.meta["recording_choice"] == "matched"
