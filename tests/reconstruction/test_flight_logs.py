"""Flight logs: every DJI SRT variant and CSV flavour of the format notes, with their traps."""

from datetime import datetime
from pathlib import Path

import numpy as np
import pytest

from worker.pipeline.errors import InputError
from worker.pipeline.ingest.read_log import read_flight_log


def write(tmp_path: Path, name: str, text: str, encoding: str = "utf-8") -> Path:
    path = tmp_path / name
    path.write_bytes(text.encode(encoding))
    return path


def srt(*texts: str, step_ms: int = 33) -> str:
    """SRT blocks for the given text (one block per entry; lines separated by \\n)."""
    out = []
    for i, text in enumerate(texts):
        a, b = i * step_ms, (i + 1) * step_ms
        out.append(f"{i + 1}\n{_ts(a)} --> {_ts(b)}\n{text}\n")
    return "\n".join(out)


def _ts(ms: int) -> str:
    return f"{ms // 3600000:02d}:{ms // 60000 % 60:02d}:{ms // 1000 % 60:02d},{ms % 1000:03d}"


# -- DJI SRT variants ------------------------------------------------------------------


def test_phantom4pro_one_hertz_lon_lat_order(tmp_path):
    text = srt(
        "F/3.2, SS 160, ISO 100, EV 0, GPS (8.2090, 47.4692, 18), D 49.21m, H 45.60m, "
        "H.S 0.00m/s, V.S 0.00m/s",
        "F/3.2, SS 160, ISO 100, EV 0, GPS (8.2091, 47.4693, 18), D 50.01m, H 45.80m, "
        "H.S 4.20m/s, V.S 0.00m/s",
        step_ms=1000,
    )
    log = read_flight_log(write(tmp_path, "DJI_0001.SRT", text))
    assert log.source_format == "dji_srt" and log.variant == "phantom"
    assert log.time_base == "video"
    np.testing.assert_allclose(log.t, [0.0, 1.0])
    np.testing.assert_allclose(log.lon, [8.2090, 8.2091])  # lon comes first
    np.testing.assert_allclose(log.lat, [47.4692, 47.4693])
    assert log.alt_ref == "takeoff"  # the third GPS value is a satellite count, not altitude
    np.testing.assert_allclose(log.alt, [45.60, 45.80])
    np.testing.assert_allclose(log.speed, [0.0, 4.2])
    assert log.meta["fnum"] == pytest.approx(3.2)
    assert log.datetime is None


def test_phantom4rtk_home_and_attitudes(tmp_path):
    text = srt(
        "F/5.6, SS 500, ISO 100, EV 0, GPS (139.7671, 35.6812, 19), D 12.1m, H 60.2m, "
        "H.S 5.0m/s, V.S 0.0m/s, HOME (139.7670, 35.6810, -57.98m), "
        "F.PRY (-2.1, 0.8, 91.5), G.PRY (-90.0, 0.0, 91.2)",
        "F/5.6, SS 500, ISO 100, EV 0, GPS (139.7672, 35.6812, 19), D 12.2m, H 60.3m, "
        "H.S 5.0m/s, V.S 0.0m/s, HOME (139.7670, 35.6810, -57.98m), "
        "F.PRY (-2.0, 0.7, 91.4), G.PRY (-89.9, 0.0, 91.1)",
    )
    log = read_flight_log(write(tmp_path, "rtk.srt", text))
    assert log.variant == "phantom4rtk"
    assert log.meta["home_lonlat"] == [139.7670, 35.6810]
    np.testing.assert_allclose(log.attitude["pitch"], [-2.1, -2.0])
    np.testing.assert_allclose(log.attitude["roll"], [0.8, 0.7])
    np.testing.assert_allclose(log.attitude["yaw"], [91.5, 91.4])
    np.testing.assert_allclose(log.attitude["gimbal_pitch"], [-90.0, -89.9])
    np.testing.assert_allclose(log.attitude["gimbal_yaw"], [91.2, 91.1])
    assert not any("radians" in w for w in log.warnings)


def test_mavic_pro_old_home_date_barometer(tmp_path):
    text = srt(
        "HOME(149.0251,-20.2532) 2017.08.05 14:11:51\nGPS(149.0251,-20.2533,16) BAROMETER:1.9",
        "HOME(149.0251,-20.2532) 2017.08.05 14:11:52\nGPS(149.0252,-20.2534,16) BAROMETER:2.4",
        step_ms=1000,
    )
    log = read_flight_log(write(tmp_path, "mavicpro.srt", text))
    assert log.variant == "mavic_pro"
    np.testing.assert_allclose(log.lon, [149.0251, 149.0252])
    np.testing.assert_allclose(log.lat, [-20.2533, -20.2534])
    np.testing.assert_allclose(log.alt, [1.9, 2.4])
    assert log.alt_ref == "takeoff"
    assert log.datetime_zone == "local"
    assert log.epoch == datetime(2017, 8, 5, 14, 11, 51)
    assert any("local time" in w for w in log.warnings)


def test_mavic_mini(tmp_path):
    text = srt("F/2.8, SS 30.15, ISO 260, EV -1.7, GPS (-121.7458, 48.0771, 17), D 12.3m, H 20.1m")
    log = read_flight_log(write(tmp_path, "mini.srt", text))
    assert log.lon[0] == pytest.approx(-121.7458) and log.lat[0] == pytest.approx(48.0771)
    assert log.alt[0] == pytest.approx(20.1)


def test_mavic2_misspelt_key_old_units_font_tags_crlf_bom(tmp_path):
    block = (
        '<font size="36">FrameCnt : {n}, DiffTime : 16ms\n'
        "2020-04-02 15:19:58,{ms:03d},764\n"
        "[iso : 100] [shutter : 1/100.0] [fnum : 280] [ev : 0] [ct : 5500] "
        "[color_md : default] [focal_len : 240] [latitude : 31.45{n}] "
        "[longtitude : 74.39{n}] [altitude: 213.98] </font>"
    )
    text = srt(*(block.format(n=n, ms=720 + 16 * n) for n in (1, 2, 3)), step_ms=16)
    text = "\ufeff" + text.replace("\n", "\r\n")
    log = read_flight_log(write(tmp_path, "mavic2.SRT", text))
    assert log.variant == "mavic2"
    np.testing.assert_allclose(log.lat, [31.451, 31.452, 31.453])
    np.testing.assert_allclose(log.lon, [74.391, 74.392, 74.393])
    np.testing.assert_allclose(log.alt, 213.98)
    assert log.alt_ref == "absolute"
    assert log.meta["fnum"] == pytest.approx(2.8)
    assert log.meta["focal_len_35mm"] == pytest.approx(24.0)
    assert log.datetime[0] == np.datetime64("2020-04-02T15:19:58.736764")
    assert any("longtitude" in w for w in log.warnings)
    assert any("tenths" in w for w in log.warnings)


def test_mavic2_without_altitude(tmp_path):
    text = srt(
        "FrameCnt : 1, DiffTime : 16ms\n2020-04-02 15:19:58,720,764\n"
        "[iso : 100] [latitude : 31.45] [longtitude : 74.39]"
    )
    log = read_flight_log(write(tmp_path, "noalt.srt", text))
    assert np.isnan(log.alt).all()
    assert any("no altitude" in w for w in log.warnings)
    assert log.interpolate(np.array([0.0]))["lat"][0] == pytest.approx(31.45)


def test_air2s_srtcnt(tmp_path):
    text = srt(
        '<font size="28">SrtCnt : 1, DiffTime : 33ms\n2021-06-12 10:21:40.123\n'
        "[iso : 100] [shutter : 1/640.0] [fnum : 2.8] [ev : 0] [ct : 5200] "
        "[color_md : default] [focal_len : 22.00] [latitude: 46.12345] "
        "[longitude: 7.12345] [altitude: 1532.2] </font>"
    )
    log = read_flight_log(write(tmp_path, "air2s.srt", text))
    assert log.variant == "air2"
    assert log.lat[0] == pytest.approx(46.12345) and log.lon[0] == pytest.approx(7.12345)
    assert log.alt[0] == pytest.approx(1532.2)
    assert log.datetime[0] == np.datetime64("2021-06-12T10:21:40.123")


def mavic3_block(n: int, lat: float = 35.12345, lon: float = 139.12345, extra: str = "") -> str:
    return (
        f'<font size="28">FrameCnt: {n}, DiffTime: 20ms\n'
        f"2021-12-25 12:27:52.{373 + 20 * n:03d}\n"
        "[iso: 100] [shutter: 1/500.0] [fnum: 3.2] [ev: 0] [focal_len: 24.00] "
        f"[latitude: {lat:.6f}] [longitude: {lon:.6f}] [rel_alt: 45.200 abs_alt: 112.401] "
        f"{extra}[ct: 5500] </font>"
    )


def test_mavic3_rel_and_abs_altitude(tmp_path):
    text = srt(*(mavic3_block(n) for n in range(1, 4)), step_ms=20)
    log = read_flight_log(write(tmp_path, "m3.srt", text))
    assert log.variant == "mavic3"
    np.testing.assert_allclose(log.t, [0.0, 0.02, 0.04])
    np.testing.assert_allclose(log.alt, 112.401)
    assert log.alt_ref == "absolute"
    np.testing.assert_allclose(log.rel_alt, 45.2)
    assert log.meta["focal_len_35mm"] == pytest.approx(24.0)


def test_gimbal_angles_in_radians_are_converted(tmp_path):
    extra = "[gb_yaw: 0.2147 gb_pitch: -1.5708 gb_roll: 0.0000] "
    text = srt(*(mavic3_block(n, extra=extra) for n in range(1, 4)), step_ms=20)
    log = read_flight_log(write(tmp_path, "rad.srt", text))
    np.testing.assert_allclose(log.attitude["gimbal_pitch"], -90.0, atol=1e-3)
    np.testing.assert_allclose(log.attitude["gimbal_yaw"], np.degrees(0.2147), atol=1e-3)
    assert any("radians" in w for w in log.warnings)
    forced = read_flight_log(write(tmp_path, "rad2.srt", text), angle_unit="deg")
    np.testing.assert_allclose(forced.attitude["gimbal_pitch"], -1.5708)


def test_gimbal_angles_in_degrees_stay(tmp_path):
    extra = "[gb_yaw: 12.3 gb_pitch: -90.0 gb_roll: 0.0] "
    text = srt(*(mavic3_block(n, extra=extra) for n in range(1, 4)), step_ms=20)
    log = read_flight_log(write(tmp_path, "deg.srt", text))
    np.testing.assert_allclose(log.attitude["gimbal_pitch"], -90.0)
    assert not any("radians" in w for w in log.warnings)


def test_aircraft_only_radians(tmp_path):
    blocks = [
        f"GPS (8.2090, 47.4692, 18), H 45.6m, F.PRY ({0.01 * n:.3f}, -0.02, {-1.2 + 0.4 * n:.3f})"
        for n in range(8)
    ]
    log = read_flight_log(write(tmp_path, "frad.srt", srt(*blocks)))
    np.testing.assert_allclose(log.attitude["yaw"][0], np.degrees(-1.2), atol=1e-6)


def test_matrice300_lat_lon_order_and_zero_altitude(tmp_path):
    text = srt(
        "GPS(36.6146,-6.1120,0.0M) BAROMETER:0.3M",
        "GPS(36.6147,-6.1121,0.0M) BAROMETER:0.5M",
    )
    log = read_flight_log(write(tmp_path, "m300.srt", text))
    assert log.variant == "matrice300"
    np.testing.assert_allclose(log.lat, [36.6146, 36.6147])  # lat first here
    np.testing.assert_allclose(log.lon, [-6.1120, -6.1121])
    assert log.alt_ref == "takeoff"
    np.testing.assert_allclose(log.alt, [0.3, 0.5])
    assert any("GPS altitude is 0" in w for w in log.warnings)


def test_matrice300_with_real_altitude(tmp_path):
    text = srt("GPS(36.6146,-6.1120,52.3M) BAROMETER:30.3M")
    log = read_flight_log(write(tmp_path, "m300b.srt", text))
    assert log.alt_ref == "absolute" and log.alt[0] == pytest.approx(52.3)
    assert log.rel_alt[0] == pytest.approx(30.3)


def test_swapped_order_is_detected(tmp_path):
    # A file that writes lat, lon in a lon-first tuple: "latitude" 139 cannot be.
    text = srt("GPS (35.6812, 139.7671, 19), H 60.2m", "GPS (35.6813, 139.7672, 19), H 60.2m")
    log = read_flight_log(write(tmp_path, "swap.srt", text))
    assert log.lat[0] == pytest.approx(35.6812) and log.lon[0] == pytest.approx(139.7671)
    assert any("swapped" in w for w in log.warnings)


def test_missing_fix_is_missing_not_null_island(tmp_path):
    blocks = [mavic3_block(1, 0.0, 0.0), mavic3_block(2, 0.0, 0.0), mavic3_block(3)]
    log = read_flight_log(write(tmp_path, "nofix.srt", srt(*blocks, step_ms=20)))
    assert np.isnan(log.lat[:2]).all() and log.valid.sum() == 1
    assert any("no GPS fix" in w for w in log.warnings)


def test_srt_without_any_fix_fails(tmp_path):
    blocks = [mavic3_block(n, 0.0, 0.0) for n in (1, 2)]
    with pytest.raises(InputError, match=r"nofix2\.srt: no record has a GPS position"):
        read_flight_log(write(tmp_path, "nofix2.srt", srt(*blocks, step_ms=20)))


def test_srt_bad_number_names_the_line(tmp_path):
    text = srt(mavic3_block(1), mavic3_block(2).replace("latitude: 35", "latitude: 3x5"))
    # One of two blocks left is too little to trust: refused, saying how much was readable.
    with pytest.raises(
        InputError, match=r"bad\.srt: only 1 of 2 blocks readable; line 11: latitude .3x5"
    ):
        read_flight_log(write(tmp_path, "bad.srt", text))


def test_srt_without_telemetry_fails(tmp_path):
    with pytest.raises(InputError, match="no telemetry"):
        read_flight_log(write(tmp_path, "plain.srt", srt("Hello", "world")))


def test_utf16_srt(tmp_path):
    text = srt("GPS (8.2090, 47.4692, 18), H 45.6m")
    log = read_flight_log(write(tmp_path, "u16.srt", "\ufeff" + text, encoding="utf-16-le"))
    assert log.lat[0] == pytest.approx(47.4692)


# -- CSV flavours --------------------------------------------------------------------------

AIRDATA_HEADER = (
    "time(millisecond),datetime(utc),latitude,longitude,height_above_takeoff(feet),"
    "altitude_above_seaLevel(feet),speed(mph),compass_heading(degrees),pitch(degrees),"
    "roll(degrees),isPhoto,isVideo,gimbal_heading(degrees),gimbal_pitch(degrees)"
)


def test_airdata_feet_and_whole_second_datetimes(tmp_path):
    rows = [
        "0,2023-05-04 14:41:26,47.4692,8.2090,0.0,1400.0,0.0,90.0,-1.0,0.5,0,0,90.0,-90.0",
        "400,2023-05-04 14:41:26,47.4693,8.2091,10.0,1410.0,10.0,91.0,-2.0,0.4,0,1,91.0,-89.0",
        "800,2023-05-04 14:41:27,47.4694,8.2092,20.0,1420.0,20.0,92.0,-3.0,0.3,0,1,92.0,-88.0",
        "1200,2023-05-04 14:41:27,47.4695,8.2093,30.0,1430.0,22.0,93.0,-3.0,0.2,0,0,93.0,-88.0",
    ]
    log = read_flight_log(write(tmp_path, "airdata.csv", "\n".join([AIRDATA_HEADER, *rows])))
    assert log.source_format == "airdata_csv"
    np.testing.assert_allclose(log.t, [0, 0.4, 0.8, 1.2])
    np.testing.assert_allclose(log.alt, np.array([1400, 1410, 1420, 1430]) * 0.3048)
    np.testing.assert_allclose(log.rel_alt[1], 10 * 0.3048)
    np.testing.assert_allclose(log.speed[1], 10 * 0.44704)
    assert log.alt_ref == "absolute"
    np.testing.assert_allclose(log.attitude["yaw"], [90, 91, 92, 93])
    np.testing.assert_allclose(log.attitude["gimbal_pitch"], [-90, -89, -88, -88])
    assert log.datetime_zone == "UTC"
    # 14:41:27 is reached between t=0.4 and t=0.8: the epoch is bounded to (26.2, 26.6].
    assert log.utc_epoch == datetime(2023, 5, 4, 14, 41, 26, 200000)
    assert log.recording_segments() == [(0.4, 1.2)]


def test_airdata_metric_units(tmp_path):
    header = AIRDATA_HEADER.replace("(feet)", "(meters)").replace("(mph)", "(m/s)")
    row = "0,2023-05-04 14:41:26,47.4692,8.2090,12.5,412.0,3.0,90.0,-1.0,0.5,0,0,90.0,-90.0"
    log = read_flight_log(write(tmp_path, "airdata_m.csv", f"{header}\n{row}\n"))
    assert log.alt[0] == pytest.approx(412.0) and log.speed[0] == pytest.approx(3.0)


def test_phantomhelp_local_time_and_brackets(tmp_path):
    header = (
        "CUSTOM.updateTime [local],OSD.latitude,OSD.longitude,OSD.height [m],OSD.pitch,"
        "OSD.roll,OSD.yaw,GIMBAL.pitch,GIMBAL.yaw,CAMERA.isVideo"
    )
    rows = [
        "2023/05/04 16:41:26.100,47.4692,8.2090,30.1,-1.0,0.5,45.0,-90.0,45.0,True",
        "2023/05/04 16:41:26.200,47.4693,8.2091,30.2,-1.1,0.6,45.5,-90.0,45.5,True",
        "2023/05/04 16:41:26.300,0.0,0.0,30.3,-1.2,0.7,46.0,-90.0,46.0,False",
    ]
    log = read_flight_log(write(tmp_path, "phantomhelp.csv", "\n".join([header, *rows])))
    assert log.source_format == "phantomhelp_csv"
    np.testing.assert_allclose(log.t, [0, 0.1, 0.2], atol=1e-9)
    assert log.datetime_zone == "local"
    assert log.alt_ref == "takeoff" and log.alt[1] == pytest.approx(30.2)
    assert log.valid.tolist() == [True, True, False]
    np.testing.assert_allclose(log.attitude["gimbal_yaw"], [45.0, 45.5, 46.0])
    assert log.epoch == datetime(2023, 5, 4, 16, 41, 26, 100000)


def test_phantomhelp_feet_semicolons_and_sep_line(tmp_path):
    text = (
        "sep=;\nCUSTOM.updateTime;OSD.latitude;OSD.longitude;OSD.height [ft];OSD.altitude [ft]\n"
        "2023/05/04 16:41:26.100;47.4692;8.2090;100;1500\n"
    )
    log = read_flight_log(write(tmp_path, "ph2.csv", text))
    assert log.alt[0] == pytest.approx(1500 * 0.3048) and log.alt_ref == "absolute"


def test_litchi_raw_gimbal_tenths(tmp_path):
    header = (
        "latitude,longitude,altitude(m),speed(mps),pitch(deg),roll(deg),yaw(deg),"
        "gimbalPitchRaw,gimbalYawRaw,isTakingVideo,datetime(utc)"
    )
    rows = [
        "47.4692,8.2090,40.0,5.0,-3.0,0.1,170.0,-900,1700,1,2023-05-04 14:41:26.100",
        "47.4693,8.2091,40.5,5.1,-3.1,0.2,171.0,-895,1710,1,2023-05-04 14:41:26.200",
    ]
    log = read_flight_log(write(tmp_path, "litchi.csv", "\n".join([header, *rows])))
    assert log.source_format == "litchi_csv"
    assert log.alt_ref == "takeoff"
    np.testing.assert_allclose(log.attitude["gimbal_pitch"], [-90.0, -89.5])
    np.testing.assert_allclose(log.attitude["gimbal_yaw"], [170.0, 171.0])
    np.testing.assert_allclose(log.t, [0.0, 0.1], atol=1e-9)
    assert log.datetime_zone == "UTC"


def test_generic_iso_with_offset_is_utc(tmp_path):
    text = (
        "time,lat,lon,alt,yaw,gimbal_pitch\n"
        "2024-05-01T12:00:00.000+02:00,47.0,8.0,500.0,10,-90\n"
        "2024-05-01T12:00:00.500+02:00,47.00001,8.0,500.5,10,-90\n"
    )
    log = read_flight_log(write(tmp_path, "generic.csv", text))
    assert log.source_format == "generic_csv"
    assert log.utc_epoch == datetime(2024, 5, 1, 10, 0, 0)
    np.testing.assert_allclose(log.t, [0.0, 0.5])
    assert log.alt_ref == "absolute"


def test_generic_seconds_and_bad_value_line(tmp_path):
    good = "time,lat,lon,alt\n0.0,47.0,8.0,500\n0.5,47.00001,8.0,501\n"
    log = read_flight_log(write(tmp_path, "g.csv", good))
    assert log.datetime is None and log.t[-1] == 0.5
    bad = good + "1.0,47.0x,8.0,502\n"
    log = read_flight_log(write(tmp_path, "g2.csv", bad))  # 2 of 3 rows: kept, warned
    assert len(log) == 2
    assert any("line 4: lat '47.0x' is not a number" in w for w in log.warnings)
    worse = bad + "1.5,x,8.0,502\n2.0,47.0,8.0,5y\n"  # 2 of 5: under half, refused
    with pytest.raises(InputError, match=r"g3\.csv: only 2 of 5 rows readable; line 4: lat"):
        read_flight_log(write(tmp_path, "g3.csv", worse))


def test_generic_without_time_column(tmp_path):
    with pytest.raises(InputError, match="no 'time' column"):
        read_flight_log(write(tmp_path, "g3.csv", "lat,lon,alt\n47,8,500\n"))


def test_unsorted_and_duplicate_rows(tmp_path):
    text = "time,lat,lon,alt\n1.0,47.1,8,1\n0.0,47.0,8,1\n1.0,47.2,8,1\n2.0,47.3,8,1\n"
    log = read_flight_log(write(tmp_path, "u.csv", text))
    np.testing.assert_allclose(log.t, [0, 1, 2])
    np.testing.assert_allclose(log.lat, [47.0, 47.1, 47.3])
    assert any("sorted" in w for w in log.warnings)
    assert any("repeat" in w for w in log.warnings)


# -- unusable inputs ---------------------------------------------------------------------


def test_encrypted_dji_txt_says_export_csv(tmp_path):
    path = tmp_path / "DJIFlightRecord_2023-05-04_[14-41-26].txt"
    path.write_bytes(bytes([0x0D, 0x00, 0x5A, 0x00]) + bytes(range(256)) * 8)
    with pytest.raises(InputError, match=r"encrypted.*CSV"):
        read_flight_log(path)


def test_empty_log(tmp_path):
    with pytest.raises(InputError, match=r"empty\.srt: the flight log is empty"):
        read_flight_log(write(tmp_path, "empty.srt", "  \n"))


def test_header_only_csv(tmp_path):
    with pytest.raises(InputError, match="header but no rows"):
        read_flight_log(write(tmp_path, "h.csv", "time,lat,lon,alt\n"))


def test_unknown_text(tmp_path):
    with pytest.raises(InputError, match="not a flight log"):
        read_flight_log(write(tmp_path, "notes.txt", "hello\nworld\n"))


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_flight_log(tmp_path / "nope.srt")


def test_interpolation_on_the_circle(tmp_path):
    text = "time,lat,lon,alt,yaw\n0,47,8,1,179\n1,47.001,8,2,-179\n"
    log = read_flight_log(write(tmp_path, "c.csv", text))
    values = log.interpolate(np.array([0.5, 5.0]))
    assert abs(abs(values["yaw"][0]) - 180.0) < 1e-6
    assert values["lat"][0] == pytest.approx(47.0005)
    assert np.isnan(values["lat"][1])
