"""End to end on a short simulated survey of the paper's mound field, through the CLI.

The simulator (worker.simulator) renders 6 s of 640x360 video at 15 fps from 7 m with a
DJI SRT, an AirData CSV (stand-alone GPS: a bias of metres, drift and noise; compass and
gimbal angles) and the truth (DSM, camera trajectory). Without ground control points no
method can see the flight's common GNSS bias, so the DSM is compared with the truth after
removing the mean difference between the estimated and the true camera positions.

Tolerances (2 cm DSM pixels, 1.6 cm ground sampling distance): NMAD of the measured
cells below 12 cm, median below 8 cm, completeness above 80 %; trajectory within 15 cm
after the bias; time offset within 0.05 s of the truth (the manifest's log start).
"""

import csv
import json
import shutil
from pathlib import Path

import av
import cv2
import numpy as np
import pytest
import rasterio
from affine import Affine
from click.testing import CliRunner
from rasterio.warp import Resampling, reproject
from rio_cogeo.cogeo import cog_validate

from worker.commands.reconstruct import reconstruct
from worker.pipeline.errors import InputError
from worker.pipeline.ingest.video import probe_video
from worker.pipeline.reconstruction import (
    STAGES,
    ReconstructionInputs,
    ReconstructionOptions,
    run_stage,
)
from worker.pipeline.reconstruction_results import (
    DsmStageResult,
    FramesResult,
    GeoreferenceResult,
    IngestResult,
    OrthophotoStageResult,
    ReconstructResult,
    plain,
)
from worker.pipeline.trajectory import read_trajectory_csv
from worker.simulator.orthophoto_truth import orthophoto_errors


@pytest.fixture(scope="session")
def survey(simulated_mounds_survey: tuple[Path, Path]) -> tuple[Path, Path]:
    return simulated_mounds_survey


def run_cli(*args: object) -> tuple[int, str]:
    result = CliRunner().invoke(reconstruct, [str(a) for a in args])
    return result.exit_code, result.output


@pytest.fixture(scope="session")
def slam_run(survey, tmp_path_factory) -> tuple[Path, dict]:
    flight, _ = survey
    out = tmp_path_factory.mktemp("slam")
    code, output = run_cli(
        "--video",
        flight / "DJI_0001.MP4",
        "--log",
        flight / "flight-airdata.csv",
        "--out",
        out,
        "--png",
    )
    assert code == 0, output
    return out, json.loads(output.strip().splitlines()[-1])


def bias_and_trajectory_error(out: Path, flight: Path) -> tuple[np.ndarray, np.ndarray]:
    traj = read_trajectory_csv(out / "trajectory.csv")
    with open(flight / "trajectory.csv", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    t = np.array([float(r["t_s"]) for r in rows])
    enu = np.array([[float(r[k]) for k in ("e", "n", "u")] for r in rows])
    truth = np.column_stack([np.interp(traj.t, t, enu[:, k]) for k in range(3)])
    err = traj.positions - truth
    bias = err.mean(axis=0)
    return bias, np.linalg.norm(err - bias, axis=1)


def dsm_error(out: Path, truth_dir: Path, bias: np.ndarray) -> tuple[np.ndarray, float]:
    with rasterio.open(out / "dsm.tif") as src:
        dsm = src.read(1, masked=True).filled(np.nan)
        transform, crs = src.transform, src.crs
    with rasterio.open(out / "dsm_filled.tif") as src:
        measured = src.read(1) == 0
    shifted = transform * Affine.translation(0, 0)
    shifted = Affine(transform.a, 0, transform.c - bias[0], 0, transform.e, transform.f - bias[1])
    truth = np.full(dsm.shape, np.nan, np.float32)
    with rasterio.open(truth_dir / "dsm.tif") as src:
        reproject(
            rasterio.band(src, 1),
            truth,
            dst_transform=shifted,
            dst_crs=crs,
            resampling=Resampling.average,
            dst_nodata=np.nan,
        )
    diff = dsm - bias[2] - truth
    ok = np.isfinite(diff) & measured
    return diff[ok], float(ok.sum())


def test_cli_writes_every_product(slam_run):
    out, summary = slam_run
    assert summary["method"] == "slam" and summary["crs"] == "EPSG:32654"
    for name in (
        "dsm.tif",
        "dsm_filled.tif",
        "dsm.png",
        "points.ply",
        "trajectory.csv",
        "trajectory.geojson",
        "report.json",
    ):
        assert (out / name).is_file(), name
    flight_path = json.loads((out / "trajectory.geojson").read_text())
    assert flight_path["geometry"]["type"] == "LineString"
    assert cog_validate(str(out / "dsm.tif"), quiet=True)[0]
    with rasterio.open(out / "dsm.tif") as src:
        assert src.crs.to_epsg() == 32654 and src.nodata == -9999
        assert abs(src.res[0] - 0.02) < 1e-9
    report = json.loads((out / "report.json").read_text())
    assert set(report["timings_s"]) == set(STAGES)
    assert report["residuals_m"][0]["rms_up"] < 1.0
    assert report["real_time_factor"] > 0
    assert read_trajectory_csv(out / "trajectory.csv").crs == "EPSG:32654"


RESULT_TYPES = {
    "ingest": IngestResult,
    "frames": FramesResult,
    "reconstruct": ReconstructResult,
    "georeference": GeoreferenceResult,
    "dsm": DsmStageResult,
    "orthophoto": OrthophotoStageResult,
}


def assert_stage_files_read_back(out: Path) -> None:
    """Every <stage>.json reads back typed and writes the same JSON, key for key."""
    assert set(RESULT_TYPES) == set(STAGES)
    for stage, kind in RESULT_TYPES.items():
        stored = json.loads((out / f"{stage}.json").read_text())
        written = json.loads(json.dumps(plain(kind.from_dict(stored).to_dict())))
        assert written == stored, stage
        assert list(written) == list(stored), stage


def test_stage_results_read_back_typed(slam_run):
    out, _ = slam_run
    assert_stage_files_read_back(out)
    assert IngestResult.from_dict(json.loads((out / "ingest.json").read_text())).video


def test_dsm_matches_the_truth_beyond_the_gnss_bias(slam_run, survey):
    out, summary = slam_run
    flight, truth_dir = survey
    bias, traj_err = bias_and_trajectory_error(out, flight)
    assert np.median(traj_err) < 0.15
    diff, _ = dsm_error(out, truth_dir, bias)
    median = float(np.median(diff))
    nmad = 1.4826 * float(np.median(np.abs(diff - median)))
    assert abs(median) < 0.08
    assert nmad < 0.12
    assert summary["completeness"] > 0.8


def test_time_offset_estimated_from_the_video(slam_run, survey):
    out, _ = slam_run
    flight, _ = survey
    manifest = json.loads((flight.parents[1] / "manifest.json").read_text())
    true_offset = -manifest["steps"][0]["surveys"][0]["flight_log_start_s"]
    frames = json.loads((out / "frames.json").read_text())
    geo = json.loads((out / "georeference.json").read_text())
    assert frames["time_offset"]["prior_source"] == "recording_flag"
    assert frames["time_offset_estimate"]["method"] == "motion_correlation"
    assert abs(frames["time_offset_estimate"]["offset_s"] - true_offset) < 0.15
    # Refined with the cameras in the world-frame adjustment (georef_world).
    assert geo["time_offset"]["method"] == "bundle_adjustment"
    assert abs(geo["time_offset"]["offset_s"] - true_offset) < 0.05


def test_a_flight_whose_tracking_held_keeps_its_dense_pairs(slam_run):
    """The georeference moves the cameras of a good flight little: hardly a pair is
    matched again, and the step says what it did."""
    out, _ = slam_run
    done = json.loads((out / "georeference.json").read_text())["redensified"]
    pairs = json.loads((out / "reconstruct.json").read_text())["stats"]["counts"]["dense_pairs"]
    assert pairs > 20
    assert done["pairs_matched_again"] <= 0.05 * pairs
    assert done["points_dropped"] >= 0 and done["seconds"] >= 0


def test_stages_are_idempotent(slam_run):
    out, _ = slam_run
    with rasterio.open(out / "dsm.tif") as src:
        before = src.read(1)
    result = run_stage("dsm", out, ReconstructionOptions())
    assert result == json.loads((out / "dsm.json").read_text())
    with rasterio.open(out / "dsm.tif") as src:
        np.testing.assert_array_equal(src.read(1), before)
    assert not list(out.glob(".*.part*"))


def test_spikes_above_the_cameras_do_not_blind_the_orthophoto(slam_run, tmp_path):
    """A DSM whose 0.5 % of cells are outliers far above the cameras (as one of issue
    18's flights had, 82 m under a flight at 32 m) still gets its orthophoto: the views'
    footprints are bounded by the DSM's bulk heights, not by its extremes."""
    out, _ = slam_run
    work = tmp_path / "work"
    shutil.copytree(out, work)
    with rasterio.open(work / "dsm.tif") as src:
        profile, heights = src.profile, src.read(1)
    cameras = -np.einsum(
        "nji,nj->ni", *(np.load(work / "georeference" / "map.npz")[k] for k in ("kf_r", "kf_tr"))
    )
    valid = heights != profile["nodata"]
    spikes = valid & (np.random.default_rng(8).random(heights.shape) < 0.005)
    heights[spikes] = cameras[:, 2].max() + 50.0
    with rasterio.open(work / "dsm.tif", "w", **profile) as dst:
        dst.write(heights, 1)
    result = run_stage("orthophoto", work, ReconstructionOptions())
    assert result["orthophoto"] is not None, result["warnings"]
    assert result["orthophoto"]["coverage"] > 0.9 and result["orthophoto"]["views"] >= 4


def test_the_orthophoto_needs_no_second_decoding_of_the_video(slam_run, tmp_path):
    """The orthophoto's views come from the frames stage's colour copy of the frames it
    stored: with the survey's video gone from where ingest read it, the orthophoto is
    made again, the same."""
    out, _ = slam_run
    work = tmp_path / "work"
    shutil.copytree(out, work)
    frames = json.loads((work / "frames.json").read_text())["frames"]
    ingest = json.loads((work / "ingest.json").read_text())
    video = probe_video(Path(ingest["inputs"]["video"]))
    # Twice the processing size, no larger than the video.
    width = min(2 * frames["width"], video.width)
    assert frames["colour_size"] == [width, width * frames["height"] // frames["width"]]
    ingest["inputs"]["video"] = str(tmp_path / "moved-away.MP4")
    (work / "ingest.json").write_text(json.dumps(ingest))
    result = run_stage("orthophoto", work, ReconstructionOptions())
    assert result["orthophoto"] is not None, result["warnings"]
    with rasterio.open(out / "orthophoto.tif") as a, rasterio.open(work / "orthophoto.tif") as b:
        np.testing.assert_array_equal(a.read(), b.read())


def run_sfm_cli(video: Path, log: Path, out: Path) -> dict:
    """`slidewatch reconstruct --method sfm`; its reconstruct stage's result."""
    code, output = run_cli("--video", video, "--log", log, "--out", out, "--method", "sfm")
    assert code == 0, output
    return json.loads((out / "reconstruct.json").read_text())


def test_sfm_reference_method(survey, tmp_path):
    flight, _ = survey
    rec = run_sfm_cli(flight / "DJI_0001.MP4", flight / "DJI_0001.SRT", tmp_path)
    assert rec["method"] == "sfm" and rec["sfm"]["registered"] >= 8
    assert (tmp_path / "dsm.tif").is_file()
    assert_stage_files_read_back(tmp_path)


def test_sfm_keeps_a_guessed_focal_length(survey, tmp_path):
    """The AirData log names no camera, so the focal length is a guess (the right one
    here), which a drone survey cannot correct (it trades against the ground's depth):
    it is kept, and the report says so."""
    flight, _ = survey
    rec = run_sfm_cli(flight / "DJI_0001.MP4", flight / "flight-airdata.csv", tmp_path)
    assert not rec["sfm"]["focal_refined"]
    assert rec["sfm"]["fx"] == pytest.approx(640 * 8.8 / 13.2, abs=0.01)
    report = json.loads((tmp_path / "report.json").read_text())
    kept = [w for w in report["warnings"] if w.startswith("SfM kept the guessed focal length")]
    assert len(kept) == 1 and "give the camera" in kept[0]


def test_a_time_offset_given_by_the_user_is_kept(survey, tmp_path):
    flight, _ = survey
    inputs = ReconstructionInputs(
        video=str(flight / "DJI_0001.MP4"), log=str(flight / "flight-airdata.csv")
    )
    result = run_stage("ingest", tmp_path, ReconstructionOptions(time_offset_s=0.25), inputs)
    prior = result["time_offset_prior"]
    assert (prior["offset_s"], prior["prior_source"], prior["method"]) == (0.25, "user", "user")


def test_the_rolling_shutter_is_named_in_the_warnings_where_it_is_not_modelled(survey, tmp_path):
    """Without the camera's readout, the slam method warns what a typical one would cost
    this flight (the mounds flown at about 2.7 m/s: fy V 30 ms / (H - 1), some 10 cm);
    given, it is used without a word; the sfm method says it does not model it; and a
    readout as long as a frame is turned down."""
    flight, _ = survey
    inputs = ReconstructionInputs(
        video=str(flight / "DJI_0001.MP4"), log=str(flight / "flight-airdata.csv")
    )

    def warnings(options: ReconstructionOptions, work: str) -> list[str]:
        result = run_stage("ingest", tmp_path / work, options, inputs)
        return [w for w in result["warnings"] if "readout" in w]

    (unknown,) = warnings(ReconstructionOptions(method="slam"), "slam")
    off = float(unknown.split("heights about ")[1].split(" m")[0])
    assert "not modelled" in unknown and 0.05 < off < 0.2
    given = ReconstructionOptions(method="slam")
    given.camera.readout_ms = 20.0
    assert warnings(given, "given") == []
    given.method = "sfm"
    (unused,) = warnings(given, "sfm")
    assert "does not model a rolling shutter" in unused
    given.method = "slam"
    given.camera.readout_ms = 70.0  # a frame of the 15-fps video lasts 66.7 ms
    with pytest.raises(InputError, match="not shorter than a frame"):
        run_stage("ingest", tmp_path / "long", given, inputs)


# -- unusable input through the CLI ------------------------------------------------------


def test_corrupt_video(survey, tmp_path):
    flight, _ = survey
    bad = tmp_path / "bad.mp4"
    bad.write_bytes((flight / "DJI_0001.MP4").read_bytes()[:3000])
    code, output = run_cli(
        "--video", bad, "--log", flight / "DJI_0001.SRT", "--out", tmp_path / "o"
    )
    assert code == 2 and "bad.mp4: not a readable video" in output


def test_empty_log(survey, tmp_path):
    flight, _ = survey
    empty = tmp_path / "empty.srt"
    empty.write_text("")
    code, output = run_cli(
        "--video", flight / "DJI_0001.MP4", "--log", empty, "--out", tmp_path / "o"
    )
    assert code == 2 and "empty.srt: the flight log is empty" in output


def test_log_of_another_flight(survey, tmp_path):
    flight, _ = survey
    created = av.open(str(flight / "DJI_0001.MP4")).metadata["creation_time"]
    assert created  # the simulator stamps its videos
    other = tmp_path / "other.csv"
    other.write_text(
        "time,lat,lon,alt\n"
        "2024-05-12T01:00:00Z,36.0585,140.1044,30\n"
        "2024-05-12T01:05:00Z,36.0586,140.1045,30\n"
    )
    code, output = run_cli(
        "--video", flight / "DJI_0001.MP4", "--log", other, "--out", tmp_path / "o"
    )
    assert code == 2 and "does not overlap DJI_0001.MP4 in time" in output


def test_images_without_gps(tmp_path):

    folder = tmp_path / "imgs"
    folder.mkdir()
    for i in range(3):
        cv2.imwrite(str(folder / f"IMG_{i}.jpg"), np.full((40, 60, 3), 128, np.uint8))
    code, output = run_cli("--images", folder, "--out", tmp_path / "o")
    assert code == 2 and "3 of 3 images have no GPS position" in output


def test_video_without_log(survey, tmp_path):
    flight, _ = survey
    code, output = run_cli("--video", flight / "DJI_0001.MP4", "--out", tmp_path / "o")
    assert code == 2 and "needs its flight log" in output


def test_orthophoto_matches_the_truth_ortho(slam_run, survey):
    """Feature positions of the orthophoto against the orthoimage the simulator rendered
    the frames from, after the survey's georeferencing offset."""
    out, _ = slam_run
    flight, truth_dir = survey
    assert cog_validate(str(out / "orthophoto.tif"), quiet=True)[0]
    stage = json.loads((out / "orthophoto.json").read_text())["orthophoto"]
    assert stage["coverage"] > 0.95 and stage["views"] >= 4
    with rasterio.open(out / "orthophoto.tif") as src, rasterio.open(out / "dsm.tif") as dsm:
        assert src.count == 4 and src.crs == dsm.crs
        assert src.res[0] <= dsm.res[0] + 1e-9  # at the DSM's resolution or finer
    bias, _ = bias_and_trajectory_error(out, flight)
    errors = orthophoto_errors(out / "orthophoto.tif", truth_dir / "ortho.tif", tuple(bias[:2]))
    assert errors.correlation > 0.9 and errors.tiles >= 15  # the right colours, everywhere
    # After the survey's georeferencing offset (the median shift over the whole
    # orthophoto: the trajectory's mean bias leaves some, as it does for the DSM).
    assert errors.residual_median_px <= 2.0, errors  # measured 1.4 px
    # What remains is the georeference's rotation (0.17 deg here), not the orthophoto's:
    # after it the features sit within a pixel.
    assert errors.local_p90_px <= 1.0, errors  # measured 0.54 px
