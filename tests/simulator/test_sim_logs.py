"""DJI SRT and AirData CSV follow the formats in shared/notes/drone-formats.md."""

import csv
import re
from datetime import datetime, timedelta

import av
import numpy as np
import pytest
from simtest_support import image_run, short_run

from worker.simulator.flight_log import FEET, airdata_columns
from worker.simulator.georef import SceneFrame
from worker.simulator.truth_io import read_trajectory_csv

BLOCK = re.compile(
    r"^(?P<idx>\d+)\n"
    r"(?P<t0>\d\d:\d\d:\d\d,\d\d\d) --> (?P<t1>\d\d:\d\d:\d\d,\d\d\d)\n"
    r'<font size="28">FrameCnt: (?P<cnt>\d+), DiffTime: (?P<diff>\d+)ms\n'
    r"(?P<date>\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\.\d\d\d)\n"
    r"\[iso: 100\] \[shutter: 1/500\.0\] \[fnum: 2\.8\] \[ev: 0\] \[focal_len: 24\.00\] "
    r"\[latitude: (?P<lat>-?\d+\.\d{6})\] \[longitude: (?P<lon>-?\d+\.\d{6})\] "
    r"\[rel_alt: (?P<rel>-?\d+\.\d{3}) abs_alt: (?P<abs>-?\d+\.\d{3})\] \[ct: 5500\] </font>$"
)


def _ms(tc: str) -> int:
    h, m, rest = tc.split(":")
    s, ms = rest.split(",")
    return ((int(h) * 60 + int(m)) * 60 + int(s)) * 1000 + int(ms)


@pytest.fixture(scope="module")
def run():
    return short_run()


def _frame_count(path) -> int:
    with av.open(str(path)) as c:
        return c.streams.video[0].frames


def test_srt_has_one_dji_block_per_video_frame(run):
    s = run.survey(1)
    text = (run.root / s["srt"]).read_text(encoding="utf-8")
    blocks = text.strip("\n").split("\n\n")
    assert len(blocks) == s["frames"] == _frame_count(run.root / s["video"])
    start = datetime.fromisoformat(s["start_local"])
    traj = read_trajectory_csv(run.root / s["trajectory"])
    lats, lons = [], []
    for i, b in enumerate(blocks):
        m = BLOCK.match(b)
        assert m, f"block {i + 1} does not follow the format:\n{b}"
        assert int(m["idx"]) == int(m["cnt"]) == i + 1
        t0, t1 = _ms(m["t0"]), _ms(m["t1"])
        assert t0 == round(i * 1000 / 30) and t1 == round((i + 1) * 1000 / 30)
        assert int(m["diff"]) == t1 - t0 in (33, 34)
        assert datetime.strptime(m["date"], "%Y-%m-%d %H:%M:%S.%f") == start + timedelta(
            milliseconds=t0
        )
        lats.append(float(m["lat"]))
        lons.append(float(m["lon"]))
    # Stand-alone GPS: a bias of metres, nearly constant over 3 s, plus noise.
    frame = SceneFrame(
        run.data["crs"], run.data["frame"]["origin_e"], run.data["frame"]["origin_n"]
    )
    x, y = frame.from_lonlat(np.array(lons), np.array(lats))
    ex = x - (traj["e"] - frame.origin_e)
    ey = y - (traj["n"] - frame.origin_n)
    bias = np.array(s["gnss"]["bias_enu_m"])
    assert np.hypot(ex.mean(), ey.mean()) < 15.0
    assert abs(ex.mean() - bias[0]) < 2.0 and abs(ey.mean() - bias[1]) < 2.0
    assert ex.std() < 0.5 and ey.std() < 0.5


def test_airdata_csv_header_rate_units_and_offset(run):
    s = run.survey(1)
    path = run.root / s["flight_log_csv"]
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    header, body = rows[0], rows[1:]
    assert header == airdata_columns("feet")
    assert " compass_heading(degrees)" in header and " xSpeed(mph)" in header
    col = {name: i for i, name in enumerate(header)}
    t_ms = np.array([int(r[col["time(millisecond)"]]) for r in body])
    assert t_ms[0] == 0 and np.all(np.diff(t_ms) == 100)  # 10 Hz
    for r in body[:5]:
        datetime.strptime(r[col["datetime(utc)"]], "%Y-%m-%d %H:%M:%S")
    is_video = np.array([int(r[col["isVideo"]]) for r in body])
    rec = np.flatnonzero(is_video)
    assert abs(len(rec) * 0.1 - s["frames"] / 30.0) <= 0.15
    # The first recording row is stamped at the video start (UTC, whole seconds).
    first = datetime.strptime(body[rec[0]][col["datetime(utc)"]], "%Y-%m-%d %H:%M:%S")
    start_utc = datetime.fromisoformat(s["start_utc"].rstrip("Z"))
    assert abs((first - start_utc).total_seconds()) <= 1.0
    # Heights are in feet.
    h_ft = np.array([float(r[col["height_above_takeoff(feet)"]]) for r in body])
    assert 6.0 < np.median(h_ft[rec]) * FEET < 8.0
    # The logged positions lag the video by log_time_offset_s (0.25 s here): they fit
    # the true trajectory shifted by the offset better than the unshifted one.
    frame = SceneFrame(
        run.data["crs"], run.data["frame"]["origin_e"], run.data["frame"]["origin_n"]
    )
    lat = np.array([float(r[col["latitude"]]) for r in body])[rec]
    lon = np.array([float(r[col["longitude"]]) for r in body])[rec]
    x, y = frame.from_lonlat(lon, lat)
    traj = read_trajectory_csv(run.root / s["trajectory"])
    tt = s["flight_log_start_s"] + t_ms[rec] / 1000.0  # true (video clock) row times

    def misfit(offset: float) -> float:
        t = np.clip(tt - offset, 0, traj["t_s"][-1])
        px = np.interp(t, traj["t_s"], traj["x_local"])
        py = np.interp(t, traj["t_s"], traj["y_local"])
        rx, ry = x - px, y - py
        return float(np.hypot(rx - rx.mean(), ry - ry.mean()).mean())

    assert s["log_time_offset_s"] == 0.25
    assert misfit(0.25) < misfit(0.0)


def test_metre_csv_without_gnss_error_matches_the_truth():
    run = image_run()
    s = run.survey(1)
    with open(run.root / s["flight_log_csv"], newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    header, body = rows[0], rows[1:]
    assert header == airdata_columns("meters")
    col = {name: i for i, name in enumerate(header)}
    h = np.array([float(r[col["height_above_takeoff(meters)"]]) for r in body])
    state = [r[col["flycState"]] for r in body]
    assert state[0] == "Motors_Off" and "Waypoint" in state
    way = np.array([st == "Waypoint" for st in state])
    assert np.allclose(h[way][5:-5], 7.0, atol=0.15)
    assert sum(int(r[col["isPhoto"]]) for r in body) == s["images"]
