"""RTK photo sets: DJI's RtkFlag and RtkStdLon/Lat/Hgt read from the XMP, used as each
photo's own position sigma by the robust fit and the SfM priors, and the fit's residuals
checked against them (worker/pipeline/ingest/images.py, robust_fit.py, sfm.py)."""

from datetime import datetime, timedelta

import numpy as np
import pytest
from pyproj import Transformer
from scipy.spatial.transform import Rotation

from worker.pipeline.attitude import rotation_world_from_camera
from worker.pipeline.georef import GeorefOptions, check_stated_accuracy
from worker.pipeline.ingest.flight_log import FlightLog, build_flight_log
from worker.pipeline.ingest.images import parse_xmp, read_image_set
from worker.pipeline.robust_fit import georeference_photos
from worker.pipeline.sfm import SfmOptions, _prior_covariances
from worker.pipeline.trajectory import Trajectory
from worker.simulator.image_set import ImageMeta, write_dji_jpeg

EPSG = 32632
ORIGIN = np.array([446_000.0, 5_253_000.0, 500.0])
ROT = Rotation.from_euler("zyx", [-52.0, 6.0, -9.0], degrees=True).as_matrix()
RTK_SIGMA = np.array([0.015, 0.015, 0.03])
STANDALONE = [3, 14, 27]  # photos whose RTK solution was lost: stand-alone GPS, metres off
BAD_FIX = 21  # a photo claiming a fixed solution 1.5 m off (a wrong fix)


def _xmp(flag: int | None, std: tuple[float, float, float] | None) -> bytes:
    attrs = ['drone-dji:GimbalPitchDegree="-90.00"']
    if flag is not None:
        attrs.append(f'drone-dji:RtkFlag="{flag}"')
    if std is not None:
        attrs += [
            f'drone-dji:RtkStdLon="{std[0]}"',
            f'drone-dji:RtkStdLat="{std[1]}"',
            f'drone-dji:RtkStdHgt="{std[2]}"',
        ]
    return (
        '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:Description '
        'xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/" ' + " ".join(attrs) + " />"
        "</x:xmpmeta>"
    ).encode()


def test_the_rtk_flag_and_sigmas_are_read_from_the_xmp():
    xmp = parse_xmp(_xmp(50, (0.01234, 0.01011, 0.02345)))
    assert xmp["rtk_flag"] == 50
    assert (xmp["rtk_std_lon"], xmp["rtk_std_lat"], xmp["rtk_std_hgt"]) == (
        0.01234,
        0.01011,
        0.02345,
    )


def _dji_photo(folder, i: int, rtk_std) -> None:
    lon, lat = 11.3 + i * 2e-5, 47.4
    meta = ImageMeta(
        time_local=datetime(2024, 5, 13, 10, 0, 0) + timedelta(seconds=2 * i),
        lat=lat,
        lon=lon,
        abs_alt=600.0,
        rel_alt=80.0,
        gimbal_yaw=90.0,
        gimbal_pitch=-90.0,
        gimbal_roll=0.0,
        flight_yaw=90.0,
        flight_pitch=0.0,
        flight_roll=0.0,
        rtk_std=rtk_std,
    )
    write_dji_jpeg(folder / f"DJI_{i:04d}.JPG", np.full((48, 64, 3), 128, np.uint8), meta)


def test_an_rtk_photo_set_states_each_photos_sigma(tmp_path):
    for i in range(6):
        _dji_photo(tmp_path, i, None if i == 4 else (0.011, 0.012, 0.025))
    log = read_image_set(tmp_path).log
    assert log.meta["rtk"] == {"fixed": 5, "float": 0, "other": 0, "none": 1}
    assert log.position_sigma is not None
    assert np.isnan(log.position_sigma[4]).all()
    np.testing.assert_allclose(log.position_sigma[0], [0.011, 0.012, 0.025])
    assert log.to_dict()["stated_sigma_m"] == [0.011, 0.012, 0.025]
    assert any("RTK: 5 of 6 photos have a fixed solution" in w for w in log.warnings)
    # The SfM priors: the stated sigma (no tighter than 2 cm), stand-alone without one.
    cov = _prior_covariances(log, log.t, [f"P{i}" for i in range(6)], SfmOptions())
    np.testing.assert_allclose(np.sqrt(np.diag(cov["P0"])), [0.02, 0.02, 0.025])
    np.testing.assert_allclose(np.sqrt(np.diag(cov["P4"])), [2.0, 2.0, 4.0])


def _rtk_survey(seed: int = 3, sfm_noise_m: float = 0.02):
    """42 photos on 6 lines at 60 m with RTK positions (1.5 cm / 3 cm), three photos
    stand-alone (metres off, stating no sigma) and one wrong fix claiming RTK."""
    rng = np.random.default_rng(seed)
    xs, ys = np.linspace(0, 150, 7), np.linspace(0, 100, 6)
    pts = np.array([(x, y) for k, y in enumerate(ys) for x in (xs if k % 2 == 0 else xs[::-1])])
    n = len(pts)
    true = np.column_stack([pts, 60.0 + rng.normal(0, 0.2, n)]) + ORIGIN
    times = np.arange(n) * 2.0
    gps = true + rng.normal(0, 1.0, (n, 3)) * RTK_SIGMA
    sigma = np.tile(RTK_SIGMA, (n, 1))
    gps[STANDALONE] += rng.normal(0, 1.0, (len(STANDALONE), 3)) * [2.5, 2.5, 5.0] + [2.0, -2.0, 4.0]
    sigma[STANDALONE] = np.nan
    gps[BAD_FIX, 0] += 1.5
    lon, lat = Transformer.from_crs(f"EPSG:{EPSG}", "EPSG:4326", always_xy=True).transform(
        gps[:, 0], gps[:, 1]
    )
    rows = [
        {"line": i + 2, "t": float(times[i]), "lat": lat[i], "lon": lon[i], "alt": gps[i, 2]}
        for i in range(n)
    ]
    log = build_flight_log("photos.csv", "generic_csv", rows)
    log.position_sigma = sigma
    noisy = true + rng.normal(0, sfm_noise_m, true.shape)
    local = ((noisy - true.mean(axis=0)) @ ROT) / 12.0
    heads = np.where((np.arange(n) // 7) % 2 == 0, 90.0, 270.0)
    r_local = np.einsum(
        "ji,njk->nik", ROT, rotation_world_from_camera(heads, -90.0, np.zeros_like(heads))
    )
    traj = Trajectory(times, local, r_local, np.ones(n, bool))
    names = [f"DJI_{i + 1:04d}.JPG" for i in range(n)]
    return traj, log, names, true


def _h_rms(d: np.ndarray) -> float:
    return float(np.sqrt((d[:, :2] ** 2).sum(axis=1).mean()))


def test_an_rtk_set_is_fitted_to_its_stated_accuracy():
    traj, log, names, true = _rtk_survey()
    result = georeference_photos(traj, names, log, 0.0)
    # Centimetres: the stand-alone photos weigh little, the wrong fix is left out.
    assert _h_rms(result.apply(traj.positions) - true) < 0.05
    assert [p["name"] for p in result.outliers] == [names[BAD_FIX]]
    assert result.within_stated_accuracy is True
    data = result.to_dict()
    assert data["stated_sigma_m"] == pytest.approx(RTK_SIGMA.tolist())
    assert data["within_stated_accuracy"] is True
    # The same photos without their stated sigmas: the stand-alone ones pull the fit
    # (and a 1.5 m wrong fix is within the stand-alone outlier floor of metres).
    log.position_sigma = None
    plain = georeference_photos(traj, names, log, 0.0)
    assert _h_rms(plain.apply(traj.positions) - true) > 2 * _h_rms(
        result.apply(traj.positions) - true
    )
    assert plain.within_stated_accuracy is None and plain.to_dict()["stated_sigma_m"] is None


def test_a_distorted_reconstruction_misses_the_stated_accuracy():
    # Decimetres of reconstruction error against centimetre positions: reported.
    traj, log, names, _ = _rtk_survey(sfm_noise_m=0.4)
    result = georeference_photos(traj, names, log, 0.0)
    assert result.within_stated_accuracy is False
    assert any("misses the positions' stated accuracy" in w for w in result.warnings)


def test_the_stated_accuracy_check_has_its_bounds():
    options = GeorefOptions()
    stated = np.array([0.02, 0.02, 0.04])
    # Bound: 3 x 0.028 + 0.05 = 0.135 m horizontally, 3 x 0.04 + 0.05 = 0.17 m vertically.
    ok = {"rms_east": 0.09, "rms_north": 0.09, "rms_up": 0.16}
    assert check_stated_accuracy(ok, stated, options) is None
    high = {"rms_east": 0.09, "rms_north": 0.09, "rms_up": 0.2}
    assert "0.20 m vertically" in check_stated_accuracy(high, stated, options)
    wide = {"rms_east": 0.1, "rms_north": 0.1, "rms_up": 0.1}
    assert "0.14 m horizontally" in check_stated_accuracy(wide, stated, options)


def test_a_log_states_the_sigma_of_its_nearest_record():
    log = FlightLog(
        path="x",
        source_format="image_exif",
        t=np.array([0.0, 2.0, 4.0]),
        lat=np.zeros(3),
        lon=np.zeros(3),
        alt=np.zeros(3),
        alt_ref="absolute",
        lines=np.arange(3),
        position_sigma=np.array([[0.01, 0.01, 0.02], [np.nan] * 3, [0.03, 0.03, 0.05]]),
    )
    got = log.stated_sigma_at(np.array([0.4, 1.9, 3.5, 9.0]))
    np.testing.assert_allclose(got[0], [0.01, 0.01, 0.02])
    assert np.isnan(got[1]).all() and np.isnan(got[3]).all()
    np.testing.assert_allclose(got[2], [0.03, 0.03, 0.05])
    assert log.stated_sigma_m() == [0.02, 0.02, 0.035]
