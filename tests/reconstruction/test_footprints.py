"""Camera footprints, the per-cell view count, and the dsm stage's overlap figures."""

import atexit
import functools
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from rasterio.transform import Affine
from shapely.geometry import box

from tests.reconstruction.keyframe_maps import keyframe_map
from worker.pipeline.dsm_export import DsmOptions
from worker.pipeline.footprints import (
    camera_footprint,
    camera_footprints,
    overlap_figures,
    points_inside,
    survey_footprints,
    view_count,
    viewpoint_groups,
)
from worker.pipeline.reconstruction import (
    GEOREF_MAP,
    ReconstructionInputs,
    ReconstructionOptions,
    dsm,
    reconstruct_survey,
    write_report,
)
from worker.pipeline.sfm import SfmOptions, _stereo_partners
from worker.pipeline.slam.densify import DensifyOptions
from worker.pipeline.slam.result import SparseMap
from worker.simulator.simulate import SimulationOptions, simulate_scenario

F_PX = 1000.0
WIDTH, HEIGHT = 2000, 1000
K = np.array([[F_PX, 0.0, WIDTH / 2], [0.0, F_PX, HEIGHT / 2], [0.0, 0.0, 1.0]])
# World to camera of a camera looking straight down, image top to the north.
NADIR = np.diag([1.0, -1.0, -1.0])


def nadir_pose(x: float, y: float, z: float) -> tuple[np.ndarray, np.ndarray]:
    centre = np.array([x, y, z])
    return NADIR, -NADIR @ centre


def test_a_nadir_camera_sees_a_known_rectangle():
    """At 50 m over the ground, 2000 x 1000 px at f = 1000 px cover 100 x 50 m."""
    r, t = nadir_pose(100.0, 200.0, 60.0)
    polygon = camera_footprint(K, (WIDTH, HEIGHT), r, t, ground_z=10.0)
    assert polygon is not None
    assert polygon.area == pytest.approx(100.0 * 50.0)
    assert polygon.bounds == pytest.approx((50.0, 175.0, 150.0, 225.0))


def test_a_camera_below_its_ground_or_looking_up_has_no_footprint():
    r, t = nadir_pose(0.0, 0.0, 5.0)
    assert camera_footprint(K, (WIDTH, HEIGHT), r, t, ground_z=10.0) is None
    looking_up = np.diag([1.0, 1.0, 1.0])
    assert camera_footprint(K, (WIDTH, HEIGHT), looking_up, -looking_up @ [0, 0, 50], 0.0) is None


def test_an_oblique_camera_is_cut_at_its_range():
    """Tilted 80 degrees from nadir its upper rays miss the ground: the footprint ends
    at four times the camera's height."""
    tilt = np.radians(80.0)
    # Turn the nadir camera about the world x axis so that it looks north, near the horizon.
    turn = np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]])
    r = NADIR @ turn.T
    t = -r @ np.array([0.0, 0.0, 20.0])
    polygon = camera_footprint(K, (WIDTH, HEIGHT), r, t, ground_z=0.0)
    assert polygon is not None
    far = np.hypot(*np.asarray(polygon.exterior.coords)[:, :2].T).max()
    assert 60.0 < far <= 4 * 20.0 + 1e-6


def test_two_overlapping_cameras_give_the_known_overlap_area():
    """Cameras 60 m apart east-west, footprints 100 x 50 m: they share 40 x 50 m."""
    views = [
        camera_footprint(K, (WIDTH, HEIGHT), *nadir_pose(x, 0.0, 50.0), ground_z=0.0)
        for x in (0.0, 60.0)
    ]
    transform = Affine(1.0, 0.0, -60.0, 0.0, -1.0, 30.0)
    shape = (60, 230)  # x -60 .. 170, y -30 .. 30
    count = view_count(views, transform, shape)
    assert count.dtype == np.int16
    assert (count >= 1).sum() == 160 * 50
    assert (count >= 2).sum() == 40 * 50
    measured = np.ones(shape, bool)
    measured[:, : 60 + 30] = False  # x < 30: the western half of the shared strip
    area, coverage = overlap_figures(views, measured, transform)
    assert area == pytest.approx(2000.0)
    assert coverage == pytest.approx(0.5)
    # A DSM only as wide as its points (x 30 .. 170, all measured): the shared strip west
    # of it was seen twice yet has no height, and counts so.
    east = Affine(1.0, 0.0, 30.0, 0.0, -1.0, 30.0)
    area, coverage = overlap_figures(views, np.ones((60, 140), bool), east)
    assert area == pytest.approx(2000.0)
    assert coverage == pytest.approx(0.5)


def test_keyframes_closer_than_a_stereo_baseline_share_a_viewpoint():
    """At 50 m, 0.04 of the depth is 2 m: a video's keyframes while the aircraft hovers
    or turns on the spot are one viewpoint, and the next one starts 2 m on."""
    centres = np.array([[0, 0, 50], [0.5, 0, 50], [1.9, 0, 50], [2.1, 0, 50], [4.5, 0, 50.0]])
    depths = np.full(len(centres), 50.0)
    assert viewpoint_groups(centres, depths, 0.04).tolist() == [0, 0, 0, 1, 2]
    # A keyframe without a depth stands alone.
    depths[0] = np.nan
    assert viewpoint_groups(centres, depths, 0.04).tolist() == [0, 1, 1, 1, 2]


def test_overlap_seen_from_one_place_only_is_not_stereo_overlap():
    """Three keyframes within a metre of each other at 50 m (one viewpoint, x -50 .. 51)
    and one 60 m east (x 10 .. 110): they overlap over 41 x 50 m only, not over the
    first three's whole footprint (which every keyframe beyond the first sees again),
    and a DSM measured over the shared strip alone covers all of the overlap."""
    centres = [(0.0, 0.0), (0.5, 0.0), (1.0, 0.0), (60.0, 0.0)]
    ground = ground_lattice(-50.0, -25.0, 110.0, 25.0, 1.0)
    sparse = survey_map(centres, 50.0, ground)
    seen = survey_footprints(sparse, 1.0)
    assert seen is not None and len(seen.viewpoints) == 2
    transform = Affine(1.0, 0.0, -60.0, 0.0, -1.0, 30.0)
    measured = np.zeros((60, 230), bool)
    measured[:, 60 + 10 : 60 + 51] = True  # x 10 .. 51: the shared strip
    area, coverage = overlap_figures(seen.viewpoints, measured, transform)
    assert area == pytest.approx(41.0 * 50.0)
    assert coverage == pytest.approx(1.0)


def test_points_inside_a_region_by_cell():
    region = box(0.0, 0.0, 10.0, 10.0)
    points = np.array([[0.2, 0.2, 0.0], [9.7, 9.7, 1.0], [10.6, 5.0, 0.0], [5000.0, 5.0, 0.0]])
    assert points_inside(points, region, 0.5).tolist() == [True, True, False, False]


# -- a small survey written as the georeference stage leaves it ------------------------------


def survey_map(
    centres: list[tuple[float, float]],
    height: float,
    points: np.ndarray,
    also_observed: dict[int, np.ndarray] | None = None,
) -> SparseMap:
    """Nadir cameras at `height` over flat ground at z = 0, each observing the points
    (N, 3) inside its footprint, and those `also_observed` gives it (indices)."""
    poses = [nadir_pose(x, y, height) for x, y in centres]
    r = np.array([p[0] for p in poses])
    tr = np.array([p[1] for p in poses])
    obs_kf, obs_point = [], []
    for i, (x, y) in enumerate(centres):
        half_w, half_h = WIDTH / F_PX * height / 2, HEIGHT / F_PX * height / 2
        seen = np.flatnonzero(
            (np.abs(points[:, 0] - x) < half_w) & (np.abs(points[:, 1] - y) < half_h)
        )
        seen = np.union1d(seen, (also_observed or {}).get(i, []))
        obs_kf += [i] * len(seen)
        obs_point += seen.astype(int).tolist()
    return keyframe_map(K, (WIDTH, HEIGHT), r, tr, obs_kf, obs_point, points)


def ground_lattice(left: float, bottom: float, right: float, top: float, step: float) -> np.ndarray:
    x, y = np.meshgrid(np.arange(left, right, step), np.arange(bottom, top, step))
    return np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])


def write_georeferenced(work: Path, sparse: SparseMap) -> None:
    (work / "georeference").mkdir(parents=True)
    sparse.save(work / GEOREF_MAP)
    geo = {
        "time_offset": {"offset_s": 0.0},
        "crs": "EPSG:32654",
        "segments": [],
        "time_offset_s": 0.0,
        "seconds": 0.0,
        "warnings": [],
    }
    (work / "georeference.json").write_text(json.dumps(geo))


# Two cameras at 50 m, 60 m apart: footprints x -50..50 and 10..110, y -25..25.
CENTRES = [(0.0, 0.0), (60.0, 0.0)]
DSM_OPTIONS = ReconstructionOptions(sparse_sor=False, dsm=DsmOptions(resolution_m=1.0))


def test_a_far_point_does_not_stretch_the_dsm(tmp_path):
    ground = ground_lattice(-50.0, -25.0, 110.0, 25.0, 0.5)
    far = np.array([[5060.0, 3000.0, 0.0]])  # a bad match kilometres away
    write_georeferenced(tmp_path, survey_map(CENTRES, 50.0, np.vstack([ground, far])))
    result = dsm(tmp_path, DSM_OPTIONS)
    assert result.points_outside_footprint == 1
    assert result.points == len(ground)
    left, bottom, right, top = result.dsm["bounds"]
    # The ground's extent, inside the union of the footprints (x -50..110, y -25..25):
    # not stretched to the far point.
    assert -51.0 <= left <= -50.0 and 109.0 <= right <= 111.0
    assert -26.0 <= bottom <= -25.0 and 24.0 <= top <= 26.0
    assert result.overlap_area_m2 == pytest.approx(40.0 * 50.0)
    assert result.overlap_coverage == pytest.approx(1.0)
    stored = json.loads((tmp_path / "dsm.json").read_text())
    assert stored["points_outside_footprint"] == 1 and stored["overlap_coverage"] == 1.0


def rays_beyond_the_ground(x: float, y: float, height: float, n: int, seed: int) -> np.ndarray:
    """Points as SfM triangulates some along nearly parallel rays: on the rays of a nadir
    camera at (x, y, height) through the outer part of its image, 300 m to 20 km along
    them, half beyond the ground and half behind the camera."""
    rng = np.random.default_rng(seed)
    # Image x and y at least a third of the way out from the centre to the border.
    side = rng.choice([-1.0, 1.0], (n, 2))
    u = side[:, 0] * rng.uniform(WIDTH / 6, WIDTH / 2, n)
    v = side[:, 1] * rng.uniform(HEIGHT / 6, HEIGHT / 2, n)
    depth = rng.uniform(300.0, 20_000.0, n) * np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    # The nadir camera's ray through (u, v) runs along (u / f, -v / f, -1) in the world.
    return np.column_stack([x + depth * u / F_PX, y - depth * v / F_PX, height - depth])


def test_far_points_of_sfm_do_not_stretch_the_dsm(tmp_path):
    """A tenth of the sparse points kilometres away along one camera's rays, as an sfm
    survey of 12 s over the mounds had them (9.5 %, most of them seen by a few cameras
    that see little else; its DSM would have been 2.9 x 2.8 km at 0.1 m): outliers,
    counted and dropped, and neither the cameras' reach nor the DSM goes beyond their
    footprints on the ground."""
    centres = [(60.0 * k, 0.0) for k in range(4)]  # footprints x -50 .. 230, y -25 .. 25
    ground = ground_lattice(-50.0, -25.0, 230.0, 25.0, 2.0)
    far = rays_beyond_the_ground(*centres[1], 50.0, n=390, seed=3)
    # Camera 1 observes them (COLMAP's points are observed by the images they come from).
    observed = {1: len(ground) + np.arange(len(far))}
    sparse = survey_map(centres, 50.0, np.vstack([ground, far]), observed)
    assert 0.09 < len(far) / (len(far) + len(ground)) < 0.11
    write_georeferenced(tmp_path, sparse)
    result = dsm(tmp_path, DSM_OPTIONS)
    assert result.points_outside_footprint == len(far)
    assert result.points == len(ground)
    left, bottom, right, top = result.dsm["bounds"]
    assert left >= -51.0 and right <= 231.0 and bottom >= -26.0 and top <= 26.0
    # The cameras' reach: their footprints on the ground, grown by the margin only.
    seen = survey_footprints(sparse, 1.0)
    assert seen is not None
    reach_left, reach_bottom, reach_right, reach_top = seen.reach.bounds
    assert reach_left >= -50.0 - seen.margin_m - 1e-6
    assert reach_right <= 230.0 + seen.margin_m + 1e-6
    assert reach_bottom >= -25.0 - seen.margin_m - 1e-6
    assert reach_top <= 25.0 + seen.margin_m + 1e-6
    # The survey's report states how many were dropped.
    report = write_report(tmp_path)
    assert report["stages"]["dsm"]["points_outside_footprint"] == len(far)


def test_a_poorly_covered_overlap_is_warned_about_in_the_report(tmp_path):
    """Points only east of x = 40: a quarter of the shared 40 x 50 m is measured."""
    ground = ground_lattice(40.0, -25.0, 110.0, 25.0, 0.5)
    write_georeferenced(tmp_path, survey_map(CENTRES, 50.0, ground))
    result = dsm(tmp_path, DSM_OPTIONS)
    assert result.overlap_coverage == pytest.approx(0.25, abs=0.01)
    report = write_report(tmp_path)
    # The survey's verdict fails on it and says so among the report's warnings.
    (check,) = [c for c in report["quality"]["checks"] if c["name"] == "overlap_coverage"]
    assert not report["quality"]["passed"] and not check["passed"]
    assert check["value"] == pytest.approx(0.25, abs=0.01) and check["bound"] == 0.8
    assert check["message"] in report["warnings"] and "Only 25%" in check["message"]
    assert report["stages"]["dsm"]["overlap_area_m2"] == pytest.approx(2000.0)


def test_each_camera_uses_the_ground_it_sees():
    """Over a 10 m step in the ground, each camera's footprint is at its own ground."""
    low = ground_lattice(-50.0, -25.0, 30.0, 25.0, 1.0)
    high = ground_lattice(30.0, -25.0, 300.0, 25.0, 1.0)
    high[:, 2] = 10.0
    sparse = survey_map([(0.0, 0.0), (200.0, 0.0)], 50.0, np.vstack([low, high]))
    # On level ground at the median height each camera sees: the first camera's 50 m.
    views = camera_footprints(sparse, ground_quantile=0.5)
    assert views[0].area == pytest.approx(100.0 * 50.0, rel=0.05)
    assert views[1].area == pytest.approx(80.0 * 40.0)  # 40 m above its ground
    # On the plane fitted to what it sees (the default), camera 1's ground is level.
    assert camera_footprints(sparse)[1].area == pytest.approx(80.0 * 40.0, rel=1e-3)
    seen = survey_footprints(sparse, 1.0)
    assert seen is not None and seen.reach.contains(views[0]) and seen.reach.contains(views[1])


def test_on_a_slope_the_footprint_follows_the_ground():
    """Over ground rising 0.4 m per m to the north, a nadir camera 50 m above the
    ground below it sees the uphill edge nearer and the downhill edge farther than on
    level ground: where the edge rays (0.5 m north or south per m down) meet the slope."""
    ground = ground_lattice(-80.0, -60.0, 80.0, 60.0, 1.0)
    ground[:, 2] = 0.4 * ground[:, 1]
    sparse = survey_map([(0.0, 0.0)], 50.0, ground)
    (view,) = camera_footprints(sparse)
    _, south, _, north = view.bounds
    tan = HEIGHT / 2 / F_PX
    assert north == pytest.approx(50.0 * tan / (1.0 + 0.4 * tan), rel=0.02)  # 20.8 m
    assert south == pytest.approx(-50.0 * tan / (1.0 - 0.4 * tan), rel=0.02)  # -31.3 m
    # The level plane at the median height it sees would say 25 m both ways.
    (level,) = camera_footprints(sparse, ground_quantile=0.5)
    assert level.bounds[1] == pytest.approx(-25.0, rel=0.02)
    assert level.bounds[3] == pytest.approx(25.0, rel=0.02)
    seen = survey_footprints(sparse, 1.0)
    assert seen is not None and seen.reach.contains(view)


@functools.cache
def small_photo_set() -> Path:
    """The mound field flown as photos of 456 x 304 px at the simulator's 75 % forward
    overlap (baseline ratio 0.25: tests/simulator's image_run flies 60 %, ratio 0.4,
    beyond the 0.3 dense stereo takes), without GNSS errors; about 8 s."""
    out = Path(tempfile.mkdtemp(prefix="footprints-photos-"))
    atexit.register(shutil.rmtree, out, True)
    options = SimulationOptions(
        seed=11,
        steps=1,
        survey="images",
        gnss="none",
        image_width=456,
        image_height=304,
        write_ortho=False,
        registration=False,
    )
    run = simulate_scenario("paper-mounds", out / "run", options)
    return run.root / run.steps[0]["surveys"][0]["images_dir"]


def test_a_simulated_photo_set_covers_its_overlap(tmp_path):
    """The whole pipeline on the small photo set (about 30 s with the simulation; SfM on
    69 photos with fewer features and neighbours than the defaults, which take 90 s):
    measured heights on at least 80 % of the ground seen by two or more photos (0.855
    when written), every point within the footprints."""
    fast = SfmOptions(max_features=1500, first_octave=0, sequential_overlap=4, spatial_neighbors=8)
    reconstruct_survey(
        ReconstructionInputs(images=str(small_photo_set())),
        tmp_path / "work",
        ReconstructionOptions(sfm=fast),
    )
    dsm_json = json.loads((tmp_path / "work" / "dsm.json").read_text())
    assert dsm_json["overlap_coverage"] >= 0.8, dsm_json
    assert dsm_json["points_outside_footprint"] < 0.001 * dsm_json["points"]
    report = json.loads((tmp_path / "work" / "report.json").read_text())
    (check,) = [c for c in report["quality"]["checks"] if c["name"] == "overlap_coverage"]
    assert check["passed"]


def test_stereo_partners_are_the_neighbours_on_both_sides_along_the_line():
    """A line of nadir photos 12.5 m apart at 50 m (footprints 100 x 50 m, 75 % forward
    overlap, baseline ratio 0.25) and one 40 m beside it (ratio 0.8, beyond the 0.3
    allowed): each inner photo pairs with the one ahead and the one behind, the one
    beside is never taken, and the last photo of the line pairs with its neighbour."""
    centres = [(0.0, 12.5 * i) for i in range(5)] + [(40.0, 25.0)]
    ground = ground_lattice(-60.0, -30.0, 100.0, 80.0, 1.0)
    sparse = survey_map(centres, 50.0, ground)
    partners = _stereo_partners(sparse, np.full(len(centres), 50.0), DensifyOptions())
    assert sorted(partners[2]) == [1, 3]
    assert partners[4] == [3]
    assert all(5 not in chosen for chosen in partners[:5]) and partners[5] == []


def test_a_view_meets_the_crowns_before_the_ground_between_them():
    """Ground at z = 0 with crowns 10 m up over a fifth of it: the image border of a
    nadir camera 50 m above the ground meets the crowns' surface, so its view for the
    overlap figures is cast 40 m below it (80 x 40 m), where the plane fitted through
    all it sees (under 2 m up) gives more than 96 x 48 m."""
    ground = ground_lattice(-80.0, -50.0, 80.0, 50.0, 1.0)
    crowns = ground[::5].copy()
    crowns[:, 2] = 10.0
    sparse = survey_map([(0.0, 0.0)], 50.0, np.vstack([ground, crowns]))
    seen = survey_footprints(sparse, 1.0)
    assert seen is not None and seen.viewpoints[0].area == pytest.approx(80.0 * 40.0, rel=0.01)
    (fitted,) = camera_footprints(sparse)
    assert fitted.area > 96.0 * 48.0
    assert seen.reach.contains(fitted)
