"""Georeferencing by trajectory fusion on synthetic flights with a known similarity."""

import numpy as np
import pytest
from pyproj import Transformer
from scipy.spatial.transform import Rotation

from worker.pipeline.attitude import rotation_world_from_camera
from worker.pipeline.errors import InputError
from worker.pipeline.georef import (
    GeoreferenceError,
    GeorefOptions,
    georeference,
    offset_residual_fn,
    umeyama,
)
from worker.pipeline.ingest.flight_log import build_flight_log
from worker.pipeline.ingest.time_offset import TimeOffset, refine_time_offset
from worker.pipeline.trajectory import Trajectory

EPSG = 32632
E0, N0, H0 = 446_000.0, 5_253_000.0, 500.0
TO_LONLAT = Transformer.from_crs(f"EPSG:{EPSG}", "EPSG:4326", always_xy=True)
TRUE_SCALE = 7.3
TRUE_ROT = Rotation.from_euler("zyx", [37.0, -8.0, 12.0], degrees=True).as_matrix()
TRUE_T = np.array([E0 + 13.0, N0 - 21.0, H0 + 4.0])


def lawnmower(legs: int = 4, length: float = 120.0, spacing: float = 40.0, speed: float = 6.0):
    """Camera centres (ENU offsets) and headings of a survey pattern, at 10 Hz."""
    pts, heads = [], []
    for k in range(legs):
        y = k * spacing
        xs = np.arange(0, length, speed / 10.0)
        if k % 2:
            xs = xs[::-1]
        pts.append(np.column_stack([xs, np.full(xs.size, y), np.full(xs.size, 80.0)]))
        heads.append(np.full(xs.size, 90.0 if k % 2 == 0 else 270.0))
        if k < legs - 1:
            ys = np.arange(y, y + spacing, speed / 10.0)
            x_end = xs[-1]
            pts.append(np.column_stack([np.full(ys.size, x_end), ys, np.full(ys.size, 80.0)]))
            heads.append(np.zeros(ys.size))
    return np.vstack(pts), np.concatenate(heads)


def straight_line(length: float = 100.0, speed: float = 5.0):
    xs = np.arange(0, length, speed / 10.0)
    return np.column_stack([xs, np.zeros(xs.size), np.full(xs.size, 80.0)]), np.full(xs.size, 90.0)


def gnss_error(n: int, rng, mode: str) -> np.ndarray:
    if mode == "none":
        return np.zeros((n, 3))
    if mode == "rtk":
        bias, drift, noise = [0.01, 0.01, 0.02], [0.005, 0.005, 0.01], [0.008, 0.008, 0.015]
    else:
        bias, drift, noise = [1.5, 1.5, 3.5], [0.5, 0.5, 1.2], [0.12, 0.12, 0.3]
    phi = np.exp(-0.1 / 240.0)
    x = rng.normal(0, 1, 3) * drift
    out = np.empty((n, 3))
    for i in range(n):
        x = phi * x + rng.normal(0, 1, 3) * np.asarray(drift) * np.sqrt(1 - phi * phi)
        out[i] = x
    return out + rng.normal(0, 1, 3) * bias + rng.normal(0, 1, (n, 3)) * noise


def flight(path, heads, mode="standalone", seed=0, outliers=0.0, att_noise=True):
    """(trajectory in the reconstruction frame, log, world GNSS error per sample)."""
    rng = np.random.default_rng(seed)
    n = len(path)
    t = np.arange(n) / 10.0
    world = path + np.array([E0, N0, H0])
    r_world = rotation_world_from_camera(heads, -90.0, 0.0)
    local = ((world - TRUE_T) @ TRUE_ROT) / TRUE_SCALE
    r_local = np.einsum("ji,njk->nik", TRUE_ROT, r_world)
    err = gnss_error(n, rng, mode)
    if outliers:
        bad = rng.random(n) < outliers
        err[bad] += rng.normal(0, 30, (bad.sum(), 3))
    logged = world + err
    lon, lat = TO_LONLAT.transform(logged[:, 0], logged[:, 1])
    yaw_bias = rng.normal(0, 1.5) if att_noise else 0.0
    sd = 0.3 if att_noise else 0.0
    rows = [
        {
            "line": i + 2,
            "t": t[i],
            "lat": lat[i],
            "lon": lon[i],
            "alt": logged[i, 2],
            "gimbal_yaw": heads[i] + yaw_bias + rng.normal(0, sd),
            "gimbal_pitch": -90.0 + rng.normal(0, sd),
            "gimbal_roll": rng.normal(0, sd),
        }
        for i in range(n)
    ]
    log = build_flight_log("log.csv", "generic_csv", rows)
    traj = Trajectory(t, local, r_local, np.ones(n, bool))
    return traj, log, err


def ground_error(result, err: np.ndarray | None = None) -> np.ndarray:
    """3D errors at ground points (z = 0 above H0) over the survey area; with `err`,
    after removing the flight's mean GNSS error (what no method without GCPs can see)."""
    g = np.mgrid[-20:140:20, -20:140:20].reshape(2, -1).T
    world = np.column_stack([g + np.array([E0, N0]), np.full(len(g), H0)])
    local = ((world - TRUE_T) @ TRUE_ROT) / TRUE_SCALE
    predicted = result.apply(local)
    if err is not None:
        predicted = predicted - err.mean(axis=0)
    return np.linalg.norm(predicted - world, axis=1)


def test_umeyama_recovers_an_exact_similarity():
    rng = np.random.default_rng(1)
    src = rng.normal(0, 10, (50, 3))
    dst = TRUE_SCALE * src @ TRUE_ROT.T + TRUE_T
    model = umeyama(src, dst)
    assert model.scale == pytest.approx(TRUE_SCALE)
    np.testing.assert_allclose(model.rotation, TRUE_ROT, atol=1e-9)
    np.testing.assert_allclose(model.translation, TRUE_T, atol=1e-6)


@pytest.mark.parametrize("method", ["similarity", "paper4"])
def test_noise_free_flight_is_recovered_exactly(method):
    path, heads = lawnmower()
    path[:, 2] += 10 * np.sin(np.arange(len(path)) / 40.0)  # 3D, for paper4
    traj, log, _ = flight(path, heads, mode="none", att_noise=False)
    result = georeference(traj, log, 0.0, GeorefOptions(method=method))
    assert result.crs == f"EPSG:{EPSG}"
    assert ground_error(result).max() < 0.02
    assert result.residuals["rms_up"] < 0.02


def test_standalone_gps_lawnmower_similarity_beats_paper4():
    path, heads = lawnmower()
    path[:, 2] += 3 * np.sin(np.arange(len(path)) / 50.0)
    errors = {"similarity": [], "paper4": []}
    for seed in range(6):
        traj, log, err = flight(path, heads, seed=seed)
        for method in errors:
            result = georeference(traj, log, 0.0, GeorefOptions(method=method))
            errors[method].append(np.median(ground_error(result, err)))
    sim, p4 = np.median(errors["similarity"]), np.median(errors["paper4"])
    assert sim < 0.4  # beyond the flight's common GNSS bias
    assert p4 > 5 * sim


def test_rtk_gives_centimetres():
    path, heads = lawnmower()
    traj, log, _ = flight(path, heads, mode="rtk", seed=3)
    result = georeference(traj, log, 0.0)
    assert np.median(ground_error(result)) < 0.05
    assert result.residuals["rms_east"] < 0.05


def test_straight_track_needs_the_attitude():
    path, heads = straight_line()
    with_att, without = [], []
    for seed in range(5):
        traj, log, err = flight(path, heads, seed=seed)
        auto = georeference(traj, log, 0.0)
        never = georeference(traj, log, 0.0, GeorefOptions(attitude="never"))
        straight = georeference(traj, log, 0.0, GeorefOptions(attitude="straight"))
        assert auto.attitude_used and auto.attitude_source == "gimbal"
        assert straight.attitude_used
        assert auto.straightness < 0.1
        assert not never.attitude_used
        with_att.append(np.median(ground_error(auto, err)))
        without.append(np.median(ground_error(never, err)))
    assert np.median(with_att) < 0.7
    assert np.median(without) > 5 * np.median(with_att)


def test_straight_track_without_any_attitude_assumes_a_nadir_camera():
    """Most DJI SRT files log no angles: a straight pass then relies on the nadir prior."""
    path, heads = straight_line()
    nadir, free = [], []
    for seed in range(5):
        traj, log, err = flight(path, heads, seed=seed)
        log.attitude.clear()
        assumed = georeference(traj, log, 0.0)
        unknown = georeference(traj, log, 0.0, GeorefOptions(sigma_nadir_deg=None))
        assert not assumed.attitude_used and assumed.attitude_source == "none"
        assert any("straight down" in w for w in assumed.warnings)
        nadir.append(np.median(ground_error(assumed, err)))
        free.append(np.median(ground_error(unknown, err)))
    assert np.median(nadir) < 0.7
    assert np.median(free) > 5 * np.median(nadir)


def test_outliers_are_rejected():
    path, heads = lawnmower()
    traj, log, err = flight(path, heads, seed=4, outliers=0.05)
    result = georeference(traj, log, 0.0)
    assert result.inliers < result.pairs
    good = np.abs(err - np.median(err, axis=0)).max(axis=1) < 10
    assert np.median(ground_error(result, err[good])) < 0.6


def test_attitude_that_disagrees_is_ignored():
    path, heads = straight_line()
    traj, log, _ = flight(path, heads, seed=2)
    log.attitude["gimbal_yaw"] = log.attitude["gimbal_yaw"] + 60.0
    result = georeference(traj, log, 0.0)
    assert not result.attitude_used
    assert any("disagrees" in w for w in result.warnings)


def test_planar_track_fails_paper4_clearly():
    path, heads = lawnmower()
    traj, log, _ = flight(path, heads, mode="none", att_noise=False)
    with pytest.raises(GeoreferenceError, match="not on one plane"):
        georeference(traj, log, 0.0, GeorefOptions(method="paper4"))


def test_no_overlap_is_an_input_error():
    path, heads = lawnmower(legs=2)
    traj, log, _ = flight(path, heads, mode="none")
    with pytest.raises(InputError, match="do not overlap"):
        georeference(traj, log, 5000.0)


def test_time_offset_refined_from_the_trajectory():
    path, heads = lawnmower(legs=3)
    traj, log, _ = flight(path, heads, mode="rtk", seed=5)
    shifted = Trajectory(traj.t - 1.3, traj.positions, traj.rotations, traj.keyframe)
    start = TimeOffset(1.0, 1.0, "recording_flag", "prior")
    found = refine_time_offset(start, shifted.t, offset_residual_fn(shifted, log), search_s=1.0)
    assert found.method == "trajectory_fit" and found.offset_s == pytest.approx(1.3, abs=0.03)
