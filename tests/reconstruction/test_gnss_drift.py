"""Stand-alone GPS drifting over a photo flight is fitted as a line in time, not taken as
scale (worker/pipeline/robust_fit.py `DriftPrior`, GeorefOptions.photo_drift_sigma_m)."""

import numpy as np
import pytest
from pyproj import Transformer
from scipy.spatial.transform import Rotation

from worker.pipeline.attitude import rotation_world_from_camera
from worker.pipeline.georef import GeorefOptions
from worker.pipeline.ingest.flight_log import build_flight_log
from worker.pipeline.robust_fit import georeference_photos
from worker.pipeline.trajectory import Trajectory

EPSG = 32654
ORIGIN = np.array([419_340.0, 3_990_800.0, 32.0])
ROTATION = Rotation.from_euler("z", 25.0, degrees=True).as_matrix()
DRIFT_M = np.array([-0.6, 0.3, 0.8])  # over the whole flight, east, north, up


def lawnmower(
    seed: int, drift_m: np.ndarray = DRIFT_M, outlier: bool = False
) -> tuple[Trajectory, object, list[str], np.ndarray]:
    """A 13 x 26 m site: 4 lines flown north and south, a photo every 0.45 s (72 photos,
    32 s); GPS with 5 cm noise and a drift of `drift_m` over the flight, on a 2 m bias;
    with `outlier`, photo 30's fix 20 m off (multipath)."""
    rng = np.random.default_rng(seed)
    ys = np.linspace(0.0, 26.0, 18)
    pts = [
        (x, y) for k, x in enumerate(np.linspace(0, 12.6, 4)) for y in (ys if k % 2 else ys[::-1])
    ]
    true = np.column_stack([np.array(pts), np.zeros(len(pts))]) + ORIGIN
    times = np.arange(len(true)) * 0.45
    gps = true + np.array([2.0, -1.5, 3.0]) + rng.normal(0, 0.05, true.shape)
    gps += np.outer(times / times[-1] - 0.5, drift_m)
    if outlier:
        gps[30, :2] += (16.0, 12.0)
    local = ((true - true.mean(axis=0)) @ ROTATION) / 3.0  # the reconstruction's own frame
    lon, lat = Transformer.from_crs(f"EPSG:{EPSG}", "EPSG:4326", always_xy=True).transform(
        gps[:, 0], gps[:, 1]
    )
    rows = [
        {"line": i + 2, "t": float(t), "lat": lat[i], "lon": lon[i], "alt": gps[i, 2]}
        for i, t in enumerate(times)
    ]
    log = build_flight_log("photos.csv", "generic_csv", rows)
    heads = np.zeros(len(times))
    r_local = np.einsum(
        "ji,njk->nik", ROTATION, rotation_world_from_camera(heads, -90.0, np.zeros_like(heads))
    )
    traj = Trajectory(times, local, r_local, np.ones(len(times), bool))
    names = [f"DJI_{i + 1:04d}.JPG" for i in range(len(times))]
    return traj, log, names, true


def spread_cm(result, traj: Trajectory, true: np.ndarray) -> float:
    """Median horizontal error of the georeferenced cameras after their mean offset (the
    GPS bias no fit can see): what scale and rotation errors leave."""
    d = result.apply(traj.positions) - true
    d -= d.mean(axis=0)
    return float(np.median(np.hypot(d[:, 0], d[:, 1])) * 100)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_drift_is_fitted_and_the_scale_stays_right(seed: int):
    traj, log, names, true = lawnmower(seed)
    result = georeference_photos(traj, names, log, 0.0)
    assert result.gnss_drift is not None
    drift = result.gnss_drift.rate * result.gnss_drift.span_s
    np.testing.assert_allclose(drift[:2], DRIFT_M[:2], atol=0.08)
    assert result.similarity.scale == pytest.approx(3.0, rel=0.002)
    assert spread_cm(result, traj, true) < 1.5
    assert result.to_dict()["gnss_drift"]["over_flight_m"][0] == pytest.approx(-0.6, abs=0.08)
    # How well 5 cm positions fix scale and rotation over the site: 2-sigma 3 cm at its
    # edge (17 m from the centre), which the fitted map's own error stays within.
    shape = result.shape_sigma
    assert shape is not None and 0.02 < shape["at_edge_m"] < 0.04
    d = result.apply(traj.positions) - true
    d -= d.mean(axis=0)
    assert np.hypot(d[:, 0], d[:, 1]).max() < shape["at_edge_m"]
    # The residuals are after the drift: the GPS noise's 5 cm, not the drift's decimetres.
    assert result.residuals["rms_east"] < 0.08 and result.residuals["rms_north"] < 0.08

    # Without it, the drift across the lines is taken as scale and rotation.
    plain = georeference_photos(traj, names, log, 0.0, GeorefOptions(photo_drift_sigma_m=None))
    assert plain.gnss_drift is None
    assert abs(plain.similarity.scale / 3.0 - 1.0) > 0.004
    assert spread_cm(plain, traj, true) > 3 * spread_cm(result, traj, true)


def test_no_drift_is_fitted_where_the_gps_shows_none():
    """White noise alone: the drift would only spend the noise, and the plain fit stays."""
    traj, log, names, _ = lawnmower(4, drift_m=np.zeros(3))
    result = georeference_photos(traj, names, log, 0.0)
    assert result.gnss_drift is None and "gnss_drift" not in result.to_dict()
    assert result.similarity.scale == pytest.approx(3.0, rel=0.002)


def test_a_set_with_an_outlier_fix_keeps_the_plain_fit():
    """A fix metres off is no smooth drift: named as an outlier, and no drift fitted."""
    traj, log, names, _ = lawnmower(5, outlier=True)
    result = georeference_photos(traj, names, log, 0.0)
    assert [p["name"] for p in result.outliers] == [names[30]]
    assert result.gnss_drift is None
