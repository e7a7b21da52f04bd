"""`simulate_scenario`: build a scenario's history and write every survey and its truth.

For each step: the truth (DSM, bare-earth DEM, orthoimage, landslide masks, event
labels) as GeoTIFF in the scenario's UTM CRS; for each survey flight of the step: the
MP4 video, its DJI SRT, an AirData CSV flight log, the true camera trajectory, and
optionally a JPEG image set with EXIF/XMP. Then the registration-error patterns of the
paper on one step's DSM, and `manifest.json` describing all of it.
"""

from __future__ import annotations

import platform
import shutil
import tempfile
import time
import zlib
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from datetime import datetime, timedelta
from pathlib import Path

import cv2
import numpy as np

from worker.pipeline.progress import ProgressFn, no_progress
from worker.simulator.camera import CameraModel
from worker.simulator.evolution import MASK_CLASSES, StepChange, advance
from worker.simulator.flight_log import LogRecord, SrtOptions, write_airdata_csv, write_dji_srt
from worker.simulator.flight_plan import Flight, build_flight
from worker.simulator.frames import FramePool, RenderRun, default_workers
from worker.simulator.georef import SceneFrame
from worker.simulator.gnss import (
    GnssErrorModel,
    ImuErrorModel,
    simulate_attitude_errors,
)
from worker.simulator.gnss_field import FieldGnssModel, named_gnss_model, simulate_flight_gnss
from worker.simulator.image_set import ImageMeta, write_dji_jpeg
from worker.simulator.landslide import SlideSpec
from worker.simulator.manifest import FORMAT, Manifest
from worker.simulator.random_slides import random_hillslope_slides
from worker.simulator.registration import registration_patterns, shift_dsm
from worker.simulator.render import RenderOptions
from worker.simulator.rolling_shutter import margin_for, readout_times
from worker.simulator.scenario import ScenarioSpec, get_scenario
from worker.simulator.terrain import Scene
from worker.simulator.texture import (
    Exposure,
    Sun,
    TextureBank,
    disturbed_albedo,
    ground_albedo,
    orthoimage,
    shading,
    tree_albedo,
)
from worker.simulator.truth_io import (
    DSM_NODATA,
    MASK_NODATA,
    write_raster,
    write_trajectory_csv,
)

SURVEY_MODES = ("video", "images", "both", "none")


@dataclass(frozen=True)
class SimulationOptions:
    """Everything `simulate_scenario` can vary. None means the scenario's default."""

    seed: int = 1
    steps: int | None = None
    survey: str = "video"
    """video, images (JPEG set instead of video), both, or none (truth only)."""
    video_seconds: float | None = None
    """Length of each survey video; the plan is flown at the speed that fits."""
    width: int = 640
    height: int = 360
    fps: float = 30.0
    flight: str | None = None
    altitude_m: float | None = None
    speed_m_s: float | None = None
    flights_per_step: int = 1
    slides: bool = True
    """False: the steps differ by the scenario's nuisance only (vegetation growth, small
    surface changes): surveys of a slope where nothing slid, for false-alarm checks."""
    random_slides: int = 0
    """hillslope: this many random slides between Step1 and Step2 instead of the
    scenario's own, which are test data (random_slides.py): training data."""
    gnss: str = "standalone"
    log_time_offset_s: float = 0.0
    """The logged states in the CSV are those of `offset` seconds earlier than the
    CSV's own time stamps and isVideo flags say (positive: the log lags the video)."""
    log_rate_hz: float = 10.0
    csv_units: str = "feet"
    srt_decimals: int = 6
    srt_gimbal: bool = False
    image_width: int = 1368
    image_height: int = 912
    image_overlap: float = 0.75
    write_ortho: bool = True
    registration: bool = True
    workers: int = 0
    """Rendering processes; 0: one per core, at most 2."""
    video_codec: str = "auto"
    crf: int = 20
    render: RenderOptions = field(default_factory=RenderOptions)
    first_local_time: str = "2024-05-13T10:00:00"
    days_between_steps: int = 1
    # Harder conditions, all off by default (a seed then simulates what it always did).
    cross_pattern: bool = False
    """Fly the plan twice, the second time with its lines perpendicular (flight_plan)."""
    sun_elevation_deg: float | None = None
    """The sun's elevation for every survey (low sun: long shadows); None: drawn 38-62."""
    light_gain: float = 1.0
    """Scales the exposure gain (low light: a dim, overcast or late survey)."""
    ground_contrast: float = 1.0
    """Scales the ground's texture contrast (texture-poor: mown grass, bare smooth soil)."""
    rolling_shutter_s: float = 0.0
    """Video rows read one after the other over this time (rolling_shutter.py); 0: a
    global shutter. Photo sets are taken with the mechanical shutter: unaffected."""

    def to_dict(self) -> dict:
        d = asdict(self)
        d["render"] = asdict(self.render)
        return d


def rng_for(seed: int, *key) -> np.random.Generator:
    """An independent, reproducible random stream for a named part of the simulation."""
    words = [zlib.crc32(str(k).encode()) for k in key]
    return np.random.default_rng(np.random.SeedSequence([int(seed), *words]))


def simulate_scenario(
    scenario: str,
    out_dir: Path,
    options: SimulationOptions | None = None,
    progress: ProgressFn = no_progress,
) -> Manifest:
    """Simulate `scenario` ('paper-mounds' or 'hillslope') into `out_dir`."""
    opts = options or SimulationOptions()
    spec = get_scenario(scenario)
    if opts.survey not in SURVEY_MODES:
        raise ValueError(f"survey must be one of {SURVEY_MODES}")
    n_steps = opts.steps or spec.default_steps
    if n_steps < 1:
        raise ValueError("steps must be at least 1")
    _check_conditions(opts)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    scratch = Path(tempfile.mkdtemp(prefix="slidewatch-sim-"))
    workers = opts.workers or default_workers()
    try:
        # The render workers start first: their interpreters load while this one
        # builds the scene.
        with (
            FramePool(workers if opts.survey != "none" else 1, scratch) as pool,
            _TruthWriter() as writer,
        ):
            manifest = _simulate(spec, out, opts, n_steps, workers, pool, writer, progress)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    progress(1.0)
    return manifest


def survey_light(rng: np.random.Generator, opts: SimulationOptions) -> tuple[Sun, Exposure]:
    """The sun and the exposure of one survey, drawn from its stream: azimuth 110-250
    deg, elevation 38-62 deg, gain 0.93-1.07, white balance 0.97-1.03 per channel. Low
    sun (`sun_elevation_deg`) and low light (`light_gain`) are set after the draws, so
    that the stream gives the rest of the survey what it gave without them."""
    sun = Sun(float(rng.uniform(110, 250)), float(rng.uniform(38, 62)))
    exposure = Exposure(
        gain=float(rng.uniform(0.93, 1.07)),
        white_balance=tuple(float(x) for x in rng.uniform(0.97, 1.03, 3)),
    )
    if opts.sun_elevation_deg is not None:
        sun = replace(sun, elevation_deg=float(opts.sun_elevation_deg))
    if opts.light_gain != 1.0:
        exposure = replace(exposure, gain=exposure.gain * opts.light_gain)
    return sun, exposure


def _check_conditions(opts: SimulationOptions) -> None:
    """The harder conditions' options within what they mean."""
    if opts.sun_elevation_deg is not None and not 0.0 < opts.sun_elevation_deg <= 90.0:
        raise ValueError(f"sun_elevation_deg must be in (0, 90], not {opts.sun_elevation_deg}")
    if not opts.light_gain > 0.0:
        raise ValueError(f"light_gain must be positive, not {opts.light_gain}")
    if not opts.ground_contrast >= 0.0:
        raise ValueError(f"ground_contrast must be 0 or more, not {opts.ground_contrast}")
    if not 0.0 <= opts.rolling_shutter_s < 1.0 / opts.fps:
        raise ValueError(
            f"rolling_shutter_s must be at least 0 and shorter than a frame "
            f"({1.0 / opts.fps:.4f} s at {opts.fps} fps), not {opts.rolling_shutter_s}"
        )


def _simulate(
    spec,
    out: Path,
    opts: SimulationOptions,
    n_steps: int,
    workers: int,
    pool: FramePool,
    writer: _TruthWriter,
    progress: ProgressFn,
) -> Manifest:
    """The body of `simulate_scenario`: surveys are rendered and encoded in the
    background (`FramePool.submit`) and truth rasters written in another thread
    (`_TruthWriter`) while this thread goes on with the next step."""
    timings: dict[str, float] = {}
    t_all = time.perf_counter()

    t0 = time.perf_counter()
    frame = SceneFrame.at_lonlat(spec.lon, spec.lat, spec.crs)
    scene = spec.build(rng_for(opts.seed, "scene"))
    grid = scene.grid
    bank = TextureBank.make(grid.shape, grid.res, rng_for(opts.seed, "texture"))
    base_albedo = ground_albedo(scene.material, bank, grid.res, opts.ground_contrast)
    timings["scene"] = time.perf_counter() - t0

    camera = CameraModel.phantom4pro(opts.width, opts.height, kind="video")
    still = CameraModel.phantom4pro(opts.image_width, opts.image_height, kind="still")
    plan = spec.flight_plan(opts.flight, opts.altitude_m, opts.speed_m_s, opts.video_seconds)
    if opts.cross_pattern:
        plan = replace(plan, cross=True)
    gnss_model = named_gnss_model(opts.gnss)
    imu_model = ImuErrorModel()
    tz = timedelta(hours=spec.local_utc_offset_h)
    first_local = datetime.fromisoformat(opts.first_local_time)

    checkpoints = []
    for cp in scene.features.get("checkpoints", []):
        e, n = frame.to_world(cp["x"], cp["y"])
        lon, lat = frame.lonlat(cp["x"], cp["y"])
        checkpoints.append(
            {
                "name": cp["name"],
                "e": round(float(e), 4),
                "n": round(float(n), 4),
                "u": round(cp["z"], 4),
                "lat": round(float(lat), 9),
                "lon": round(float(lon), 9),
                "x_local": cp["x"],
                "y_local": cp["y"],
                "kind": "0.6 m black-and-white target",
            }
        )
    home_e, home_n = frame.to_world(*spec.home_xy)
    scene_info = {k: v for k, v in scene.features.items() if k != "checkpoints"}
    scene_info["checkpoints"] = checkpoints
    scene_info["home"] = {
        "e": float(home_e),
        "n": float(home_n),
        "x_local": spec.home_xy[0],
        "y_local": spec.home_xy[1],
    }
    scene_info["trees_at_step1"] = scene.trees.counts()
    data: dict = {
        "format": FORMAT,
        "scenario": spec.name,
        "seed": opts.seed,
        "created_by": "slidewatch worker.simulator",
        "scenario_info": spec.to_dict(),
        "options": opts.to_dict(),
        "crs": frame.crs,
        "frame": frame.to_dict(),
        "grid": grid.to_dict(frame),
        "scene": scene_info,
        "camera": camera.to_dict(),
        "image_camera": still.to_dict(),
        "gnss": gnss_model.to_dict(),
        "imu": imu_model.to_dict(),
        "mask_classes": MASK_CLASSES,
        "conventions": {
            "local_frame": "x = e - frame.origin_e, y = n - frame.origin_n, z = u",
            "attitude": "DJI: yaw clockwise from north, pitch 0 horizon / -90 nadir, roll "
            "positive right side down; q* in trajectories rotate camera (x right, y down, z "
            "forward) into world (e, n, u)",
            "times": "video clock: t = 0 at the first frame; SRT local time without zone "
            f"(UTC{spec.local_utc_offset_h:+.0f}); CSV datetime(utc)",
            "airdata_speeds": "xSpeed north, ySpeed east, zSpeed down",
        },
        "steps": [],
        "registration": [],
    }
    manifest = Manifest(root=out, data=data)

    n_surveys = n_steps * opts.flights_per_step
    done_surveys = 0
    dsm, canopy = scene.compose()
    dem_prev = scene.dem()
    mask_cum = np.zeros(grid.shape, np.uint8)
    per_event: list[dict] = []
    render_total = RenderRun()
    dsm_by_step: dict[int, np.ndarray] = {}
    # Per survey: (step, flight, a function that waits for its background render and
    # returns the render's wall seconds and the fields to complete its record with).
    finishers: list = []
    t_truth = t_render = t_logs = 0.0
    for k in range(1, n_steps + 1):
        step_dir = out / f"step{k}"
        truth_dir = step_dir / "truth"
        t0 = time.perf_counter()
        step_rec: dict = {
            "index": k,
            "name": f"step{k}",
            "date_local": (first_local + timedelta(days=(k - 1) * opts.days_between_steps))
            .date()
            .isoformat(),
            "truth": {},
            "events": [],
        }
        if k > 1:
            scene, change = _advance_step(spec, scene, dsm, k, n_steps, opts)
            dsm, canopy = scene.compose()
            mask_cum = np.where(change.mask > 0, change.mask, mask_cum).astype(np.uint8)
            dem = scene.dem()
            for i, res in enumerate(change.slides, start=1):
                rec = res.summary()
                sel = change.events == i
                file_delta = float((dem[sel].astype(np.float64) - dem_prev[sel]).sum())
                rec["index_in_events_raster"] = i
                rec["step"] = k
                rec["relative_volume_error_from_dem_files"] = float(
                    f"{abs(file_delta) * grid.cell_area / res.depleted_m3:.3e}"
                )
                rec["mask_area_m2"] = round(float(sel.sum() * grid.cell_area), 4)
                step_rec["events"].append(rec)
                per_event.append(
                    {
                        "step": k,
                        "name": res.spec.name,
                        "depleted_m3": rec["depleted_m3"],
                        "relative_error": rec["relative_volume_error"],
                        "relative_error_from_dem_files": rec[
                            "relative_volume_error_from_dem_files"
                        ],
                    }
                )
            step_rec["nuisance"] = change.nuisance
            step_rec["fallen_trees"] = change.fallen_trees
            step_rec["vanished_trees"] = change.vanished_trees
            step_rec["truth"]["mask"] = _rel(
                writer.write(
                    truth_dir / "mask.tif",
                    change.mask,
                    grid,
                    frame,
                    MASK_NODATA,
                    "landslide mask since the previous step",
                ),
                out,
            )
            step_rec["truth"]["mask_since_step1"] = _rel(
                writer.write(
                    truth_dir / "mask_since_step1.tif",
                    mask_cum,
                    grid,
                    frame,
                    MASK_NODATA,
                    "landslide mask since step 1",
                ),
                out,
            )
            step_rec["truth"]["events"] = _rel(
                writer.write(
                    truth_dir / "events.tif",
                    change.events,
                    grid,
                    frame,
                    None,
                    "1-based index of the step's event in manifest events",
                ),
                out,
            )
            dem_prev = dem
        step_rec["truth"]["dsm"] = _rel(
            writer.write(
                truth_dir / "dsm.tif",
                dsm,
                grid,
                frame,
                DSM_NODATA,
                "true DSM (surface incl. vegetation), m",
            ),
            out,
        )
        step_rec["truth"]["dem"] = _rel(
            writer.write(
                truth_dir / "dem.tif",
                scene.dem(),
                grid,
                frame,
                DSM_NODATA,
                "true bare-earth DEM, m",
            ),
            out,
        )
        step_rec["trees"] = scene.trees.counts()
        dsm_by_step[k] = dsm
        t_truth += time.perf_counter() - t0

        albedo = _albedo(scene, canopy, base_albedo, bank)
        step_rec["surveys"] = []
        for j in range(opts.flights_per_step):
            srng = rng_for(opts.seed, "survey", k, j)
            sun, exposure = survey_light(srng, opts)
            t0 = time.perf_counter()
            ortho = orthoimage(albedo, shading(dsm, grid.res, sun), exposure)
            if j == 0 and opts.write_ortho:
                step_rec["truth"]["ortho"] = _rel(
                    writer.write(
                        truth_dir / "ortho.tif",
                        ortho,
                        grid,
                        frame,
                        None,
                        "orthoimage the first survey was rendered from",
                    ),
                    out,
                )
            t_truth += time.perf_counter() - t0
            start_local = first_local + timedelta(
                days=(k - 1) * opts.days_between_steps, minutes=40 * j
            )
            start_local += timedelta(seconds=float(srng.uniform(0, 600)))
            start_local = start_local.replace(microsecond=0)
            survey = _survey(
                pool,
                out,
                step_dir / f"flight{j + 1}",
                scene,
                dsm,
                ortho,
                frame,
                camera,
                still,
                plan,
                spec.home_xy,
                opts,
                gnss_model,
                imu_model,
                srng,
                start_local,
                tz,
                f"s{k}f{j + 1}",
                render_total,
            )
            survey["id"] = f"step{k}-flight{j + 1}"
            survey["sun"] = {
                "azimuth_deg": round(sun.azimuth_deg, 2),
                "elevation_deg": round(sun.elevation_deg, 2),
            }
            survey["exposure"] = exposure.to_dict()
            finishers.append((k, j, survey.pop("_finish")))
            t_logs += survey.pop("_log_time")
            step_rec["surveys"].append(survey)
            done_surveys += 1
            progress(0.05 + 0.85 * done_surveys / max(n_surveys, 1))
        data["steps"].append(step_rec)
        manifest.save()

    t0 = time.perf_counter()
    if opts.registration and n_steps >= 2:
        r_step = spec.registration_step(n_steps)
        ref = manifest.step(1)["truth"]["dsm"]
        for name, shift in registration_patterns(spec.registration_scale).items():
            shifted = shift_dsm(dsm_by_step[r_step], grid.res, shift)
            path = writer.write(
                out / "registration" / f"step{r_step}_pattern-{name}_dsm.tif",
                shifted,
                grid,
                frame,
                DSM_NODATA,
                f"step {r_step} DSM shifted by {shift} m (e, n, u)",
            )
            data["registration"].append(
                {
                    "pattern": name,
                    "shift_enu_m": [round(v, 6) for v in shift],
                    "step": r_step,
                    "reference_dsm": ref,
                    "unshifted_dsm": manifest.step(r_step)["truth"]["dsm"],
                    "shifted_dsm": _rel(path, out),
                    "mask": manifest.step(r_step)["truth"].get("mask_since_step1"),
                }
            )
    timings["registration"] = time.perf_counter() - t0
    # Wait for the surveys rendered in the background and the truth files.
    t0 = time.perf_counter()
    for k, j, finish in finishers:
        seconds, fields = finish()
        t_render += seconds
        # (Into the manifest's own dict: `save` has replaced the one `_survey` made.)
        manifest.survey(k, j).update(fields)
    writer.wait()
    timings["waiting_for_surveys_and_files"] = time.perf_counter() - t0
    timings["truth"] = t_truth
    # Wall time of the background render + encode jobs (they overlap the above).
    timings["surveys_render_and_encode"] = t_render
    timings["surveys_logs"] = t_logs
    timings["total"] = time.perf_counter() - t_all
    errs = [e["relative_error"] for e in per_event]
    ferrs = [e["relative_error_from_dem_files"] for e in per_event]
    data["volume_conservation"] = {
        "tolerance_relative": 1e-6,
        "tolerance_relative_from_dem_files": 1e-3,
        "max_relative_error": max(errs) if errs else 0.0,
        "max_relative_error_from_dem_files": max(ferrs) if ferrs else 0.0,
        "per_event": per_event,
    }
    data["rendering"] = {
        "frames": render_total.frames,
        "render_seconds_in_workers": round(render_total.render_seconds, 3),
        "render_cpu_seconds": round(render_total.cpu_seconds, 3),
        "cpu_ms_per_frame": round(1000 * render_total.cpu_seconds / max(render_total.frames, 1), 2),
        "frames_per_cpu_second": round(render_total.frames / render_total.cpu_seconds, 2)
        if render_total.cpu_seconds > 0
        else None,
        "frames_per_second_per_process": round(render_total.frames / render_total.render_seconds, 2)
        if render_total.render_seconds > 0
        else None,
        "frames_per_second_wall_incl_encoding": round(
            render_total.frames / render_total.wall_seconds, 2
        )
        if render_total.wall_seconds > 0
        else None,
        "workers": workers,
    }
    data["timings_s"] = {k: round(v, 3) for k, v in timings.items()}
    data["platform"] = {"python": platform.python_version(), "machine": platform.machine()}
    manifest.save()
    return manifest


def _advance_step(
    spec: ScenarioSpec,
    scene: Scene,
    dsm: np.ndarray,
    k: int,
    n_steps: int,
    opts: SimulationOptions,
) -> tuple[Scene, StepChange]:
    """Step k from step k-1: its slides, then the nuisance. A random slide that no longer
    fits once the others moved the ground is left out (the scenario's own always fit)."""
    slides = _step_slides(spec, scene, k, n_steps, opts)
    while True:
        try:
            return advance(
                scene, slides, spec.nuisance, rng_for(opts.seed, "step", k), dsm_before=dsm
            )
        except ValueError as exc:
            misfits = [s for s in slides if opts.random_slides and repr(s.name) in str(exc)]
            if not misfits:
                raise
            slides = [s for s in slides if s not in misfits]


def _step_slides(
    spec: ScenarioSpec, scene: Scene, k: int, n_steps: int, opts: SimulationOptions
) -> list[SlideSpec]:
    """The slides between step k-1 and step k."""
    if not opts.slides:
        return []
    if opts.random_slides:
        if spec.name != "hillslope":
            raise ValueError("random slides are defined for the hillslope scenario only")
        rng = rng_for(opts.seed, "random-slides")
        return random_hillslope_slides(scene, rng, opts.random_slides) if k == 2 else []
    return spec.slides(k, n_steps)


def _rel(path: Path, root: Path) -> str:
    return Path(path).relative_to(root).as_posix()


def _rolling_shutter_poses(
    flight, scene: Scene, camera: CameraModel, times: np.ndarray, opts: SimulationOptions
) -> tuple[np.ndarray, np.ndarray, RenderOptions]:
    """Per frame the poses at mid readout (the frame's time), first row and last row
    ((n, 3, 3) positions, (n, 3, 3, 3) rotations), and the render options with the
    margin these poses need (rolling_shutter.py)."""
    first_t, last_t = readout_times(times, opts.rolling_shutter_s)
    mid = flight.camera_pose(times)
    first = flight.camera_pose(first_t)
    last = flight.camera_pose(last_t)
    above = mid[0][:, 2] - scene.height_at(mid[0][:, 0], mid[0][:, 1])
    margin = margin_for(camera, first, last, above)
    positions = np.stack([mid[0], first[0], last[0]], axis=1)
    rotations = np.stack([mid[1], first[1], last[1]], axis=1)
    return positions, rotations, replace(opts.render, rolling_shutter_margin_px=margin)


def _albedo(scene: Scene, canopy, base: np.ndarray, bank: TextureBank) -> np.ndarray:
    alb = base
    if scene.disturbed is not None:
        alb = disturbed_albedo(alb, bank, scene.disturbed, scene.sand_like)
    return tree_albedo(alb, bank, canopy.index, scene.trees.kind, scene.trees.tone, canopy.radial)


def _survey(
    pool: FramePool,
    out: Path,
    sdir: Path,
    scene: Scene,
    dsm: np.ndarray,
    ortho: np.ndarray,
    frame: SceneFrame,
    camera: CameraModel,
    still: CameraModel,
    plan,
    home_xy,
    opts: SimulationOptions,
    gnss_model: GnssErrorModel | FieldGnssModel,
    imu_model: ImuErrorModel,
    rng: np.random.Generator,
    start_local: datetime,
    tz: timedelta,
    key: str,
    render_total: RenderRun,
) -> dict:
    """Fly one survey and write its video / images, logs and true trajectory."""
    sdir.mkdir(parents=True, exist_ok=True)
    flight = build_flight(plan, camera, scene.height_at, home_xy, rng)
    start_utc = start_local - tz
    t_log0, t_log1 = float(flight.t[0]), float(flight.t[-1])
    # The field model needs the true track (multipath zones, time-tag slips); the others
    # draw exactly what they drew before from the same stream.
    gnss = simulate_flight_gnss(
        gnss_model, t_log0 - 5.0, t_log1 + 5.0, lambda t: flight.sample(t)["position"], rng
    )
    att = simulate_attitude_errors(imu_model, t_log0 - 5.0, t_log1 + 5.0, rng)
    home_abs_logged = float(flight.home[2] + gnss.error_at(np.array([t_log0 + 3.0]))[0, 2])
    rec: dict = {
        "kind": opts.survey,
        "start_local": start_local.isoformat(timespec="milliseconds"),
        "start_utc": start_utc.isoformat(timespec="milliseconds") + "Z",
        "log_time_offset_s": opts.log_time_offset_s,
        "gnss": gnss.summary(),
        "compass_yaw_bias_deg": round(att.yaw_bias, 4),
        "flight": {
            "plan": plan.to_dict(),
            "speed_m_s": round(flight.speed_m_s, 4),
            "path_length_m": round(flight.path_length_m, 3),
            "line_spacing_m": round(flight.line_spacing_m, 4),
            "lines": flight.n_lines,
            "duration_s": round(flight.duration, 4),
            "home_local": [round(float(v), 4) for v in flight.home],
            **flight.info,
        },
    }
    t_render = 0.0
    t_logs = 0.0
    finishers: list = []

    def logged(times: np.ndarray) -> dict:
        """What the aircraft logs at true times `times`."""
        s = flight.sample(times)
        err = gnss.error_at(times)
        pos = s["position"]
        lon, lat = frame.lonlat(pos[:, 0] + err[:, 0], pos[:, 1] + err[:, 1])
        abs_alt = pos[:, 2] + err[:, 2]
        a_err, g_err = att.at(times)
        return {
            "true": s,
            "lat": np.asarray(lat),
            "lon": np.asarray(lon),
            "abs_alt": abs_alt,
            "rel_alt": abs_alt - home_abs_logged,
            "aircraft_ypr": s["aircraft_ypr"] + a_err,
            "gimbal_ypr": s["gimbal_ypr"] + g_err,
        }

    if opts.survey in ("video", "both"):
        from worker.simulator.video import VideoOptions, VideoResult, VideoWriter, pick_codec

        n_frames = int(np.floor(flight.duration * opts.fps + 1e-9)) + 1
        times = np.arange(n_frames) / opts.fps
        pos, rot = flight.camera_pose(times)
        t0 = time.perf_counter()
        render_pos, render_rot, video_render = pos, rot, opts.render
        if opts.rolling_shutter_s > 0:
            render_pos, render_rot, video_render = _rolling_shutter_poses(
                flight, scene, camera, times, opts
            )
            rec["rolling_shutter"] = {
                "readout_s": opts.rolling_shutter_s,
                "margin_px": video_render.rolling_shutter_margin_px,
            }
        ref = pool.scene(
            f"{key}-video",
            dsm,
            scene.grid,
            ortho,
            camera,
            video_render,
            noise_seed=zlib.crc32(key.encode()),
        )
        video_path = sdir / "DJI_0001.MP4"
        preview_path = sdir / "preview.png"
        # Names of their own: the closures below run later, after the image set's
        # section (survey 'both') has bound `run` again.
        video_run = RenderRun()
        video_options = VideoOptions(fps=opts.fps, codec=opts.video_codec, crf=opts.crf)

        def encode(frames) -> VideoResult:
            """Runs in the pool's thread: frames in order into the MP4 (libx264 releases
            the GIL, so this thread goes on meanwhile), the middle one as preview."""
            with VideoWriter(
                video_path, camera.width, camera.height, video_options, creation_time=start_utc
            ) as vw:
                for i, img in enumerate(frames):
                    vw.write(img)
                    if i == n_frames // 2:
                        cv2.imwrite(str(preview_path), img[..., ::-1])
            return vw.result

        video_job = pool.submit(ref, render_pos, render_rot, encode, stats=video_run)
        t_render += time.perf_counter() - t0  # registering the scene; the rest is in job
        rec["preview"] = _rel(preview_path, out)
        rec["preview_frame"] = n_frames // 2
        t0 = time.perf_counter()
        lg = logged(times)
        srt_path = sdir / "DJI_0001.SRT"
        write_dji_srt(
            srt_path,
            opts.fps,
            start_local,
            lg["lat"],
            lg["lon"],
            lg["rel_alt"],
            lg["abs_alt"],
            lg["gimbal_ypr"],
            SrtOptions(decimals=opts.srt_decimals, gimbal=opts.srt_gimbal),
        )
        traj_path = sdir / "trajectory.csv"
        cam_ypr = flight.sample(times)["gimbal_ypr"]
        write_trajectory_csv(
            traj_path,
            np.arange(n_frames),
            times,
            start_utc,
            frame,
            pos,
            rot,
            cam_ypr,
            lg["true"]["aircraft_ypr"],
            lg["true"]["velocity"],
        )
        t_logs += time.perf_counter() - t0
        rec.update(
            {
                "video": _rel(video_path, out),
                "srt": _rel(srt_path, out),
                "trajectory": _rel(traj_path, out),
                "frames": n_frames,
                "fps": opts.fps,
                "width": camera.width,
                "height": camera.height,
                "video_codec": pick_codec(opts.video_codec),
                "render": {},  # filled in when the background job is done (finish_video)
            }
        )

        def finish_video() -> tuple[float, dict]:
            """Wait for the video: the job's wall seconds and the record's last fields."""
            result = video_job.result()
            if result.frames != n_frames:
                raise RuntimeError(f"{video_path}: {result.frames} frames, not {n_frames}")
            run = video_run  # (local)
            _add_run(render_total, run)
            return run.wall_seconds, {
                "video_codec": result.codec,
                "render": {
                    "cpu_ms_per_frame": round(1000 * run.cpu_seconds / max(run.frames, 1), 2),
                    "frames_per_second_per_process": round(run.frames / run.render_seconds, 2)
                    if run.render_seconds
                    else None,
                    "frames_per_second_wall_incl_encoding": round(run.frames / run.wall_seconds, 2)
                    if run.wall_seconds
                    else None,
                },
            }

        finishers.append(finish_video)

    photo_times = np.zeros(0)
    if opts.survey in ("images", "both"):
        alt = plan.altitude_m
        along = still.ground_footprint(alt)[1]
        spacing = max((1.0 - opts.image_overlap) * along, 0.05)
        photo_times = np.arange(0.0, flight.duration + 1e-9, spacing / flight.speed_m_s)
        pos, rot = flight.camera_pose(photo_times)
        t0 = time.perf_counter()
        ref = pool.scene(
            f"{key}-images",
            dsm,
            scene.grid,
            ortho,
            still,
            opts.render,
            noise_seed=zlib.crc32(key.encode()) + 1,
        )
        img_dir = sdir / "images"
        img_dir.mkdir(parents=True, exist_ok=True)
        lg = logged(photo_times)
        names = []
        run = RenderRun()
        rtk = isinstance(gnss_model, GnssErrorModel) and gnss_model.mode == "rtk"
        for i, img in enumerate(pool.render(ref, pos, rot, stats=run)):
            name = f"DJI_{i + 1:04d}.JPG"
            names.append(name)
            write_dji_jpeg(
                img_dir / name,
                img,
                ImageMeta(
                    time_local=start_local + timedelta(seconds=float(photo_times[i])),
                    lat=float(lg["lat"][i]),
                    lon=float(lg["lon"][i]),
                    abs_alt=float(lg["abs_alt"][i]),
                    rel_alt=float(lg["rel_alt"][i]),
                    gimbal_yaw=float(_wrap(lg["gimbal_ypr"][i, 0])),
                    gimbal_pitch=float(lg["gimbal_ypr"][i, 1]),
                    gimbal_roll=float(lg["gimbal_ypr"][i, 2]),
                    flight_yaw=float(_wrap(lg["aircraft_ypr"][i, 0])),
                    flight_pitch=float(lg["aircraft_ypr"][i, 1]),
                    flight_roll=float(lg["aircraft_ypr"][i, 2]),
                    rtk_std=gnss_model.noise_sigma_m if rtk else None,
                ),
            )
        t_render += time.perf_counter() - t0
        _add_run(render_total, run)
        images_csv = sdir / "images.csv"
        cam_ypr = flight.sample(photo_times)["gimbal_ypr"]
        write_trajectory_csv(
            images_csv,
            np.arange(len(photo_times)),
            photo_times,
            start_utc,
            frame,
            pos,
            rot,
            cam_ypr,
            lg["true"]["aircraft_ypr"],
            lg["true"]["velocity"],
        )
        _prepend_names(images_csv, names)
        rec.update(
            {
                "images_dir": _rel(img_dir, out),
                "images_csv": _rel(images_csv, out),
                "images": len(names),
                "image_spacing_m": round(spacing, 4),
            }
        )

    if opts.survey != "none":
        t0 = time.perf_counter()
        csv_path = sdir / "flight-airdata.csv"
        write_airdata_csv(
            csv_path,
            _log_record(flight, frame, scene, logged, start_utc, opts, photo_times, rng),
            units=opts.csv_units,
        )
        rec["flight_log_csv"] = _rel(csv_path, out)
        rec["flight_log_start_s"] = round(float(flight.t[0]), 6)
        rec["flight_log_rate_hz"] = opts.log_rate_hz
        rec["flight_log_units"] = opts.csv_units
        t_logs += time.perf_counter() - t0
    rec["_log_time"] = t_logs

    def finish() -> tuple[float, dict]:
        """Wall seconds of rendering (here, plus the background job's) and the fields
        the background job adds to this record."""
        seconds, fields = t_render, {}
        for f in finishers:
            s, more = f()
            seconds += s
            fields.update(more)
        return seconds, fields

    rec["_finish"] = finish
    return rec


def _add_run(total: RenderRun, run: RenderRun) -> None:
    total.frames += run.frames
    total.render_seconds += run.render_seconds
    total.cpu_seconds += run.cpu_seconds
    total.wall_seconds += run.wall_seconds


class _TruthWriter:
    """Writes truth rasters in a background thread, in order (GDAL compresses without
    the GIL, so the caller computes the next step meanwhile). `write` returns the path
    at once; `wait` (and leaving the with block) waits and re-raises any error."""

    def __init__(self) -> None:
        self._executor = ThreadPoolExecutor(1, thread_name_prefix="slidewatch-truth")
        self._futures: list[Future] = []

    def write(self, path: Path, *args, **kwargs) -> Path:
        """`write_raster(path, *args, **kwargs)`, later."""
        self._futures.append(self._executor.submit(write_raster, path, *args, **kwargs))
        return Path(path)

    def wait(self) -> None:
        futures, self._futures = self._futures, []
        for f in futures:
            f.result()

    def __enter__(self) -> _TruthWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self._executor.shutdown(wait=True)
        if exc_type is None:
            self.wait()


def _wrap(a):
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


def _prepend_names(path: Path, names: list[str]) -> None:
    lines = path.read_text(encoding="utf-8").splitlines()
    out = ["image," + lines[0]] + [f"{n},{line}" for n, line in zip(names, lines[1:], strict=True)]
    path.write_text("\n".join(out) + "\n", encoding="utf-8")


def _log_record(
    flight: Flight,
    frame: SceneFrame,
    scene: Scene,
    logged,
    start_utc: datetime,
    opts: SimulationOptions,
    photo_times: np.ndarray,
    rng: np.random.Generator,
) -> LogRecord:
    dt = 1.0 / opts.log_rate_hz
    t_rows = np.arange(flight.t[0], flight.t[-1] + 1e-9, dt)
    lg = logged(t_rows - opts.log_time_offset_s)
    true = lg["true"]
    pos = true["position"]
    ground = scene.height_at(pos[:, 0], pos[:, 1])
    dist = np.hypot(pos[:, 0] - flight.home[0], pos[:, 1] - flight.home[1])
    is_video = (
        (t_rows >= 0.0) & (t_rows <= flight.duration)
        if opts.survey in ("video", "both")
        else np.zeros(t_rows.size, bool)
    )
    is_photo = np.zeros(t_rows.size, bool)
    if photo_times.size:
        idx = np.clip(np.searchsorted(t_rows, photo_times), 0, t_rows.size - 1)
        is_photo[idx] = True
    sats = np.clip(np.round(18 + np.cumsum(rng.normal(0, 0.05, t_rows.size))), 12, 24)
    if opts.gnss == "rtk":
        sats = sats + 14
    state = []
    take_off = flight.t[0] + 3.0
    for t, vz, z in zip(t_rows, true["velocity"][:, 2], pos[:, 2], strict=True):
        if t < take_off or (
            t > flight.duration + 2.0
            and z - flight.home[2] < 0.05
            and vz > -0.05
            and t > flight.duration + 4.0
        ):
            state.append("Motors_Off")
        elif t < 0 and vz > 0.3:
            state.append("AutoTakeoff")
        elif t > flight.duration + 2.0:
            state.append("AutoLanding")
        else:
            state.append("Waypoint")
    return LogRecord(
        time_ms=np.round((t_rows - t_rows[0]) * 1000.0).astype(np.int64),
        utc=[start_utc + timedelta(seconds=float(t)) for t in t_rows],
        lat=lg["lat"],
        lon=lg["lon"],
        rel_alt=lg["rel_alt"],
        abs_alt=lg["abs_alt"],
        ground_z=ground,
        home_z=float(flight.home[2]),
        vel_enu=true["velocity"],
        dist_home=dist,
        aircraft_ypr=lg["aircraft_ypr"],
        gimbal_ypr=lg["gimbal_ypr"],
        is_video=is_video,
        is_photo=is_photo,
        satellites=sats,
        state=state,
    )


def with_options(base: SimulationOptions, **changes) -> SimulationOptions:
    """A copy of `base` with some fields changed (None values are ignored)."""
    return replace(base, **{k: v for k, v in changes.items() if v is not None})


__all__ = [
    "SURVEY_MODES",
    "SimulationOptions",
    "rng_for",
    "simulate_scenario",
    "with_options",
]
