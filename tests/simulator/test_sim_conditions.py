"""The simulator's harder conditions do what they say: a cross pattern flies both
directions, low sun casts longer shadows and low light darkens the frame, a
texture-poor field has less local contrast, and a rolling shutter shifts each row by
the motion during the readout."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from worker.simulator.camera import CameraModel, rotation_world_from_camera
from worker.simulator.flight_plan import build_flight
from worker.simulator.georef import Grid
from worker.simulator.render import HeightFieldRenderer, RenderOptions
from worker.simulator.rolling_shutter import margin_for
from worker.simulator.scenario import get_scenario
from worker.simulator.simulate import SimulationOptions, simulate_scenario, survey_light
from worker.simulator.texture import (
    Exposure,
    Material,
    TextureBank,
    ground_albedo,
    orthoimage,
    shading,
)

CAMERA = CameraModel.phantom4pro(320, 180)
CLEAN = RenderOptions(noise_sigma=0.0, vignetting=0.0)
NADIR_NORTH_UP = rotation_world_from_camera(0.0, -90.0, 0.0)


def _headings_on_lines(flight) -> np.ndarray:
    """Track headings (deg, 0-180: a line and its way back alike) while the aircraft
    flies faster than half its cruise speed during the video."""
    rec = (flight.t >= 0) & (flight.t <= flight.video_end)
    v = flight.velocity[rec]
    fast = np.hypot(v[:, 0], v[:, 1]) > 0.5 * flight.speed_m_s
    return np.degrees(np.arctan2(v[fast, 0], v[fast, 1])) % 180.0


def test_a_cross_pattern_flies_its_lines_in_both_directions():
    spec = get_scenario("paper-mounds")
    plan = spec.flight_plan("lawnmower", 10.0, 4.0)  # lines north-south
    flat = lambda x, y: np.zeros_like(x)  # noqa: E731
    plain = build_flight(plan, CAMERA, flat, spec.home_xy, np.random.default_rng(1))
    cross = build_flight(
        replace(plan, cross=True), CAMERA, flat, spec.home_xy, np.random.default_rng(1)
    )

    def shares(flight) -> tuple[float, float]:
        h = _headings_on_lines(flight)
        north_south = np.mean((h < 10) | (h > 170))
        east_west = np.mean(np.abs(h - 90) < 10)
        return float(north_south), float(east_west)

    # (The rest of the time in turns: 6 m wide at 4 m/s.)
    ns, ew = shares(plain)
    assert ns > 0.75 and ew < 0.05
    ns, ew = shares(cross)
    # The second grid's lines are as long as the first's (a square field): as much of
    # the time on lines each way.
    assert ns > 0.33 and ew > 0.33 and ns == pytest.approx(ew, abs=0.05)
    assert cross.info["cross_grid_flown"] == 1.0 and "cross_grid_flown" not in plain.info
    assert cross.path_length_m > 1.9 * plain.path_length_m
    # A video too short for both grids at the top speed says how much of the second it has.
    short = build_flight(
        replace(plan, cross=True, speed_m_s=None, duration_s=20.0),
        CAMERA,
        flat,
        spec.home_xy,
        np.random.default_rng(1),
    )
    assert short.info["truncated_by_max_speed"] and short.info["cross_grid_flown"] < 1.0


def _pillar_scene() -> tuple[Grid, np.ndarray, np.ndarray]:
    """Flat ground at z = 10 with a 2 x 2 m pillar 3 m tall at (0, -8), and a grey
    albedo with a fine texture."""
    grid = Grid.centered(80.0, 80.0, 0.1)
    x, y = grid.mesh()
    dsm = np.full(grid.shape, 10.0, np.float32)
    dsm[(np.abs(x) < 1.0) & (np.abs(y + 8.0) < 1.0)] = 13.0
    rng = np.random.default_rng(4)
    albedo = np.clip(0.5 + 0.03 * rng.standard_normal((*grid.shape, 1)), 0, 1)
    return grid, dsm, np.repeat(albedo, 3, axis=2).astype(np.float32)


def _shadow_reach(frame: np.ndarray, azimuth_deg: float) -> float:
    """How far (m) the pillar's shadow reaches from the pillar's centre away from the
    sun, on a nadir frame from 40 m above the ground centred on (0, 0)."""
    gray = frame.astype(np.float32).mean(axis=2)
    dark = gray < 0.6 * np.median(gray)
    rows, cols = np.nonzero(dark)
    metres_per_px = 40.0 / CAMERA.fx
    east = (cols - CAMERA.cx) * metres_per_px
    north = -(rows - CAMERA.cy) * metres_per_px - (-8.0)
    away = np.radians(azimuth_deg + 180.0)
    along = east * np.sin(away) + north * np.cos(away)
    return float(along.max())


def test_low_sun_lengthens_the_shadows_and_low_light_darkens_the_frame():
    grid, dsm, albedo = _pillar_scene()
    usual = SimulationOptions()
    low = SimulationOptions(sun_elevation_deg=10.0, light_gain=0.6)
    frames, suns, gains = [], [], []
    for options in (usual, low):
        # The same stream for both: the same azimuth, gain and white balance.
        sun, exposure = survey_light(np.random.default_rng(7), options)
        ortho = orthoimage(albedo, shading(dsm, grid.res, sun), exposure)
        renderer = HeightFieldRenderer(dsm, grid, ortho, CAMERA, CLEAN)
        frames.append(renderer.render(np.array([0.0, 0.0, 50.0]), NADIR_NORTH_UP).image)
        suns.append(sun)
        gains.append(exposure.gain)
    assert suns[0].azimuth_deg == suns[1].azimuth_deg and 38.0 <= suns[0].elevation_deg <= 62.0
    assert suns[1].elevation_deg == 10.0 and gains[1] == pytest.approx(0.6 * gains[0])
    reach = [_shadow_reach(f, suns[0].azimuth_deg) for f in frames]
    # The shadow of a 3 m pillar reaches 3 m / tan(elevation) beyond its sunlit side:
    # 17.0 m at 10 deg, 1.6-3.8 m at the usual 38-62 deg. Measured from the pillar's
    # centre (up to 1.4 m from its side), to within 0.6 m.
    lengthening = 3.0 / np.tan(np.radians(10.0)) - 3.0 / np.tan(np.radians(suns[0].elevation_deg))
    assert reach[1] - reach[0] == pytest.approx(lengthening, abs=0.6)
    # Flat sunlit ground: its brightness scales with the light, 0.6.
    ratio = np.median(frames[1].astype(np.float32)) / np.median(frames[0].astype(np.float32))
    assert ratio == pytest.approx(0.6, abs=0.02)


def _local_contrast(image: np.ndarray) -> float:
    """Median absolute difference from the 3-pixel Gaussian mean: contrast at the scale
    features are matched on, robust to a few edges."""
    gray = image.astype(np.float32)
    gray = gray.mean(axis=2) if gray.ndim == 3 else gray
    return float(np.median(np.abs(gray - cv2.GaussianBlur(gray, (0, 0), 3.0))))


def test_a_texture_poor_field_has_its_local_contrast_scaled_by_the_factor():
    grid = Grid.centered(40.0, 40.0, 0.05)
    material = np.full(grid.shape, Material.GRASS, np.uint8)
    material[:, : grid.width // 2] = Material.SAND
    bank = TextureBank.make(grid.shape, grid.res, np.random.default_rng(5))
    dsm = np.full(grid.shape, 10.0, np.float32)
    contrast = {}
    for factor in (1.0, 0.3):
        albedo = ground_albedo(material, bank, grid.res, factor)
        ortho = orthoimage(albedo, np.ones(grid.shape, np.float32), Exposure())
        frame = HeightFieldRenderer(dsm, grid, ortho, CAMERA, CLEAN).render(
            np.array([0.0, 0.0, 25.0]), NADIR_NORTH_UP
        )
        contrast[factor] = (_local_contrast(albedo * 255.0), _local_contrast(frame.image))
    albedo_ratio = contrast[0.3][0] / contrast[1.0][0]
    frame_ratio = contrast[0.3][1] / contrast[1.0][1]
    assert albedo_ratio == pytest.approx(0.3, abs=0.02)
    # On the rendered frame a little more: rounding to 8-bit levels adds its own
    # contrast, a third of a level, to texture of about one level.
    assert 0.27 < frame_ratio < 0.4
    # Factor 1 is the ground as it always was.
    assert np.array_equal(
        ground_albedo(material, bank, grid.res), ground_albedo(material, bank, grid.res, 1.0)
    )


def _row_shift(reference: np.ndarray, image: np.ndarray, row: int) -> float:
    """The shift s (px, along the rows) for which image[row] best matches
    reference[row - s], found on a 0.05 px grid."""
    best, best_err = 0.0, np.inf
    for s in np.arange(-6.0, 6.0001, 0.05):
        r = row - s
        if r < 0 or r > reference.shape[0] - 1:
            continue
        r0 = int(np.floor(r))
        r1 = min(r0 + 1, reference.shape[0] - 1)
        f = r - r0
        line = (1 - f) * reference[r0] + f * reference[r1]
        err = float(np.mean((line - image[row]) ** 2))
        if err < best_err:
            best, best_err = float(s), err
    return best


def test_a_rolling_shutter_shifts_each_row_by_the_motion_during_its_readout():
    """Flying north at 10 m/s, 10 m over flat textured ground, image top to the north,
    rows read over 30 ms: the last row is read from 0.3 m further north than the first,
    so row v shows the ground the global-shutter frame shows at row v - s(v), with
    s = (v / (h - 1) - 0.5) x 0.3 m x fx / 10 m (-3.2 px at the top, +3.2 px at the
    bottom)."""
    grid = Grid.centered(40.0, 40.0, 0.05)
    rng = np.random.default_rng(3)
    blocks = (rng.random((grid.height // 4 + 1, grid.width // 4 + 1, 3)) * 200 + 30).astype(
        np.uint8
    )
    ortho = cv2.resize(blocks, (grid.width, grid.height), interpolation=cv2.INTER_NEAREST)
    ortho = cv2.GaussianBlur(ortho, (0, 0), 1.0)
    dsm = np.full(grid.shape, 10.0, np.float32)
    speed, readout, height = 10.0, 0.03, 10.0
    mid = np.array([0.0, 0.0, 10.0 + height])
    half_way = np.array([0.0, speed * readout / 2, 0.0])
    first, last = mid - half_way, mid + half_way
    r = NADIR_NORTH_UP
    margin = margin_for(CAMERA, (first[None], r[None]), (last[None], r[None]), np.array([height]))
    expected_edge = 0.5 * speed * readout * CAMERA.fx / height
    assert expected_edge + 2 <= margin <= expected_edge + 3
    global_shutter = HeightFieldRenderer(dsm, grid, ortho, CAMERA, CLEAN)
    rolling = HeightFieldRenderer(
        dsm, grid, ortho, CAMERA, replace(CLEAN, rolling_shutter_margin_px=margin)
    )
    reference = global_shutter.render(mid, r).image.astype(np.float32).mean(axis=2)
    # One pose: the grown view, cut back, is the global-shutter frame exactly.
    same = rolling.render(mid, r).image.astype(np.float32).mean(axis=2)
    assert np.array_equal(same, reference)
    image = rolling.render(np.stack([mid, first, last]), np.stack([r, r, r]))
    shifted = image.image.astype(np.float32).mean(axis=2)
    for row in (0, 20, 45, 90, 135, 160, 179):
        expected = (row / (CAMERA.height - 1) - 0.5) * speed * readout * CAMERA.fx / height
        assert _row_shift(reference, shifted, row) == pytest.approx(expected, abs=0.1), row


def test_conditions_out_of_range_are_refused_by_name(tmp_path):
    bad = {
        "sun_elevation_deg": 0.0,
        "light_gain": 0.0,
        "ground_contrast": -0.1,
        "rolling_shutter_s": 0.05,  # longer than a frame at 30 fps
    }
    for name, value in bad.items():
        with pytest.raises(ValueError, match=name):
            simulate_scenario("paper-mounds", tmp_path / name, SimulationOptions(**{name: value}))
        assert not (tmp_path / name).exists()
