"""The manifest describes every file; rasters carry a real CRS; videos are 30 fps CFR."""

import av
import numpy as np
import pytest
import rasterio
from simtest_support import short_run, truth_only_run

from worker.simulator.manifest import Manifest


@pytest.fixture(scope="module")
def run():
    return short_run()


def test_manifest_round_trips_and_names_existing_files(run):
    again = Manifest.load(run.root)
    assert again.data == run.data
    assert again.data["format"] == "slidewatch-sim/1"
    assert again.data["crs"] == "EPSG:32654"
    files = again.files()
    names = {p.name for p in files}
    for n in (
        "dsm.tif",
        "dem.tif",
        "ortho.tif",
        "mask.tif",
        "events.tif",
        "DJI_0001.MP4",
        "DJI_0001.SRT",
        "flight-airdata.csv",
        "trajectory.csv",
        "preview.png",
    ):
        assert n in names
    assert len(files) == 3 + 6 + 2 * 5 + 4  # truth, surveys, registration
    s = again.survey(2)
    for key in ("video", "srt", "flight_log_csv", "trajectory"):
        assert (again.root / s[key]).is_file()
    assert len(again.data["scene"]["checkpoints"]) == 3
    assert [m["name"] for m in again.data["scene"]["mounds"]] == ["A", "B"]


def test_truth_rasters_are_tiled_deflate_geotiffs_in_utm(run):
    g = run.data["grid"]
    for key, dtype, nodata in (
        ("dsm", "float32", -9999.0),
        ("mask", "uint8", 255),
        ("ortho", "uint8", None),
    ):
        with rasterio.open(run.truth(2, key)) as src:
            assert src.crs.to_epsg() == 32654
            assert src.dtypes[0] == dtype
            assert src.nodata == nodata
            assert src.profile["tiled"] and src.profile["compress"] == "deflate"
            assert (src.width, src.height) == (g["width"], g["height"])
            assert src.transform.a == g["res_m"] and src.transform.e == -g["res_m"]
            assert (src.transform.c, src.transform.f) == (g["west"], g["north"])
    # The scene lies where the manifest says: near Tsukuba, Japan.
    cp = run.data["scene"]["checkpoints"][0]
    assert 35.9 < cp["lat"] < 36.2 and 140.0 < cp["lon"] < 140.2
    with rasterio.open(run.truth(1, "dsm")) as src:
        r, c = src.index(cp["e"], cp["n"])
        assert src.read(1)[r, c] == pytest.approx(cp["u"], abs=0.02)


def test_video_is_constant_30_fps_with_the_manifest_frame_count(run):
    s = run.survey(1)
    with av.open(str(run.root / s["video"])) as c:
        st = c.streams.video[0]
        assert st.codec_context.name in ("h264", "mpeg4")
        assert (st.codec_context.width, st.codec_context.height) == (640, 360)
        assert float(st.average_rate) == 30.0
        pts = [f.pts * float(f.time_base) for f in c.decode(video=0)]
    assert len(pts) == s["frames"] == 91
    assert np.allclose(np.diff(pts), 1 / 30, atol=1e-4)


def test_truth_only_run_has_no_survey_files():
    m = truth_only_run(7)
    assert all(s["surveys"][0]["kind"] == "none" for s in m.steps)
    assert not any(p.suffix in (".MP4", ".SRT", ".csv") for p in m.files())
