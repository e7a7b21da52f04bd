"""Images (EXIF/XMP), camera intrinsics, video decoding and the video-log time offset."""

import io
import struct
from datetime import datetime
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np
import piexif
import pytest

from worker.pipeline.errors import InputError
from worker.pipeline.ingest.camera import (
    SENSOR_FORMATS,
    CameraOverride,
    Intrinsics,
    focal_plane_sensor_width_mm,
    lookup_camera,
    resolve_intrinsics,
)
from worker.pipeline.ingest.flight_log import build_flight_log
from worker.pipeline.ingest.images import read_image_metadata, read_image_set
from worker.pipeline.ingest.read_log import read_flight_log
from worker.pipeline.ingest.time_offset import (
    check_overlap,
    estimate_time_offset,
    prior_offset,
)
from worker.pipeline.ingest.video import VideoReader, probe_video

# -- images -------------------------------------------------------------------------------


def _rat(x: float, den: int = 10000) -> tuple[int, int]:
    return (round(x * den), den)


def _dms(value: float) -> tuple:
    value = abs(value)
    d = int(value)
    m = int((value - d) * 60)
    s = (value - d - m / 60) * 3600
    return ((d, 1), (m, 1), _rat(s, 100000))


def make_jpeg(
    path: Path,
    lat: float | None = 47.4692,
    lon: float | None = -8.2090,
    alt: float = 512.3,
    when: str = "2023:05:04 14:41:26",
    subsec: str = "25",
    model: str = "FC6310",
    xmp: str | None = None,
    size: tuple[int, int] = (96, 64),
    make: str = "DJI",
    camera_exif: dict[int, object] | None = None,
) -> Path:
    """A small JPEG with EXIF; `camera_exif` replaces the lens tags (FocalLength 8.8 mm,
    FocalLengthIn35mmFilm 24) of a DJI camera."""
    rng = np.random.default_rng(0)
    image = (rng.random((size[1], size[0], 3)) * 255).astype(np.uint8)
    ok, jpeg = cv2.imencode(".jpg", image)
    assert ok
    exif = {
        "0th": {piexif.ImageIFD.Make: make.encode(), piexif.ImageIFD.Model: model.encode()},
        "Exif": {
            piexif.ExifIFD.DateTimeOriginal: when.encode(),
            piexif.ExifIFD.SubSecTimeOriginal: subsec.encode(),
            **(
                camera_exif
                if camera_exif is not None
                else {
                    piexif.ExifIFD.FocalLength: (880, 100),
                    piexif.ExifIFD.FocalLengthIn35mmFilm: 24,
                }
            ),
        },
        "GPS": {},
    }
    if lat is not None and lon is not None:
        exif["GPS"] = {
            piexif.GPSIFD.GPSLatitudeRef: b"N" if lat >= 0 else b"S",
            piexif.GPSIFD.GPSLatitude: _dms(lat),
            piexif.GPSIFD.GPSLongitudeRef: b"E" if lon >= 0 else b"W",
            piexif.GPSIFD.GPSLongitude: _dms(lon),
            piexif.GPSIFD.GPSAltitudeRef: 0,
            piexif.GPSIFD.GPSAltitude: _rat(alt, 1000),
        }
    out = io.BytesIO()
    piexif.insert(piexif.dump(exif), jpeg.tobytes(), out)
    data = out.getvalue()
    if xmp is not None:
        packet = b"http://ns.adobe.com/xap/1.0/\x00" + xmp.encode()
        segment = b"\xff\xe1" + struct.pack(">H", len(packet) + 2) + packet
        data = data[:2] + segment + data[2:]
    path.write_bytes(data)
    return path


XMP_ATTRS = (
    '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF><rdf:Description '
    'drone-dji:AbsoluteAltitude="+512.30" drone-dji:RelativeAltitude="+60.10" '
    'drone-dji:GimbalRollDegree="+0.00" drone-dji:GimbalYawDegree="+87.50" '
    'drone-dji:GimbalPitchDegree="-89.90" drone-dji:FlightRollDegree="+1.20" '
    'drone-dji:FlightYawDegree="+88.10" drone-dji:FlightPitchDegree="-3.40" '
    'drone-dji:RtkStdLon="0.012" drone-dji:RtkStdLat="0.011" drone-dji:RtkStdHgt="0.025"/>'
    "</rdf:RDF></x:xmpmeta>"
)
XMP_ELEMENTS = (
    '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF><rdf:Description>'
    "<drone-dji:GimbalPitchDegree>-90.0</drone-dji:GimbalPitchDegree>"
    "<drone-dji:GimbalYawDegree>-12.5</drone-dji:GimbalYawDegree>"
    "<drone-dji:GpsLatitude>35.5</drone-dji:GpsLatitude>"
    "<drone-dji:GpsLongtitude>139.25</drone-dji:GpsLongtitude>"
    "</rdf:Description></rdf:RDF></x:xmpmeta>"
)


def test_exif_gps_time_camera_and_xmp_attributes(tmp_path):
    meta = read_image_metadata(make_jpeg(tmp_path / "DJI_0001.JPG", xmp=XMP_ATTRS))
    assert (meta.width, meta.height) == (96, 64)
    assert meta.lat == pytest.approx(47.4692, abs=1e-7)
    assert meta.lon == pytest.approx(-8.2090, abs=1e-7)  # West
    assert meta.alt == pytest.approx(512.3)
    assert meta.datetime == datetime(2023, 5, 4, 14, 41, 26, 250000)
    assert meta.datetime_zone == "local"
    assert meta.model == "FC6310" and meta.focal_mm == pytest.approx(8.8)
    assert meta.focal_35mm == 24
    assert meta.xmp["gimbal_pitch"] == pytest.approx(-89.9)
    assert meta.xmp["gimbal_yaw"] == pytest.approx(87.5)
    assert meta.xmp["yaw"] == pytest.approx(88.1)
    assert meta.xmp["rel_alt"] == pytest.approx(60.1)
    assert meta.xmp["rtk_std_hgt"] == pytest.approx(0.025)


def test_xmp_child_elements_and_misspelt_longitude(tmp_path):
    path = make_jpeg(tmp_path / "a.jpg", lat=None, lon=None, xmp=XMP_ELEMENTS)
    meta = read_image_metadata(path)
    assert meta.lat == pytest.approx(35.5) and meta.lon == pytest.approx(139.25)
    assert meta.xmp["gimbal_yaw"] == pytest.approx(-12.5)


def test_image_set_becomes_a_flight_log(tmp_path):
    for i in range(4):
        make_jpeg(
            tmp_path / f"DJI_{i:04d}.JPG",
            lat=47.0 + i * 1e-4,
            lon=8.0,
            when=f"2023:05:04 14:41:{26 + 2 * i:02d}",
            xmp=XMP_ATTRS,
        )
    image_set = read_image_set(tmp_path)
    log = image_set.log
    assert len(image_set.images) == 4 and log.source_format == "image_exif"
    np.testing.assert_allclose(log.t, [0, 2, 4, 6])
    np.testing.assert_allclose(log.lat, 47.0 + np.arange(4) * 1e-4, atol=1e-7)
    assert log.alt_ref == "absolute"
    assert log.has_attitude("gimbal_pitch", "gimbal_yaw")


def test_images_without_gps_fail_clearly(tmp_path):
    for i in range(3):
        make_jpeg(tmp_path / f"IMG_{i}.jpg", lat=None, lon=None)
    with pytest.raises(InputError, match=r"3 of 3 images have no GPS.*IMG_0\.jpg"):
        read_image_set(tmp_path)


def test_some_images_without_gps_warn(tmp_path):
    for i in range(4):
        make_jpeg(tmp_path / f"IMG_{i}.jpg", when=f"2023:05:04 14:41:{20 + i:02d}")
    make_jpeg(tmp_path / "IMG_9.jpg", lat=None, lon=None, when="2023:05:04 14:41:59")
    image_set = read_image_set(tmp_path)
    assert len(image_set.log) == 4 and len(image_set.images) == 5
    assert any("IMG_9.jpg" in w for w in image_set.warnings)


def test_not_a_jpeg_and_empty_folder(tmp_path):
    (tmp_path / "x.jpg").write_bytes(b"not a jpeg at all")
    with pytest.raises(InputError, match=r"x\.jpg: not a JPEG"):
        read_image_metadata(tmp_path / "x.jpg")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="no JPEG images"):
        read_image_set(empty)


# -- camera -------------------------------------------------------------------------------


def test_intrinsics_from_table_exif_override_and_default():
    table = resolve_intrinsics(5472, 3648, exif_model="FC6310", exif_focal_mm=8.8)
    assert table.fx == pytest.approx(8.8 / 13.2 * 5472)
    assert table.source.startswith("table: Phantom 4 Pro")
    video = table.scaled(640, 360)
    assert video.fx == pytest.approx(8.8 / 13.2 * 640)
    assert video.cx == pytest.approx(319.5) and video.cy == pytest.approx(179.5)
    by_35 = resolve_intrinsics(1920, 1080, focal_35mm=24.0)
    assert by_35.fx == pytest.approx(24 / 36 * 1920)
    override = resolve_intrinsics(640, 360, override=CameraOverride(fx=1000.0, width=1280))
    assert override.fx == pytest.approx(500.0) and override.source == "override: fx"
    hfov = resolve_intrinsics(640, 360, override=CameraOverride(hfov_deg=90.0))
    assert hfov.fx == pytest.approx(320.0)
    named = resolve_intrinsics(640, 360, override=CameraOverride(model="mavic3"))
    assert named.fx == pytest.approx(12.29 / 17.3 * 640)
    default = resolve_intrinsics(640, 360)
    assert default.warnings and default.fx == pytest.approx(8.8 / 13.2 * 640)
    with pytest.raises(InputError, match="not in the table"):
        resolve_intrinsics(640, 360, override=CameraOverride(model="bogus-cam"))
    for model in ("FC6310R", "L1D-20c", "L2D-20c", "FC3582", "FC8482", "FC3411", "ZH20"):
        assert lookup_camera(model) is not None, model


def _intrinsics_of(path: Path) -> Intrinsics:
    """What ingest does with a photo: its EXIF into `resolve_intrinsics`."""
    meta = read_image_metadata(path)
    return resolve_intrinsics(
        meta.width,
        meta.height,
        exif_model=meta.model,
        exif_focal_mm=meta.focal_mm,
        focal_35mm=meta.focal_35mm,
        exif_sensor_width_mm=meta.sensor_width_mm,
    )


FOCAL = piexif.ExifIFD.FocalLength
FOCAL_35 = piexif.ExifIFD.FocalLengthIn35mmFilm


def test_consumer_camera_by_model_and_focal_length(tmp_path):
    """Issue 17: a compact with GPS writes Model and FocalLength, no 35 mm equivalent."""
    path = make_jpeg(
        tmp_path / "IMG_0001.JPG",
        make="Canon",
        model="Canon PowerShot SX260 HS",
        size=(400, 300),
        camera_exif={FOCAL: (45, 10)},
    )
    intr = _intrinsics_of(path)
    assert intr.fx == pytest.approx(4.5 / 6.17 * 400, rel=0.01)
    assert intr.fy == intr.fx and not intr.focal_guess and not intr.warnings
    assert intr.source == (
        'table: Canon PowerShot SX260 HS: 1/2.3" sensor 6.17 mm wide from the camera '
        "table, focal 4.5 mm from EXIF: fx = 292 px"
    )
    # The same camera zoomed in: the focal length follows EXIF, the sensor the table.
    zoomed = resolve_intrinsics(
        4000, 3000, exif_model="Canon PowerShot SX260 HS", exif_focal_mm=9.0
    )
    assert zoomed.fx == pytest.approx(9.0 / 6.17 * 4000, rel=0.01)
    assert lookup_camera("DSC-RX100M3").sensor_width_mm == SENSOR_FORMATS['1"']


def test_only_the_35mm_equivalent(tmp_path):
    path = make_jpeg(
        tmp_path / "a.jpg",
        make="Acme",
        model="Acme Cam 1",
        size=(400, 300),
        camera_exif={FOCAL_35: 28},
    )
    intr = _intrinsics_of(path)
    assert intr.fx == pytest.approx(28 / 36 * 400, rel=0.01) and not intr.focal_guess
    assert intr.source.startswith("35 mm equivalent focal length 28 mm of Acme Cam 1")
    assert "fx = 28 / 36 * 400 = 311 px" in intr.source


def test_focal_plane_resolution(tmp_path):
    """A camera not in the table that writes its own pixel pitch: 4000 px over a
    6.17 mm sensor, in pixels per inch; the JPEG was resized to 400 px afterwards."""
    ppi = 4000 / 6.17 * 25.4
    path = make_jpeg(
        tmp_path / "a.jpg",
        make="Acme",
        model="Acme Cam 2",
        size=(400, 300),
        camera_exif={
            FOCAL: (50, 10),
            piexif.ExifIFD.FocalPlaneXResolution: (round(ppi * 1000), 1000),
            piexif.ExifIFD.FocalPlaneResolutionUnit: 2,
            piexif.ExifIFD.PixelXDimension: 4000,
        },
    )
    meta = read_image_metadata(path)
    assert meta.sensor_width_mm == pytest.approx(6.17, rel=1e-4)
    intr = _intrinsics_of(path)
    assert intr.fx == pytest.approx(5.0 / 6.17 * 400, rel=0.01) and not intr.focal_guess
    assert intr.source.startswith("focal plane: Acme Cam 2: sensor 6.17 mm wide from EXIF")
    # Centimetres, no PixelXDimension (the JPEG's own width is meant).
    assert focal_plane_sensor_width_mm(400 / 0.617, 3, 400) == pytest.approx(6.17)
    # A value implying an impossible sensor is ignored, with a warning.
    odd = resolve_intrinsics(
        400, 300, exif_model="Acme Cam 2", exif_focal_mm=5.0, exif_sensor_width_mm=0.3
    )
    assert odd.focal_guess and "0.3 mm wide sensor" in odd.warnings[0]


def test_unknown_camera_is_a_guess_that_sfm_refines(tmp_path):
    path = make_jpeg(
        tmp_path / "a.jpg",
        make="Acme",
        model="Mystery 9",
        size=(400, 300),
        camera_exif={FOCAL: (45, 10)},
    )
    intr = _intrinsics_of(path)
    assert intr.focal_guess and intr.source.startswith("guess: ")
    assert intr.fx == pytest.approx(8.8 / 13.2 * 400, rel=0.01)
    (warning,) = intr.warnings
    assert "'Mystery 9' is not in the camera table" in warning
    assert "focal length (4.5 mm)" in warning and "no EXIF camera model" not in warning
    bare = resolve_intrinsics(400, 300)
    assert bare.focal_guess and "no EXIF camera model, no focal length" in bare.warnings[0]
    # The flag travels through ingest.json and the stills' rescaling to SfM.
    again = Intrinsics.from_dict(intr.to_dict()).scaled(200, 150)
    assert again.focal_guess and again.fx == pytest.approx(intr.fx / 2)


def test_dji_camera_from_the_table(tmp_path):
    path = make_jpeg(tmp_path / "DJI_0001.JPG", model="FC6310", size=(400, 300))
    intr = _intrinsics_of(path)
    assert intr.fx == pytest.approx(8.8 / 13.2 * 400, rel=0.01) and not intr.focal_guess
    assert intr.source == (
        'table: Phantom 4 Pro / Pro V2: 1" sensor 13.2 mm wide from the camera table, '
        "focal 8.8 mm from EXIF: fx = 267 px"
    )
    mavic3 = resolve_intrinsics(5280, 3956, exif_model="M3E")
    assert mavic3.fx == pytest.approx(12.29 / 17.3 * 5280, rel=0.01)
    assert "focal 12.29 mm from the camera table (none in EXIF)" in mavic3.source


# -- video --------------------------------------------------------------------------------


def make_video(
    path: Path, codec: str = "libx264", frames: int = 30, fps: int = 30, pix_fmt: str = "yuv420p"
) -> Path:
    container = av.open(str(path), "w")
    stream = container.add_stream(codec, rate=fps)
    stream.width, stream.height, stream.pix_fmt = 320, 240, pix_fmt
    if codec == "libx265":
        stream.options = {"x265-params": "log-level=error"}
    rng = np.random.default_rng(1)
    base = (rng.random((240, 320 + 4 * frames, 3)) * 255).astype(np.uint8)
    for i in range(frames):
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(base[:, 4 * i : 4 * i + 320]))
        for packet in stream.encode(frame):
            container.mux(packet)
    for packet in stream.encode():
        container.mux(packet)
    container.close()
    return path


@pytest.mark.parametrize(("codec", "name"), [("libx264", "clip.mp4"), ("libx265", "clip.mov")])
def test_video_frames_with_presentation_times(tmp_path, codec, name):
    path = make_video(tmp_path / name, codec=codec, frames=15)
    info = probe_video(path)
    assert (info.width, info.height) == (320, 240) and info.fps == pytest.approx(30)
    assert info.codec == ("h264" if codec == "libx264" else "hevc")
    reader = VideoReader(path)
    frames = list(reader.frames(size=(160, 120), every=2))
    assert [f.index for f in frames] == list(range(0, 15, 2))
    np.testing.assert_allclose([f.t for f in frames], np.arange(0, 15, 2) / 30, atol=1e-6)
    assert frames[0].image.shape == (120, 160) and frames[0].image.dtype == np.uint8
    assert not reader.warnings


@pytest.mark.parametrize(
    ("pix_fmt", "size"),
    [("yuv420p", (160, 120)), ("yuv420p", None), ("yuvj420p", (160, 120)), ("yuv444p", None)],
)
def test_grey_frames_match_the_ffmpeg_scaler(tmp_path, pix_fmt, size):
    """Grey frames come from the luma plane: FFmpeg's grey (range expansion of limited-range
    video, area averaging) to within one level."""
    path = make_video(tmp_path / "clip.mp4", frames=6, pix_fmt=pix_fmt)
    width, height = size or (None, None)
    container = av.open(str(path))
    expected = [
        f.reformat(width=width, height=height, format="gray", interpolation="AREA").to_ndarray()
        for f in container.decode(video=0)
    ]
    container.close()
    frames = list(VideoReader(path).frames(size=size))
    assert len(frames) == len(expected) == 6
    for frame, want in zip(frames, expected, strict=True):
        assert frame.image.shape == want.shape and frame.image.flags.c_contiguous
        diff = np.abs(frame.image.astype(int) - want)
        assert diff.max() <= 1 and diff.mean() < 0.5
        if size is None:
            assert diff.max() == 0  # no resizing: the same look-up as FFmpeg


def test_corrupt_and_missing_video(tmp_path):
    good = make_video(tmp_path / "good.mp4").read_bytes()
    (tmp_path / "half.mp4").write_bytes(good[: len(good) // 2])
    with pytest.raises(InputError, match=r"half\.mp4: not a readable video"):
        probe_video(tmp_path / "half.mp4")
    (tmp_path / "junk.mov").write_bytes(b"\x00\x01junk" * 50)
    with pytest.raises(InputError, match=r"junk\.mov: not a readable video"):
        VideoReader(tmp_path / "junk.mov")
    (tmp_path / "empty.mp4").write_bytes(b"")
    with pytest.raises(InputError, match="empty"):
        probe_video(tmp_path / "empty.mp4")
    with pytest.raises(InputError, match="not found"):
        probe_video(tmp_path / "none.mp4")


def test_audio_only_file_has_no_video_stream(tmp_path):
    path = tmp_path / "sound.m4a"
    container = av.open(str(path), "w")
    stream = container.add_stream("aac", rate=8000)
    frame = av.AudioFrame.from_ndarray(
        np.zeros((1, 1024), np.float32), format="fltp", layout="mono"
    )
    frame.sample_rate = 8000
    frame.time_base = Fraction(1, 8000)
    for packet in [*stream.encode(frame), *stream.encode()]:
        container.mux(packet)
    container.close()
    with pytest.raises(InputError, match="no video stream"):
        probe_video(path)


# -- time offset --------------------------------------------------------------------------


def _speed_log(offset_s: float, duration: float = 120.0, rate: float = 10.0):
    """A log whose ground speed varies (accelerations at turns) and its image motion
    signal seen by a video starting `offset_s` into the log."""
    t = np.arange(0, duration, 1 / rate)
    # Stops and accelerations at irregular times (turns of a survey pattern).
    knots = np.random.default_rng(7).uniform(1.0, 9.0, int(duration / 4) + 2)
    speed = np.interp(t, np.arange(knots.size) * 4.0, knots)
    x = np.cumsum(speed) / rate
    lat = 47 + x / 111_195.0
    rows = [
        {"line": i + 2, "t": ti, "lat": la, "lon": 8.0, "alt": 500.0, "rel_alt": 60.0}
        for i, (ti, la) in enumerate(zip(t, lat, strict=True))
    ]
    log = build_flight_log("log.csv", "generic_csv", rows)
    video_t = np.arange(0, 60, 1 / 30)
    rng = np.random.default_rng(3)
    motion = np.interp(video_t + offset_s, t, speed) / 60.0 * 500 + rng.normal(0, 1, video_t.size)
    return log, video_t, motion


def test_offset_found_from_motion_within_a_tenth_of_a_second():
    log, video_t, motion = _speed_log(offset_s=23.4)
    prior = prior_offset(log)
    assert prior.prior_source == "log_start"
    found = estimate_time_offset(log, video_t, motion, prior)
    assert found.observable and found.method == "motion_correlation"
    assert found.offset_s == pytest.approx(23.4, abs=0.1)


def test_offset_prior_from_recording_flag_and_srt(tmp_path):
    text = "time,lat,lon,alt,recording\n" + "".join(
        f"{i * 0.5},{47 + i * 1e-5},8,500,{int(4 <= i < 14)}\n" for i in range(20)
    )
    log = read_flight_log(tmp_path.joinpath("r.csv").write_text(text) and tmp_path / "r.csv")
    prior = prior_offset(log, video_duration_s=5.0)
    assert prior.prior_source == "recording_flag" and prior.offset_s == pytest.approx(2.0)
    srt_log = build_flight_log("x.srt", "dji_srt", [{"line": 1, "t": 0.0, "lat": 1, "lon": 1}])
    srt_log.time_base = "video"
    assert prior_offset(srt_log).prior_source == "srt"


def test_offset_from_creation_time(tmp_path):
    text = "time,lat,lon,alt\n2024-05-01T10:00:00Z,47,8,500\n2024-05-01T10:05:00Z,47.01,8,500\n"
    log = read_flight_log(tmp_path.joinpath("c.csv").write_text(text) and tmp_path / "c.csv")
    prior = prior_offset(log, 60.0, "2024-05-01T10:01:30")
    assert prior.prior_source == "creation_time" and prior.offset_s == pytest.approx(90.0)


def test_constant_speed_keeps_the_prior():
    t = np.arange(0, 100, 0.1)
    rows = [{"line": i, "t": ti, "lat": 47 + ti * 5 / 111195, "lon": 8.0} for i, ti in enumerate(t)]
    log = build_flight_log("c.csv", "generic_csv", rows)
    video_t = np.arange(0, 30, 1 / 30)
    found = estimate_time_offset(log, video_t, np.full(video_t.size, 40.0), prior_offset(log))
    assert not found.observable and found.method == "prior"
    assert any("cannot be observed" in w for w in found.warnings)


def test_log_that_does_not_overlap_the_video():
    log, _, _ = _speed_log(0.0, duration=60.0)
    assert check_overlap(log, 10.0, 30.0) == pytest.approx(1.0)
    with pytest.raises(InputError, match="does not overlap the video in time"):
        check_overlap(log, 3600.0, 30.0, video_name="the video")
