"""Image-set mode: JPEGs with EXIF GPS and DJI XMP tags readable by exifread."""

import csv
import re
from datetime import datetime

import exifread
import numpy as np
import pytest
from simtest_support import image_run


def _deg(tag) -> float:
    d, m, s = (float(v.num) / float(v.den) for v in tag.values)
    return d + m / 60.0 + s / 3600.0


@pytest.fixture(scope="module")
def run():
    return image_run()


def test_image_set_files_and_truth_table(run):
    s = run.survey(1)
    assert "video" not in s and "srt" not in s
    files = sorted((run.root / s["images_dir"]).glob("DJI_*.JPG"))
    assert len(files) == s["images"] >= 20
    with open(run.root / s["images_csv"], newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["image"] for r in rows] == [f.name for f in files]


def test_exif_and_xmp_tags(run):
    s = run.survey(1)
    with open(run.root / s["images_csv"], newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    img_dir = run.root / s["images_dir"]
    start = datetime.fromisoformat(s["start_local"])
    for row in rows[:: max(1, len(rows) // 6)]:
        with open(img_dir / row["image"], "rb") as fh:
            tags = exifread.process_file(fh, details=True, debug=True)
        assert str(tags["Image Make"]) == "DJI"
        assert str(tags["Image Model"]) == "FC6310"
        assert str(tags["EXIF ExifImageWidth"]) == "456"
        assert str(tags["EXIF ExifImageLength"]) == "304"
        fl = tags["EXIF FocalLength"].values[0]
        assert float(fl.num) / float(fl.den) == pytest.approx(8.8)
        assert str(tags["EXIF FocalLengthIn35mmFilm"]) == "24"
        assert str(tags["GPS GPSLatitudeRef"]) == "N"
        assert str(tags["GPS GPSLongitudeRef"]) == "E"
        # No GNSS error in this run: the tags hold the true camera position.
        assert _deg(tags["GPS GPSLatitude"]) == pytest.approx(float(row["lat"]), abs=2e-7)
        assert _deg(tags["GPS GPSLongitude"]) == pytest.approx(float(row["lon"]), abs=2e-7)
        alt = tags["GPS GPSAltitude"].values[0]
        assert float(alt.num) / float(alt.den) == pytest.approx(float(row["alt"]), abs=2e-3)
        taken = datetime.strptime(
            f"{tags['EXIF DateTimeOriginal']}.{tags['EXIF SubSecTimeOriginal']}",
            "%Y:%m:%d %H:%M:%S.%f",
        )
        assert abs((taken - start).total_seconds() - float(row["t_s"])) < 2e-3
        xmp = str(tags["Image ApplicationNotes"])
        fields = dict(re.findall(r'drone-dji:(\w+)="([^"]*)"', xmp))
        assert fields["GimbalPitchDegree"].startswith("-")
        assert float(fields["GimbalPitchDegree"]) == pytest.approx(-90.0, abs=0.5)
        yaw_err = (float(fields["GimbalYawDegree"]) - float(row["camera_yaw_deg"]) + 180) % 360
        assert abs(yaw_err - 180) < 8.0  # compass bias and noise
        assert float(fields["RelativeAltitude"]) == pytest.approx(7.0, abs=0.05)
        assert float(fields["AbsoluteAltitude"]) == pytest.approx(float(row["alt"]), abs=0.01)
        for key in ("GimbalRollDegree", "FlightYawDegree", "FlightPitchDegree", "FlightRollDegree"):
            assert re.fullmatch(r"[+-]\d+\.\d\d", fields[key]), key


def test_images_overlap_as_planned(run):
    s = run.survey(1)
    with open(run.root / s["images_csv"], newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    xy = np.array([[float(r["x_local"]), float(r["y_local"])] for r in rows])
    steps = np.hypot(*np.diff(xy, axis=0).T)
    # Spacing along the track is (1 - overlap) x footprint, less in turns.
    assert np.median(steps) == pytest.approx(s["image_spacing_m"], rel=0.1)
