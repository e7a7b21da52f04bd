"""The robust photo-set fit: outlier GPS fixes named and left out, a drifting altitude
down-weighted (worker/pipeline/robust_fit.py), its way into the stage results and the
report, the simulator's consumer GNSS model and `slidewatch bench photos`."""

import json

import numpy as np
import pytest
from click.testing import CliRunner
from pyproj import Transformer
from scipy.spatial.transform import Rotation

from tests.simulator.simtest_support import LIGHT_SFM, image_run
from worker.commands.bench_photos import photos as bench_photos
from worker.pipeline.attitude import rotation_world_from_camera
from worker.pipeline.georef import GeorefOptions, georeference, umeyama
from worker.pipeline.georef_map import photo_names_at
from worker.pipeline.ingest.flight_log import build_flight_log
from worker.pipeline.reconstruction import (
    ReconstructionInputs,
    ReconstructionOptions,
    reconstruct_survey,
    write_report,
)
from worker.pipeline.reconstruction_results import GeoreferenceResult
from worker.pipeline.robust_fit import ViewPrior, georeference_photos, robust_similarity
from worker.pipeline.sfm import SfmOptions
from worker.pipeline.trajectory import Trajectory
from worker.simulator.gnss import GnssErrorModel, simulate_gnss

EPSG = 32632
ORIGIN = np.array([446_000.0, 5_253_000.0, 500.0])
TRUE_SCALE = 20.0
TRUE_ROT = Rotation.from_euler("zyx", [37.0, -8.0, 12.0], degrees=True).as_matrix()
OUTLIERS = [5, 17, 22, 31]


def photo_survey(seed: int = 1):
    """40 photos on 5 lines over 200 x 120 m at 80 m, 2 s apart; GPS: 0.7 m noise, an
    altitude drifting linearly by 40 m over the flight, four fixes 35 m off horizontally.
    Returns (local centres, true centres, GPS positions, headings, times)."""
    rng = np.random.default_rng(seed)
    xs, ys = np.linspace(0, 200, 8), np.linspace(0, 120, 5)
    pts = np.array([(x, y) for k, y in enumerate(ys) for x in (xs if k % 2 == 0 else xs[::-1])])
    n = len(pts)
    true = np.column_stack([pts, 80.0 + rng.normal(0, 0.3, n)]) + ORIGIN
    times = np.arange(n) * 2.0
    gps = true + rng.normal(0, 0.7, (n, 3))
    gps[:, 2] += 40.0 * times / times[-1] - 20.0
    az = rng.uniform(0, 2 * np.pi, len(OUTLIERS))
    gps[OUTLIERS, 0] += 35.0 * np.cos(az)
    gps[OUTLIERS, 1] += 35.0 * np.sin(az)
    local = ((true - true.mean(axis=0)) @ TRUE_ROT) / TRUE_SCALE
    heads = np.where((np.arange(n) // 8) % 2 == 0, 90.0, 270.0)
    return local, true, gps, heads, times


def h_rms(d: np.ndarray) -> float:
    return float(np.sqrt((d[:, :2] ** 2).sum(axis=1).mean()))


def test_robust_fit_recovers_the_similarity_and_names_the_outliers():
    local, true, gps, _, _ = photo_survey()
    fit = robust_similarity(local, gps)
    # Horizontal: within the GPS noise (0.7 m per axis, ~1 m per photo horizontally).
    assert h_rms(fit.similarity.apply(local) - true) < 1.5
    assert fit.similarity.scale == pytest.approx(TRUE_SCALE, rel=0.02)
    assert sorted(fit.outliers.tolist()) == OUTLIERS
    # The vertical counts for less than the horizontal: at least vertical_ratio times.
    assert fit.sigmas[2] >= 4.0 * fit.sigmas[0]
    # The plain least-squares fit on the same photos is pulled metres off by the outliers.
    plain = umeyama(local, gps)
    assert h_rms(plain.apply(local) - true) > 2.5


def test_a_view_prior_holds_the_tilt_against_the_altitude_drift():
    local, true, gps, _, _ = photo_survey()
    down = np.array([0.0, 0.0, -1.0])
    view = ViewPrior(TRUE_ROT.T @ down, down, float(np.radians(1.0) / np.sqrt(len(local))))
    d = robust_similarity(local, gps, view=view).similarity.apply(local) - true
    # Beyond the drift's mean (which no fit can see) the heights are right within 1 m;
    # without the prior the fit tilts to follow the drift (several metres).
    assert np.sqrt(((d[:, 2] - d[:, 2].mean()) ** 2).mean()) < 1.0
    d0 = robust_similarity(local, gps).similarity.apply(local) - true
    assert np.sqrt(((d0[:, 2] - d0[:, 2].mean()) ** 2).mean()) > 3.0


def _photo_inputs():
    local, true, gps, heads, times = photo_survey()
    lon, lat = Transformer.from_crs(f"EPSG:{EPSG}", "EPSG:4326", always_xy=True).transform(
        gps[:, 0], gps[:, 1]
    )
    rows = [
        {"line": i + 2, "t": float(times[i]), "lat": lat[i], "lon": lon[i], "alt": gps[i, 2]}
        for i in range(len(times))
    ]
    log = build_flight_log("photos.csv", "generic_csv", rows)
    r_local = np.einsum(
        "ji,njk->nik", TRUE_ROT, rotation_world_from_camera(heads, -90.0, np.zeros_like(heads))
    )
    traj = Trajectory(times, local, r_local, np.ones(len(times), bool))
    names = [f"DJI_{i + 1:04d}.JPG" for i in range(len(times))]
    return traj, log, names, true


def test_georeference_photos_lists_every_photo_and_names_the_outliers():
    traj, log, names, true = _photo_inputs()
    result = georeference_photos(traj, names, log, 0.0)
    assert h_rms(result.apply(traj.positions) - true) < 1.5
    assert [p["name"] for p in result.outliers] == [names[i] for i in OUTLIERS]
    assert len(result.photos) == len(names) and result.inliers == len(names) - len(OUTLIERS)
    bad = result.outliers[0]
    assert bad["horizontal_m"] > 20.0 and set(bad) >= {"east_m", "north_m", "up_m", "status"}
    assert any(names[OUTLIERS[0]] in w for w in result.warnings)
    data = result.to_dict()
    assert data["method"] == "robust_photos"
    assert data["outliers"] == [names[i] for i in OUTLIERS] and len(data["photos"]) == len(names)
    # Residual statistics without the outliers: metres, not the outliers' tens.
    assert result.residuals["rms_east"] < 2.0 and result.residuals["rms_north"] < 2.0
    # The video path keeps its keys: no photo table.
    assert "photos" not in georeference(traj, log, 0.0, GeorefOptions()).to_dict()


def test_photo_names_follow_the_camera_times():
    photos = {0.0: "A.JPG", 2.0: "B.JPG", 4.0: "C.JPG"}
    assert photo_names_at(np.array([4.0, 0.004, 2.0, 9.0]), photos) == [
        "C.JPG",
        "A.JPG",
        "B.JPG",
        "t=9.000s",
    ]


def test_the_photo_table_reaches_the_stage_result_and_the_report(tmp_path):
    rows = [
        {"name": "DJI_0001.JPG", "east_m": 0.4, "north_m": -0.2, "up_m": 3.0,
         "horizontal_m": 0.447, "status": "used", "segment": 0},
        {"name": "DJI_0002.JPG", "east_m": 31.0, "north_m": 12.0, "up_m": -4.0,
         "horizontal_m": 33.242, "status": "outlier", "segment": 0},
    ]  # fmt: skip
    data = {
        "time_offset": {"offset_s": 0.0},
        "crs": "EPSG:32632",
        "segments": [{"segment": 0, "residuals_after_m": {"rms_east": 0.4}}],
        "time_offset_s": 0.0,
        "seconds": 0.1,
        "warnings": [],
        "photos": rows,
    }
    result = GeoreferenceResult.from_dict(data)
    assert result.photos == rows and result.to_dict() == data
    without = {k: v for k, v in data.items() if k != "photos"}
    assert GeoreferenceResult.from_dict(without).to_dict() == without
    (tmp_path / "georeference.json").write_text(json.dumps(data))
    report = write_report(tmp_path)
    assert report["photo_outliers"] == [rows[1]]
    assert report["stages"]["georeference"]["photos"] == rows


def test_consumer_gnss_has_a_drifting_altitude_and_outlier_fixes():
    model = GnssErrorModel.named("consumer")
    track = simulate_gnss(model, 0.0, 120.0, np.random.default_rng(3))
    again = simulate_gnss(model, 0.0, 120.0, np.random.default_rng(3))
    np.testing.assert_array_equal(track.error_enu, again.error_enu)  # seeded
    clean = track.error_enu - track.outlier_enu
    up = clean[:, 2]
    # Tens of metres of altitude wander within a minute, horizontal a few metres.
    assert np.ptp(up[track.t <= 60.0]) > 10.0
    assert np.abs(clean[:, :2]).max() < 10.0
    jumps = np.hypot(track.outlier_enu[:, 0], track.outlier_enu[:, 1])
    assert jumps.max() >= 20.0 and (jumps > 0).mean() < 0.2
    # The other models keep their manifests and random streams.
    assert "outlier_rate_hz" not in GnssErrorModel.named("standalone").to_dict()
    assert simulate_gnss(GnssErrorModel(), 0.0, 10.0, np.random.default_rng(0)).outlier_enu is None


def test_bench_photos_writes_its_figures(tmp_path):
    out = tmp_path / "photos.json"
    result = CliRunner().invoke(bench_photos, ["--json", str(out), "--seeds", "2"])
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert set(data["robust"]["horizontal_rms_m"]) == {"median", "p90", "worst"}
    assert len(data["runs"]) == 2 and "outliers:" in result.output


def test_an_image_set_reconstruction_lists_its_photos(tmp_path):
    """The whole pipeline on the simulator's small image set (SfM on 44 photos of
    456 x 304 px, with light SfM options): the georeference stage's result and
    report.json carry the photo table, and GPS without error leaves every photo used
    within centimetres."""
    run = image_run()
    folder = run.root / run.steps[0]["surveys"][0]["images_dir"]
    reconstruct_survey(
        ReconstructionInputs(images=str(folder)),
        tmp_path / "work",
        ReconstructionOptions(sfm=SfmOptions(**LIGHT_SFM)),
    )
    geo = json.loads((tmp_path / "work" / "georeference.json").read_text())
    report = json.loads((tmp_path / "work" / "report.json").read_text())
    assert geo["segments"][0]["fit"]["method"] == "robust_photos"
    assert len(geo["photos"]) >= 0.8 * len(list(folder.glob("DJI_*.JPG")))
    assert all(p["status"] == "used" and p["horizontal_m"] < 0.1 for p in geo["photos"])
    assert report["photo_outliers"] == [] and report["stages"]["georeference"]["photos"]
