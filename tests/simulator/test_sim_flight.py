"""Flight plans: lawnmower spacing from the overlap, nadir camera, the paper's 3-D
trajectory, terrain following at real scale."""

import numpy as np
import pytest

from worker.simulator.camera import CameraModel
from worker.simulator.flight_plan import FlightPlan, build_flight
from worker.simulator.scenario import get_scenario

CAM = CameraModel.phantom4pro(640, 360)


def flat(x, y):
    return np.zeros_like(np.asarray(x, dtype=float)) + 25.0


def test_phantom4pro_intrinsics():
    assert CAM.fx == pytest.approx(640 * 8.8 / 13.2)
    assert CAM.hfov_deg == pytest.approx(73.7, abs=0.1)
    assert (CAM.cx, CAM.cy) == (319.5, 179.5)


def test_lawnmower_spacing_heading_and_nadir_camera():
    plan = FlightPlan(length_m=30.0, width_m=30.0, altitude_m=7.0, side_overlap=0.6, speed_m_s=3.0)
    fl = build_flight(plan, CAM, flat, (-20.0, -20.0), np.random.default_rng(0))
    across = CAM.ground_footprint(7.0)[0]
    assert fl.line_spacing_m == pytest.approx(0.4 * across)
    assert fl.n_lines == int(np.ceil((30.0 - across) / fl.line_spacing_m)) + 1
    t = np.arange(0, fl.duration, 0.1)
    st = fl.sample(t)
    assert np.allclose(st["position"][:, 2], 32.0, atol=0.01)
    assert np.all(np.abs(st["gimbal_ypr"][:, 1] + 90.0) < 0.3)
    v = st["velocity"]
    fast = np.hypot(v[:, 0], v[:, 1]) > 2.95  # on the lines (turns are slower)
    heading = np.degrees(np.arctan2(v[fast, 0], v[fast, 1]))
    d = (st["gimbal_ypr"][fast, 0] - heading + 180) % 360 - 180
    assert np.percentile(np.abs(d), 95) < 3.0
    # Lines are the plan's: x positions cluster on the line offsets.
    offsets = (np.arange(fl.n_lines) - (fl.n_lines - 1) / 2) * fl.line_spacing_m
    xs = st["position"][fast, 0]
    assert np.min(np.abs(xs[:, None] - offsets[None, :]), axis=1).max() < 0.05
    assert fl.speed_m_s == 3.0
    assert np.hypot(v[:, 0], v[:, 1]).max() < 3.05


def test_video_length_sets_the_speed():
    plan = FlightPlan(length_m=22.0, width_m=22.0, duration_s=30.0)
    fl = build_flight(plan, CAM, flat, (-12.0, -12.0), np.random.default_rng(1))
    assert fl.duration == 30.0
    end = fl.sample(np.array([30.0]))["position"][0]
    assert fl.info["covered_path_m"] == pytest.approx(fl.path_length_m, rel=1e-3)
    assert np.hypot(*(fl.sample(np.array([29.9]))["velocity"][0, :2])) < 1.0
    assert end[2] == pytest.approx(32.0, abs=0.01)


def test_paper_3d_trajectory_varies_between_7_and_20_m():
    plan = get_scenario("paper-mounds").flight_plan("paper-3d")
    fl = build_flight(plan, CAM, flat, (-12.0, -12.0), np.random.default_rng(2))
    z = fl.sample(np.arange(0, fl.duration, 0.1))["position"][:, 2] - 25.0
    assert z.min() == pytest.approx(7.0, abs=0.1)
    assert z.max() == pytest.approx(20.0, abs=0.3)


def test_hillslope_flight_follows_the_terrain():
    spec = get_scenario("hillslope")
    rng = np.random.default_rng(3)
    scene = spec.build(rng)
    fl = build_flight(spec.flight_plan(), CAM, scene.height_at, spec.home_xy, rng)
    p = fl.sample(np.arange(0, fl.duration, 0.5))["position"]
    agl = p[:, 2] - scene.height_at(p[:, 0], p[:, 1])
    assert agl.min() > 90.0 and agl.max() < 110.0  # 100 m above the terrain
    relief = scene.ground.max() - scene.ground.min()
    assert relief > 100.0  # a real-scale slope
