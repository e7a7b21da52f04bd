"""Flight-log variants of real files (fixtures/flight_logs) and the keep-what-is-good rule:
unreadable SRT blocks and CSV rows are skipped and reported by line; a file is refused
only when too little remains."""

import random
import re
from pathlib import Path

import numpy as np
import pytest

from worker.pipeline.errors import InputError
from worker.pipeline.ingest.read_log import read_flight_log
from worker.pipeline.ingest.recordings import VideoClues

FIXTURES = Path(__file__).parent / "fixtures" / "flight_logs"


def fixture(name: str) -> Path:
    return FIXTURES / name


def has(log, *words: str) -> bool:
    return any(all(w in warning for w in words) for warning in log.warnings)


def test_phantom4rtk_attitude_with_degree_signs():
    log = read_flight_log(fixture("p4rtk_degree_signs.srt"))
    assert log.variant == "phantom4rtk" and len(log) == 4
    np.testing.assert_allclose(log.attitude["pitch"], 2.7)
    np.testing.assert_allclose(log.attitude["roll"], [-0.4, -0.5, -0.6, -0.7])
    np.testing.assert_allclose(log.attitude["yaw"], [89.1, 89.2, 89.3, 89.4])
    np.testing.assert_allclose(log.attitude["gimbal_pitch"], -90.0)
    np.testing.assert_allclose(log.attitude["gimbal_yaw"], [89.0, 89.1, 89.2, 89.3])
    np.testing.assert_allclose(log.lon, [139.7671, 139.7672, 139.7673, 139.7674])
    np.testing.assert_allclose(log.alt, [60.0, 60.1, 60.2, 60.3])
    assert log.alt_ref == "takeoff"
    assert not has(log, "unreadable")


def test_mavic_pro_gps_not_available_block_has_no_fix():
    log = read_flight_log(fixture("mavic_pro_gps_na.srt"))
    assert log.variant == "mavic_pro" and len(log) == 5
    assert log.valid.tolist() == [True, True, False, True, True]
    np.testing.assert_allclose(log.lon[log.valid], [149.0250, 149.0251, 149.0253, 149.0254])
    np.testing.assert_allclose(log.alt, [1.9, 2.9, 3.9, 4.9, 5.9])  # barometer still read
    assert has(log, "position 'N/A' (no fix) in 1 blocks", "lines 14")


def test_joined_recordings_keep_the_longest_and_say_so():
    log = read_flight_log(fixture("joined_recordings.srt"))
    assert len(log) == 5
    np.testing.assert_allclose(log.t, [0, 1, 2, 3, 4])
    np.testing.assert_allclose(log.lon, 8.3090)
    assert has(log, "joins 2 recordings", "3.0 s", "5.0 s", "kept recording 2", "longest")
    assert log.meta["recording_kept"] == 2
    assert [r["duration_s"] for r in log.meta["recordings"]] == [3.0, 5.0]


def test_joined_recordings_keep_the_one_matching_the_video():
    log = read_flight_log(fixture("joined_recordings.srt"), video=VideoClues(duration_s=3.1))
    assert len(log) == 3
    np.testing.assert_allclose(log.lon, 8.2090)
    np.testing.assert_allclose(log.alt, [45.0, 45.1, 45.2])
    assert has(log, "joins 2 recordings", "kept recording 1, which matches the video (3.1 s)")


def test_enterprise_drone_attitude_is_aircraft_attitude():
    log = read_flight_log(fixture("enterprise_drone_attitude.srt"))
    np.testing.assert_allclose(log.attitude["yaw"], [12.0, 12.1, 12.2])
    np.testing.assert_allclose(log.attitude["pitch"], -1.2)
    np.testing.assert_allclose(log.attitude["roll"], 0.4)
    np.testing.assert_allclose(log.attitude["gimbal_pitch"], -90.0)
    np.testing.assert_allclose(log.attitude["gimbal_yaw"], 12.0)
    assert log.alt_ref == "absolute" and log.alt[0] == pytest.approx(78.9)
    assert not has(log, "radians")


def test_older_heights_hb_is_height_above_takeoff():
    log = read_flight_log(fixture("old_heights_hb_hs.srt"))
    assert log.alt_ref == "takeoff"
    np.testing.assert_allclose(log.alt, [12.0, 12.1, 12.2])  # Hb wins over Hs
    np.testing.assert_allclose(log.lon, [8.2090, 8.2091, 8.2092])
    assert not has(log, "no altitude")


def test_hs_alone_is_read_as_height_with_a_warning(tmp_path):
    text = fixture("old_heights_hb_hs.srt").read_text().replace("Hb:12.", "Hx:12.")
    log = read_flight_log(_write(tmp_path, "hs.srt", text))
    np.testing.assert_allclose(log.alt, 0.8)
    assert has(log, "'Hs' read as the height above take-off")


def test_barometer_in_parentheses():
    log = read_flight_log(fixture("barometer_parentheses.srt"))
    assert log.alt_ref == "takeoff"
    np.testing.assert_allclose(log.alt, [91.0, 91.1, 91.2])


def test_zoom_focal_length_in_mm_is_not_divided():
    log = read_flight_log(fixture("zoom_focal_len.srt"))
    assert log.meta["focal_len_35mm"] == pytest.approx(643.3)
    assert not has(log, "tenths")


def test_implausible_focal_length_is_ignored_with_its_value(tmp_path):
    text = fixture("zoom_focal_len.srt").read_text().replace("643.30", "6433.0")
    log = read_flight_log(_write(tmp_path, "f.srt", text))
    assert "focal_len_35mm" not in log.meta
    assert has(log, "focal_len 6433 mm is not a plausible 35 mm equivalent")


def test_zooming_recording_gives_no_focal_length(tmp_path):
    text = fixture("zoom_focal_len.srt").read_text().replace("643.30", "24.00", 1)
    log = read_flight_log(_write(tmp_path, "z.srt", text))
    assert "focal_len_35mm" not in log.meta
    assert has(log, "focal_len changes during the recording", "24-643.3 mm")


def test_old_firmware_tenths_only_for_whole_numbers_of_those_families(tmp_path):
    text = fixture("zoom_focal_len.srt").read_text().replace("643.30", "240")
    mavic3 = read_flight_log(_write(tmp_path, "m3.srt", text))  # newer family: mm
    assert mavic3.meta["focal_len_35mm"] == pytest.approx(240.0)
    old = re.sub(r"\[rel_alt: [^\]]*\]", "[altitude: 78.9]", text)  # Mavic 2 shape
    mavic2 = read_flight_log(_write(tmp_path, "m2.srt", old))
    assert mavic2.variant == "mavic2" and mavic2.meta["focal_len_35mm"] == pytest.approx(24.0)


def test_blocks_without_time_ranges_use_the_frame_counter():
    log = read_flight_log(fixture("no_time_ranges.srt"))
    assert len(log) == 4 and log.time_base == "video"
    np.testing.assert_allclose(log.t, [0.0, 0.02, 0.04, 0.06])
    np.testing.assert_allclose(log.lat, [35.1234, 35.12341, 35.12342, 35.12343])
    assert has(log, "no time range lines", "frame counter")


def test_blocks_without_time_ranges_or_counter_use_the_clock(tmp_path):
    text = re.sub(r"FrameCnt: \d+, DiffTime: 20ms\n", "", fixture("no_time_ranges.srt").read_text())
    log = read_flight_log(_write(tmp_path, "clock.srt", text))
    np.testing.assert_allclose(log.t, [0.0, 0.02, 0.04, 0.06], atol=1e-9)
    assert has(log, "no time range lines", "clock time")


def test_joined_recordings_without_time_ranges_split_at_the_frame_counter(tmp_path):
    blocks = fixture("no_time_ranges.srt").read_text().strip().split("\n\n")
    second = [b.replace("35.1234", "36.1234") for b in blocks[:2]]
    log = read_flight_log(_write(tmp_path, "j.srt", "\n\n".join(blocks + second) + "\n"))
    np.testing.assert_allclose(log.lat, [35.1234, 35.12341, 35.12342, 35.12343])
    assert has(log, "joins 2 recordings", "0.1 s", "0.0 s", "kept recording 1", "longest")
    short = read_flight_log(
        _write(tmp_path, "j2.srt", "\n\n".join(blocks + second) + "\n"),
        video=VideoClues(duration_s=0.04),
    )
    np.testing.assert_allclose(short.lat, [36.1234, 36.12341])


def test_bracket_latitude_not_available_is_no_fix(tmp_path):
    text = fixture("mavic3_sample.srt").read_text()
    text = text.replace("[latitude: 35.12342]", "[latitude: N/A]")
    log = read_flight_log(_write(tmp_path, "na.srt", text))
    assert len(log) == 10 and log.valid.sum() == 9
    assert has(log, "(no fix) in 1 blocks", "lines 17")


def test_untimed_block_in_a_timed_file_is_skipped(tmp_path):
    text = fixture("mavic3_sample.srt").read_text().replace("\n00:00:00,040 --> 00:00:00,060", "")
    log = read_flight_log(_write(tmp_path, "u.srt", text))
    assert len(log) == 9
    assert has(log, "1 of 10 blocks unreadable", "line 13: the block has no time range line")


def test_repeating_one_second_clock_on_frame_subtitles(tmp_path):
    text = fixture("mavic3_sample.srt").read_text()
    text = re.sub(r"2021-12-25 12:27:52\.\d+", "2021-12-25 12:27:52", text)
    log = read_flight_log(_write(tmp_path, "clock1s.srt", text))
    assert len(log) == 10  # times come from the time ranges, not the repeating clock
    assert log.epoch is not None and log.epoch.second == 52


def test_unreadable_time_range_skips_that_block(tmp_path):
    text = fixture("mavic3_sample.srt").read_text().replace("00:00:00,040 -->", "00:00:0x,040 -->")
    log = read_flight_log(_write(tmp_path, "tr.srt", text))
    assert len(log) == 9
    assert has(log, "1 of 10 blocks unreadable", "line 13: unreadable subtitle time range")


def test_too_few_readable_blocks_refuse_the_file_saying_how_many(tmp_path):
    text = fixture("mavic3_sample.srt").read_text()
    text = re.sub(r"latitude: 35\.1234[0-5]", "latitude: N/Ax", text)
    with pytest.raises(InputError, match=r"only 4 of 10 blocks readable; line 5: latitude 'N/Ax'"):
        read_flight_log(_write(tmp_path, "bad.srt", text))


def test_corrupting_any_one_block_drops_that_block_only(tmp_path):
    """Property: each block in turn gets one of its bracketed numbers replaced by garbage
    (number and garbage chosen by a seeded generator); the log still reads, with one
    block fewer and a warning naming the corrupted line."""
    rng = random.Random(20241125)
    lines = fixture("mavic3_sample.srt").read_text().split("\n")
    garbage = ["x", "12.3.4", "#", "N?A", "1e", "--5", "3,5", "nan?"]
    value = re.compile(r"(?<=: )-?\d+(?:\.\d+)?(?![\d/])")  # not the shutter's 1/500
    numbered = [i for i, line in enumerate(lines) if line.startswith("[iso")]
    assert len(numbered) == 10
    for i in numbered:
        spots = [m for m in value.finditer(lines[i])]
        spot = rng.choice(spots)
        corrupted = list(lines)
        corrupted[i] = lines[i][: spot.start()] + rng.choice(garbage) + lines[i][spot.end() :]
        log = read_flight_log(_write(tmp_path, f"c{i}.srt", "\n".join(corrupted)))
        assert len(log) == 9, corrupted[i]
        assert has(log, "1 of 10 blocks unreadable", f"line {i + 1}:"), log.warnings
        assert i + 1 not in log.lines.tolist()


def test_csv_unreadable_rows_are_skipped_with_their_lines():
    log = read_flight_log(fixture("airdata_bad_rows.csv"))
    assert log.source_format == "airdata_csv" and len(log) == 6
    assert 5 not in log.lines.tolist() and 8 not in log.lines.tolist()
    assert has(log, "2 of 8 rows unreadable", "line 5: latitude '47.46xx'", "line 8:")
    assert log.meta["rows_skipped"] == 2


def test_csv_row_without_time_or_on_no_planet(tmp_path):
    text = "time,lat,lon,alt\n0,47,8,1\n,47.1,8,1\n2,147.2,8,1\n3,47.3,8,1\n4,47.4,8,1\n"
    log = read_flight_log(_write(tmp_path, "g.csv", text))
    np.testing.assert_allclose(log.t, [0, 3, 4])
    assert has(log, "2 of 5 rows unreadable", "line 3: empty time", "line 4: latitude 147.2")


def test_csv_refused_when_most_rows_are_garbage(tmp_path):
    source = fixture("airdata_bad_rows.csv").read_text().split("\n")
    text = "\n".join(
        [source[0]] + [r.replace(",8.2090,", ",8.2x,") for r in source[1:6]] + source[6:]
    )
    with pytest.raises(InputError, match=r"only 2 of 8 rows readable; line 2: longitude"):
        read_flight_log(_write(tmp_path, "bad.csv", text))


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path
