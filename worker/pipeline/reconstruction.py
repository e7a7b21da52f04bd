"""A survey from drone video (+ flight log) or an image set to a DSM and an orthophoto,
in six stages.

    ingest -> frames -> reconstruct -> georeference -> dsm -> orthophoto

The stages are declared once, as data (`RECONSTRUCTION_PIPELINE`, see stages.py): the
CLI, the job layer and the page's stage help come from there. Each stage is a function
over `work_dir` that reads the inputs and what earlier stages wrote there and
(re)writes its own outputs atomically, so each can run as its own Celery task, be
retried, and be run again with the same result. Every stage returns a typed result
(reconstruction_results.py), also written as `<stage>.json`, and later stages read those
files back typed. Layout of `work_dir`:

    ingest.json              ingest        inputs, log summary, video or image-set
                                           summary, intrinsics, prior time offset
    frames/frames.mkv        frames        video: kept frames at the processing size
    frames/frames.csv        frames        per decoded frame: t, sharpness, motion, kept
    frames/colour.mkv        frames        slam: the same frames in colour, for the
                                           orthophoto (twice the processing size)
    frames/stills/*.jpg      frames        sfm on video: frames at 3 fps, <= 2560 px
    frames.json              frames        counts, time offset (estimated from motion)
    reconstruct/map.npz      reconstruct   the map in the reconstruction's own frame
    reconstruct/sfm/         reconstruct   sfm: COLMAP database and model
    reconstruct.json         reconstruct   method, counts, timings, real-time factor
    georeference/map.npz     georeference  the map in the survey's UTM zone
    trajectory.csv           georeference  camera trajectory with timestamps (UTM)
    trajectory.geojson       georeference  the flight path in WGS84 (a survey product)
    georeference.json        georeference  CRS, per-segment fit, residuals, time offset
    points.ply               dsm           the cloud the DSM is made of (UTM, double)
    dsm.tif                  dsm           DSM, Cloud-Optimized GeoTIFF, nodata -9999
    dsm_filled.tif           dsm           0 measured, 1 filled by inpainting, 255 out
    dsm.png                  dsm           grey-scale export, on request (see dsm_export)
    dsm.json                 dsm           DSM figures
    orthophoto.tif           orthophoto    true orthophoto on the DSM, RGBA COG
    orthophoto.json          orthophoto    its figures (or why there is none)
    report.json              orthophoto    every stage's figures and timings in one file

Methods: `slam` (default for video) and `sfm` (pycolmap, the paper's OpenDroneMap
reference, and the only method for image sets); `auto` picks by input.

A video still uploading (`ReconstructionInputs.video_bytes`, the length it will have) is
processed as it arrives: ingest reads its header, frames decodes what has arrived and
waits for the rest (worker/pipeline/ingest/arriving.py). The frames stage takes the
video from the inputs it is given, else from ingest.json, so a finished upload may have
been moved between the two.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import rasterio

from worker.pipeline.atomic import atomic_path, write_text_atomic
from worker.pipeline.dsm_export import FILLED_MEASURED, DsmOptions, export_dsm
from worker.pipeline.errors import InputError
from worker.pipeline.footprints import overlap_figures, points_inside, survey_footprints
from worker.pipeline.frames import (
    COLOUR_VIDEO,
    FrameOptions,
    extract_still_frames,
    iter_prepared_frames,
    prefetched,
    prepare_video_frames,
    read_frame_scan,
    tracking_frames,
)
from worker.pipeline.georef import offset_residual_fn, position_accuracy, survey_epsg
from worker.pipeline.georef_map import MapGeorefOptions, georeference_map
from worker.pipeline.height_agreement import pair_agreement
from worker.pipeline.ingest.arriving import Arrival
from worker.pipeline.ingest.camera import CameraOverride, Intrinsics, resolve_intrinsics
from worker.pipeline.ingest.flight_log import FlightLog
from worker.pipeline.ingest.images import read_image_set
from worker.pipeline.ingest.read_log import read_flight_log
from worker.pipeline.ingest.recordings import VideoClues
from worker.pipeline.ingest.time_offset import (
    UNCERTAIN_OFFSET,
    OffsetMethod,
    PriorSource,
    TimeOffset,
    check_overlap,
    estimate_time_offset,
    prior_offset,
    refine_time_offset,
    weigh_rivals,
)
from worker.pipeline.ingest.video import probe_video
from worker.pipeline.orthophoto import (
    OrthophotoOptions,
    ViewImages,
    colour_view_size,
    still_view_images,
    stored_view_images,
    video_view_images,
    write_orthophoto,
)
from worker.pipeline.pair_adjustment import PairAdjustOptions, apply_planes, pair_planes
from worker.pipeline.pointcloud import (
    compact_rows,
    grid_outliers,
    statistical_outliers,
    write_ply,
)
from worker.pipeline.progress import ProgressFn, no_progress
from worker.pipeline.quality import failed_messages, survey_quality
from worker.pipeline.reconstruction_results import (
    DsmStageResult,
    FramesResult,
    GeoreferenceResult,
    IngestResult,
    OrthophotoStageResult,
    ReconstructionStageResult,
    ReconstructResult,
    plain,
)
from worker.pipeline.sfm import SfmOptions, run_sfm
from worker.pipeline.slam.densify import DensifyOptions, wide_pair_points
from worker.pipeline.slam.redensify import (
    KeyframePoses,
    RedensifyOptions,
    plan_redensify,
    redensify,
)
from worker.pipeline.slam.result import SparseMap
from worker.pipeline.slam.system import SlamOptions, run_slam
from worker.pipeline.slam.ties import TieOptions, keyframe_images, tie_flight_lines
from worker.pipeline.stages import COG_MEDIA_TYPE, GEOJSON, Output, Pipeline, StageSpec
from worker.pipeline.trajectory import trajectory_geojson, write_trajectory_csv

METHODS = ("auto", "slam", "sfm")

FRAMES_DIR = "frames"
STILLS_DIR = "frames/stills"
RECON_MAP = "reconstruct/map.npz"
SFM_DIR = "reconstruct/sfm"
GEOREF_MAP = "georeference/map.npz"
TRAJECTORY = "trajectory.csv"
TRAJECTORY_GEOJSON = "trajectory.geojson"
POINTS = "points.ply"
DSM = "dsm.tif"
ORTHOPHOTO = "orthophoto.tif"
REPORT = "report.json"


@dataclass
class ReconstructionInputs:
    video: str | None = None
    log: str | None = None
    images: str | None = None
    # The video is still uploading and will have this many bytes (None: it is complete).
    video_bytes: int | None = None
    video_stall_timeout_s: float = 600.0  # give up when no byte arrives for this long

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def paths(self) -> dict[str, str | None]:
        """The input paths, absolute (links are kept: their names are the user's)."""
        return {
            k: os.path.abspath(v) if v else None
            for k, v in (("video", self.video), ("log", self.log), ("images", self.images))
        }

    def video_arrival(self) -> Arrival | None:
        if self.video_bytes is None:
            return None
        return Arrival(self.video_bytes, self.video_stall_timeout_s)


@dataclass
class ReconstructionOptions:
    method: str = "auto"
    camera: CameraOverride = field(default_factory=CameraOverride)
    time_offset_s: float | None = None  # given by the user: not estimated
    angle_unit: str = "auto"
    # Of an SRT joined from several recordings, the one to use (1-based, as the log's
    # warning numbers them); None: the one that matches the video.
    recording: int | None = None
    frames: FrameOptions = field(default_factory=FrameOptions)
    slam: SlamOptions = field(default_factory=SlamOptions)
    ties: TieOptions = field(default_factory=TieOptions)  # slam: between flight lines
    sfm: SfmOptions = field(default_factory=SfmOptions)
    georef: MapGeorefOptions = field(default_factory=MapGeorefOptions)
    # slam: dense pairs matched again where the georeference moved their cameras
    redensify: RedensifyOptions = field(default_factory=RedensifyOptions)
    dsm: DsmOptions = field(default_factory=DsmOptions)
    # dense pairs' heights made to agree, one plane per pair (dsm stage)
    pair_adjustment: PairAdjustOptions = field(default_factory=PairAdjustOptions)
    orthophoto: OrthophotoOptions = field(default_factory=OrthophotoOptions)
    sparse_sor: bool = True  # open3d statistical outlier removal on the sparse cloud
    dense_sor: bool = False  # the same on the dense cloud (slow: 20 s per 2M points)
    dense_grid_k: float = 3.5  # robust per-cell height filter of the dense cloud

    def __post_init__(self) -> None:
        chosen = self.recording
        if chosen is not None and (type(chosen) is not int or chosen < 1):
            raise InputError(f"recording is a recording's number (1, 2, ...), not {chosen!r}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> ReconstructionOptions:
        return _from_dict(cls, data or {}, "reconstruction options")


def _from_dict(cls: type, data: dict[str, Any], where: str) -> Any:
    """Build a (nested) options dataclass from a dict; unknown keys fail clearly."""
    names = {f.name: f for f in dataclasses.fields(cls)}
    unknown = set(data) - set(names)
    if unknown:
        raise InputError(f"unknown {where}: {', '.join(sorted(unknown))}")
    defaults = cls()
    kwargs = {}
    for name, value in data.items():
        current = getattr(defaults, name)
        if dataclasses.is_dataclass(current) and isinstance(value, dict):
            kwargs[name] = _from_dict(type(current), value, f"{where} {name}")
        elif isinstance(current, tuple) and isinstance(value, list):
            kwargs[name] = tuple(value)
        else:
            kwargs[name] = value
    return cls(**kwargs)


# -- helpers ---------------------------------------------------------------------------
def _write_json(path: Path, data: dict[str, Any]) -> None:
    write_text_atomic(path, json.dumps(plain(data), indent=2, allow_nan=False))


def _read_json(work_dir: Path, stage: str) -> dict[str, Any]:
    path = Path(work_dir) / f"{stage}.json"
    if not path.is_file():
        raise InputError(f"the {stage} stage has not run in {work_dir}")
    return json.loads(path.read_text(encoding="utf-8"))


ResultT = TypeVar("ResultT", bound=ReconstructionStageResult)

# The stage that writes each result type's file.
_RESULT_STAGE: dict[type[ReconstructionStageResult], str] = {
    IngestResult: "ingest",
    FramesResult: "frames",
    ReconstructResult: "reconstruct",
    GeoreferenceResult: "georeference",
    DsmStageResult: "dsm",
    OrthophotoStageResult: "orthophoto",
}


def _read_result(work_dir: Path, kind: type[ResultT]) -> ResultT:
    """An earlier stage's result, read back from its `<stage>.json`."""
    return kind.from_dict(_read_json(work_dir, _RESULT_STAGE[kind]))


def _write_result(work_dir: Path, result: ReconstructionStageResult) -> None:
    _write_json(work_dir / f"{_RESULT_STAGE[type(result)]}.json", result.to_dict())


def _method(inputs: dict[str, Any], options: ReconstructionOptions) -> str:
    if options.method not in METHODS:
        raise InputError(f"unknown method {options.method!r}; use one of {METHODS}")
    if inputs.get("images"):
        if options.method == "slam":
            raise InputError(
                "the slam method reconstructs video; image sets are reconstructed with "
                "the sfm method"
            )
        return "sfm"
    return "slam" if options.method == "auto" else options.method


def _load_log(ingest: IngestResult, options: ReconstructionOptions) -> FlightLog:
    if ingest.image_set:
        return read_image_set(ingest.image_set).log
    # What the video says picks the same recording of a joined SRT as ingest did.
    log = ingest.inputs["log"]
    if log is None:
        raise InputError("ingest.json names no flight log")
    return read_flight_log(
        log,
        angle_unit=options.angle_unit,
        video=VideoClues.from_video_info(ingest.video),
        recording=options.recording,
    )


# -- stages ------------------------------------------------------------------------------
def ingest(
    inputs: ReconstructionInputs,
    work_dir: Path,
    options: ReconstructionOptions | None = None,
    progress: ProgressFn = no_progress,
) -> IngestResult:
    """Read and check every input; choose the intrinsics; the prior time offset."""
    start = time.perf_counter()
    options = options or ReconstructionOptions()
    work_dir = Path(work_dir)
    work_dir.mkdir(parents=True, exist_ok=True)
    given = inputs.paths()
    if given["images"] and (given["video"] or given["log"]):
        raise InputError("give either a video with its flight log, or an image set")
    if not given["images"] and not (given["video"] and given["log"]):
        raise InputError("a video needs its flight log (DJI SRT or a CSV export)")
    method = _method(given, options)
    out: dict[str, Any] = {"inputs": given, "method": method, "warnings": []}
    if given["images"]:
        image_set = read_image_set(given["images"])
        first = image_set.images[0]
        log = image_set.log
        intr = resolve_intrinsics(
            first.width,
            first.height,
            override=options.camera,
            exif_model=first.model,
            exif_focal_mm=first.focal_mm,
            focal_35mm=first.focal_35mm,
            exif_sensor_width_mm=first.sensor_width_mm,
        )
        out["images"] = image_set.to_dict()
        out["intrinsics_source"] = intr.to_dict()
        out["intrinsics"] = intr.to_dict()
        out["time_offset_prior"] = TimeOffset(
            0.0, 0.0, PriorSource.image_exif, OffsetMethod.prior
        ).to_dict()
        out["warnings"] += image_set.warnings
    else:
        video = probe_video(given["video"], inputs.video_arrival())
        progress(0.3)
        log = read_flight_log(
            given["log"],
            angle_unit=options.angle_unit,
            video=VideoClues.from_video_info(video.to_dict()),
            recording=options.recording,
        )
        focal35 = log.meta.get("focal_len_35mm")
        intr = resolve_intrinsics(
            video.width, video.height, override=options.camera, focal_35mm=focal35
        )
        processing = intr.scaled(options.frames.width, options.frames.height)
        out["video"] = video.to_dict()
        out["intrinsics_source"] = intr.to_dict()
        out["intrinsics"] = processing.to_dict()
        prior = prior_offset(log, video.duration_s, video.creation_time)
        if options.time_offset_s is not None:
            offset = options.time_offset_s
            prior = TimeOffset(offset, offset, PriorSource.user, OffsetMethod.user)
        if prior.prior_source != PriorSource.log_start and video.duration_s:
            name = Path(given["video"]).name
            if prior.prior_source == PriorSource.creation_time:
                # Some cameras stamp the end of the recording, not its start.
                try:
                    check_overlap(log, prior.offset_s, video.duration_s, video_name=name)
                except InputError:
                    end_stamped = prior.offset_s - video.duration_s
                    check_overlap(log, end_stamped, video.duration_s, video_name=name)
                    prior = TimeOffset(
                        end_stamped,
                        end_stamped,
                        PriorSource.creation_time,
                        OffsetMethod.prior,
                        warnings=["the video's creation time is its end; offset adjusted"],
                    )
            else:
                check_overlap(log, prior.offset_s, video.duration_s, video_name=name)
        out["time_offset_prior"] = prior.to_dict()
        out["warnings"] += prior.warnings
        _check_readout(processing, video.fps)
        out["warnings"] += _rolling_shutter_notes(processing, method, log)
    out["log"] = log.to_dict()
    out["warnings"] += log.warnings + intr.warnings
    out["crs"] = f"EPSG:{survey_epsg(log)}"
    out["seconds"] = round(time.perf_counter() - start, 3)
    result = IngestResult(**out)
    _write_result(work_dir, result)
    progress(1.0)
    return result


# A readout typical of consumer drone video (10-35 ms), for the warning's example.
TYPICAL_READOUT_S = 0.03


def _check_readout(intr: Intrinsics, fps: float) -> None:
    """A frame's rows are read within the frame: a longer readout is a mistake."""
    if fps > 0 and intr.readout_s >= 1.0 / fps:
        raise InputError(
            f"the camera's readout_ms {intr.readout_s * 1000:g} is not shorter than a frame "
            f"({1000.0 / fps:.1f} ms at {fps:g} frames per second)"
        )


def _rolling_shutter_notes(intr: Intrinsics, method: str, log: FlightLog) -> list[str]:
    """Warnings on the video's rolling shutter: a readout the method does not use, or,
    where none is given, what a typical one would cost this flight
    (slam/rolling_shutter.py: along the track, heights off by fy V readout / (H - 1))."""
    readout = intr.readout_s
    if readout > 0:
        if method == "slam":
            return []
        return [
            f"the camera's readout of {readout * 1000:g} ms is not used: the {method} method "
            "does not model a rolling shutter (the slam method does)"
        ]
    speed = log.median_ground_speed()
    if method != "slam" or not np.isfinite(speed) or speed <= 0:
        return []
    off = intr.fy * speed * TYPICAL_READOUT_S / max(intr.height - 1, 1)
    return [
        f"the camera's readout time is not given (camera readout_ms): a rolling shutter is "
        f"not modelled. Drone video is usually read row by row over 10-35 ms; at this "
        f"flight's {speed:.1f} m/s a {TYPICAL_READOUT_S * 1000:.0f}-ms readout would put "
        f"heights about {off:.2f} m off along the track"
    ]


def frames(
    work_dir: Path,
    options: ReconstructionOptions | None = None,
    progress: ProgressFn = no_progress,
    inputs: ReconstructionInputs | None = None,
) -> FramesResult:
    """Decode and filter the video (the one in `inputs` when given, else ingest's); estimate
    the time offset from image motion."""
    start = time.perf_counter()
    options = options or ReconstructionOptions()
    work_dir = Path(work_dir)
    ing = _read_result(work_dir, IngestResult)
    method = ing.method
    out: dict[str, Any] = {"method": method}
    if ing.image_set:
        out["time_offset"] = ing.time_offset_prior
        image_set = read_image_set(ing.image_set)
        width = image_set.images[0].width
        if width > options.sfm.max_width:
            stills = _downscale_images(
                [m.path for m in image_set.images], work_dir / STILLS_DIR, options.sfm.max_width
            )
            out["stills"] = stills
            out["still_times"] = image_set.image_times.tolist()
            out["note"] = f"images reduced to {stills['width']} px wide for SfM"
        else:
            out["note"] = "image set: the images are used as they are"
    else:
        video = inputs.paths()["video"] if inputs and inputs.video else ing.inputs["video"]
        if video is None:
            raise InputError("ingest.json names no video")
        arrival = inputs.video_arrival() if inputs and inputs.video else None
        weight = 0.6 if method == "sfm" else 1.0
        slam = options.slam
        colour_size = None
        if method == "slam" and options.orthophoto.enabled:
            # The orthophoto's views are keyframes, chosen among the stored frames.
            # The video's size as ingest probed it (an upload still arriving is not
            # probed twice).
            probed = ing.video or probe_video(Path(video), arrival).to_dict()
            colour_size = colour_view_size(
                (int(probed["width"]), int(probed["height"])),
                (options.frames.width, options.frames.height),
                options.orthophoto.colour_scale,
            )
        result = prepare_video_frames(
            Path(video),
            work_dir / FRAMES_DIR,
            options.frames,
            lambda f: progress(weight * f),
            # slam tracks a subset of the frames: store only those (sfm reads stills).
            track_step_px=slam.track_step_px if method == "slam" else 0.0,
            track_max_gap_s=slam.track_max_gap_s,
            arrival=arrival,
            colour_size=colour_size,
        )
        out["frames"] = result.to_dict()
        prior = TimeOffset(**{**ing.time_offset_prior, "warnings": []})
        if prior.method == OffsetMethod.user:
            offset = prior
        else:
            log = _load_log(ing, options)
            scan = result.scan
            estimate = estimate_time_offset(
                log, scan.t[scan.kept], scan.motion_px_s[scan.kept], prior
            )
            # SRT clocks are the video's: the estimate is reported, not used.
            offset = prior if prior.prior_source == PriorSource.srt else estimate
            out["time_offset_estimate"] = estimate.to_dict()
            duration = float(scan.t[-1] - scan.t[0]) if scan.t.size > 1 else 0.0
            if duration:
                check_overlap(log, offset.offset_s, duration, video_name=Path(video).name)
        out["time_offset"] = offset.to_dict()
        if method == "sfm":
            stills = extract_still_frames(
                Path(video),
                work_dir / STILLS_DIR,
                fps=options.sfm.fps,
                max_width=options.sfm.max_width,
                progress=lambda f: progress(0.6 + 0.4 * f),
                arrival=arrival,
            )
            out["stills"] = stills.to_dict()
            out["still_times"] = stills.times
    out["seconds"] = round(time.perf_counter() - start, 3)
    result = FramesResult(**out)
    _write_result(work_dir, result)
    progress(1.0)
    return result


def _downscale_images(paths: list[str], out_dir: Path, max_width: int) -> dict[str, Any]:
    """JPEG copies at most `max_width` wide, in capture order (frame_00000.jpg ...)."""
    import cv2

    out_dir.mkdir(parents=True, exist_ok=True)
    size = None
    for i, path in enumerate(paths):
        image = cv2.imread(path, cv2.IMREAD_COLOR)
        if image is None:
            raise InputError(f"{Path(path).name}: the image cannot be decoded")
        h, w = image.shape[:2]
        size = (max_width, round(h * max_width / w))
        small = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        with atomic_path(out_dir / f"frame_{i:05d}.jpg") as tmp:
            ok, data = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, 92])
            if not ok:
                raise RuntimeError("JPEG encoding failed")
            tmp.write_bytes(data.tobytes())
    return {"frames": len(paths), "width": size[0], "height": size[1]}


def reconstruct(
    work_dir: Path,
    options: ReconstructionOptions | None = None,
    progress: ProgressFn = no_progress,
) -> ReconstructResult:
    """The map in the reconstruction's own frame (slam), or in the GNSS frame (sfm)."""
    start = time.perf_counter()
    options = options or ReconstructionOptions()
    work_dir = Path(work_dir)
    ing = _read_result(work_dir, IngestResult)
    fr = _read_result(work_dir, FramesResult)
    method = ing.method
    intr = Intrinsics.from_dict(ing.intrinsics)
    out: dict[str, Any] = {"method": method}
    if method == "slam":
        scan = read_frame_scan(work_dir / FRAMES_DIR / "frames.csv")
        wanted = set(
            tracking_frames(scan, options.slam.track_step_px, options.slam.track_max_gap_s).tolist()
        )
        if not wanted <= set(scan.index[scan.stored].tolist()):
            raise InputError(
                "the frames stage stored the frames of other tracking options "
                "(slam track_step_px, track_max_gap_s): run the frames stage again"
            )
        stream = (
            (f.t, f.index, f.image)
            for f in prefetched(iter_prepared_frames(work_dir / FRAMES_DIR))
            if f.index in wanted
        )
        sparse = run_slam(stream, intr, options.slam, progress, total_frames=len(wanted))
        out["tracked_frames"] = len(wanted)
        if options.ties.enabled:
            tie_start = time.perf_counter()
            images = keyframe_images(sparse, iter_prepared_frames(work_dir / FRAMES_DIR))
            ties = tie_flight_lines(sparse, images.get, options.ties)
            out["ties"] = {**ties.to_dict(), "seconds": round(time.perf_counter() - tie_start, 3)}
        duration = float(scan.t[-1] - scan.t[0]) if scan.t.size > 1 else 0.0
    else:
        log = _load_log(ing, options)
        offset = float(fr.time_offset["offset_s"])
        if ing.image_set and fr.stills is None:
            image_set = read_image_set(ing.image_set)
            paths = [m.path for m in image_set.images]
            times = image_set.image_times.tolist()
            still_intr = intr
        else:
            paths = sorted(str(p) for p in (work_dir / STILLS_DIR).glob("*.jpg"))
            if fr.stills is None or fr.still_times is None:
                raise InputError("the frames stage wrote no stills: run it again with sfm")
            times = fr.still_times
            stills = fr.stills
            source = Intrinsics.from_dict(ing.intrinsics_source)
            still_intr = source.scaled(stills["width"], stills["height"])
        sparse, sfm_report = run_sfm(
            paths, times, log, offset, still_intr, work_dir / SFM_DIR, options.sfm, progress
        )
        out["sfm"] = sfm_report
        duration = float(times[-1] - times[0]) if len(times) > 1 else 0.0
    sparse.save(work_dir / RECON_MAP)
    seconds = time.perf_counter() - start
    out.update(
        {
            "keyframes": int(sparse.kf_t.size),
            "frames_with_pose": int(sparse.fr_t.size),
            "sparse_points": int(sparse.point_xyz.shape[0]),
            "dense_points": int(sparse.dense_xyz.shape[0]),
            "segments": len(sparse.segments),
            "stats": sparse.stats,
            "video_seconds": duration,
            "seconds": round(seconds, 3),
            "real_time_factor": round(duration / seconds, 3) if seconds > 0 else None,
        }
    )
    if sparse.kf_t.size < 2:
        raise InputError(
            "the reconstruction failed: too few frames could be tracked (texture-poor, "
            "blurred or too fast a video?)"
        )
    result = ReconstructResult(**out)
    _write_result(work_dir, result)
    progress(1.0)
    return result


def georeference(
    work_dir: Path,
    options: ReconstructionOptions | None = None,
    progress: ProgressFn = no_progress,
) -> GeoreferenceResult:
    """Fuse the trajectory with the log: the map and trajectory in the UTM zone."""
    start = time.perf_counter()
    options = options or ReconstructionOptions()
    work_dir = Path(work_dir)
    ing = _read_result(work_dir, IngestResult)
    fr = _read_result(work_dir, FramesResult)
    sparse = SparseMap.load(work_dir / RECON_MAP)
    log = _load_log(ing, options)
    offset = TimeOffset(**{**fr.time_offset, "warnings": list(fr.time_offset["warnings"])})
    out: dict[str, Any] = {}
    # The trajectory fit is the finest estimate (measured: within 10 ms where image
    # motion was 15-90 ms off); SRT clocks and user offsets are kept as they are.
    kept = (PriorSource.srt, PriorSource.image_exif)
    if offset.method != OffsetMethod.user and offset.prior_source not in kept:
        longest = max(sparse.segments, key=lambda s: int((sparse.fr_segment == s).sum()))
        traj = sparse.trajectory(longest)
        traj = traj.subset(np.arange(len(traj)) % max(1, len(traj) // 400) == 0)
        residual_at = offset_residual_fn(traj, log)
        offset = weigh_rivals(refine_time_offset(offset, traj.t, residual_at), residual_at)
    out["time_offset"] = offset.to_dict()
    progress(0.2)
    photos = None
    if ing.image_set:
        # Photo sets get the robust fit, which names the photos whose GPS is off.
        image_set = read_image_set(ing.image_set)
        photos = {
            float(t): Path(m.path).name
            for t, m in zip(image_set.image_times.tolist(), image_set.images, strict=True)
            if np.isfinite(t)
        }
    hold = offset.method == OffsetMethod.user or offset.prior_source in kept
    tracked = KeyframePoses.of(sparse)
    fit = georeference_map(sparse, log, offset.offset_s, options.georef, photos, hold_offset=hold)
    if fit.adjusted_offset_s is not None:
        offset.offset_s = fit.adjusted_offset_s
        offset.method = OffsetMethod.bundle_adjustment
        out["time_offset"] = offset.to_dict()
    progress(0.8)
    if ing.method == "slam" and options.redensify.enabled:
        # The positions' accuracy as the log states it or the user declared it.
        sigma = position_accuracy(log, options.georef.georef)
        horizontal = None if sigma is None else float(max(sigma[:2]))
        out["redensified"] = _redensify(work_dir, tracked, sparse, options, horizontal)
    sparse.save(work_dir / GEOREF_MAP)
    traj = sparse.trajectory()
    traj.crs = fit.crs
    write_trajectory_csv(work_dir / TRAJECTORY, traj)
    write_text_atomic(work_dir / TRAJECTORY_GEOJSON, json.dumps(trajectory_geojson(traj)))
    out.update(fit.to_dict())
    out["seconds"] = round(time.perf_counter() - start, 3)
    result = GeoreferenceResult(**out)
    _write_result(work_dir, result)
    progress(1.0)
    return result


def _redensify(
    work_dir: Path,
    tracked: KeyframePoses,
    sparse: SparseMap,
    options: ReconstructionOptions,
    log_sigma_m: float | None,
) -> dict[str, Any]:
    """Match again the dense pairs the georeference moved (see slam/redensify.py), with
    their keyframes' images read back from the frames the frames stage stored."""
    start = time.perf_counter()
    plan = plan_redensify(tracked, sparse, options.redensify, options.slam.densify, log_sigma_m)
    needed = plan.keyframes()
    images: dict[int, np.ndarray] = {}
    if needed:
        times = sparse.kf_t[sorted(needed)]

        def wanted(t: float) -> bool:
            # As keyframe_images matches them: within 0.1 ms.
            return bool(np.abs(times - t).min() < 1e-4)

        frames = iter_prepared_frames(work_dir / FRAMES_DIR, wanted=wanted)
        images = {i: image for i, image in keyframe_images(sparse, frames).items() if i in needed}
    report = redensify(sparse, images, plan, options.slam.densify)
    return {**report.to_dict(), "seconds": round(time.perf_counter() - start, 3)}


def _snap_125(value: float) -> float:
    """The 1-2-5 step nearest to value on a log scale."""
    exponent = np.floor(np.log10(value))
    candidates = np.array([1.0, 2.0, 5.0, 10.0]) * 10**exponent
    return float(candidates[np.argmin(np.abs(np.log(candidates / value)))])


def dsm(
    work_dir: Path,
    options: ReconstructionOptions | None = None,
    progress: ProgressFn = no_progress,
) -> DsmStageResult:
    """Clean the cloud, write points.ply, grid and fill the DSM, write report.json."""
    start = time.perf_counter()
    options = options or ReconstructionOptions()
    work_dir = Path(work_dir)
    geo = _read_result(work_dir, GeoreferenceResult)
    sparse = SparseMap.load(work_dir / GEOREF_MAP)
    crs = geo.crs
    pts_sparse = sparse.point_xyz
    n_dense = len(sparse.dense_xyz)
    out: dict[str, Any] = {"sparse_points": len(pts_sparse), "dense_points": n_dense}
    if options.sparse_sor and len(pts_sparse):
        keep = statistical_outliers(pts_sparse)
        out["sparse_outliers_removed"] = int((~keep).sum())
        pts_sparse = pts_sparse[keep]
    progress(0.2)
    gsd = _ground_sampling_distance(sparse)
    # Cells of 1.5 GSD, but no finer than the dense points lie: finer cells are mostly
    # empty between them and the DSM mostly inpainted.
    spacing = _dense_point_spacing(sparse, gsd, options)
    resolution = options.dsm.resolution_m or _snap_125(max(1.5 * gsd, spacing))
    out["gsd_m"] = round(gsd, 4)
    # One array for the cloud: the dense points in the map frame, filtered in place, then
    # the sparse ones (fresh memory for millions of points costs more than the copies).
    cloud = np.empty((n_dense + len(pts_sparse), 3))
    n = n_dense
    if n_dense:
        sparse.dense_points(out=cloud[:n_dense])
        pair_kf, pair_partner = sparse.dense_kf, sparse.dense_partner
        # Only SLAM matches each keyframe twice (the sfm method's pairs are one per view).
        slam = _read_result(work_dir, IngestResult).method == "slam"
        if slam and options.slam.densify.wide_baseline_ratio is not None:
            keep = wide_pair_points(cloud[:n], sparse.dense_wide_pair(), resolution)
            out["dense_pair_choice_removed"] = int((~keep).sum())
            n = compact_rows(cloud, keep)
            pair_kf, pair_partner = pair_kf[keep], pair_partner[keep]
            del keep
        # Before the outlier filters and the pairs' planes, on the points the DSM is made
        # of (compaction keeps the pairs' order, see height_agreement): the check it
        # feeds was measured against the truth so (a lower bound of the DSM's error,
        # which the planes bring down).
        agreement = pair_agreement(cloud[:n], pair_kf, pair_partner, resolution)
        if agreement is not None:
            out["height_agreement"] = agreement
        if options.pair_adjustment.enabled and n:
            pair = pair_kf.astype(np.int64) * (int(pair_partner.max()) + 1) + pair_partner
            planes = pair_planes(cloud[:n], pair, resolution, options.pair_adjustment)
            apply_planes(cloud[:n], pair, planes)
            del pair
            out["pair_adjustment"] = planes.to_dict()
        del pair_kf, pair_partner
        if options.dense_sor:
            keep = statistical_outliers(cloud[:n])
            out["dense_sor_removed"] = int((~keep).sum())
            n = compact_rows(cloud, keep)
        keep = grid_outliers(cloud[:n], 4 * resolution, k=options.dense_grid_k)
        out["dense_grid_removed"] = int((~keep).sum())
        n = compact_rows(cloud, keep)
        del keep
    cloud[n : n + len(pts_sparse)] = pts_sparse
    n += len(pts_sparse)
    dsm_options = dataclasses.replace(options.dsm, resolution_m=resolution)
    # The DSM covers what the cameras saw: points beyond every camera's footprint (a bad
    # segment, a wrong match) are dropped and cannot stretch the raster, whose extent is
    # then that of the points kept (the footprints' own reach is wider: a raster of it
    # would be mostly empty at its edges).
    seen = survey_footprints(
        sparse, resolution, min_baseline_ratio=options.slam.densify.min_baseline_ratio
    )
    if seen is not None:
        keep = points_inside(cloud[:n], seen.reach, resolution)
        out["points_outside_footprint"] = int((~keep).sum())
        n = compact_rows(cloud, keep)
        del keep
    points = cloud[:n]
    if len(points) < 10:
        raise InputError("the reconstruction has too few points for a DSM")
    progress(0.4)
    # points.ply is written by a second thread while the DSM is gridded (file writes
    # release the GIL); neither changes `points`.
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="ply") as pool:
        ply = pool.submit(write_ply, work_dir / POINTS, points, comment=f"crs {crs}")
        raster = export_dsm(points, crs, work_dir, dsm_options, name="dsm")
        ply.result()
    out["dsm"] = raster.to_dict()
    out["points"] = len(points)
    if seen is not None:
        with rasterio.open(raster.filled_mask_path) as src:
            measured = src.read(1) == FILLED_MEASURED
            transform = src.transform
        area, coverage = overlap_figures(seen.viewpoints, measured, transform)
        out["overlap_area_m2"] = round(area, 2)
        # Judged against its bound by the survey's quality verdict (quality.py), which
        # warns in the report.
        out["overlap_coverage"] = None if coverage is None else round(coverage, 4)
    out["seconds"] = round(time.perf_counter() - start, 3)
    result = DsmStageResult(**out)
    _write_result(work_dir, result)
    progress(1.0)
    return result


def orthophoto(
    work_dir: Path,
    options: ReconstructionOptions | None = None,
    progress: ProgressFn = no_progress,
    inputs: ReconstructionInputs | None = None,
) -> OrthophotoStageResult:
    """The true orthophoto on the DSM (orthophoto.py), then report.json. A survey whose
    imagery cannot be read again keeps its DSM: the stage says why there is no
    orthophoto, in its warnings and the report, and does not fail the survey."""
    start = time.perf_counter()
    options = options or ReconstructionOptions()
    work_dir = Path(work_dir)
    out: dict[str, Any] = {"warnings": []}
    (work_dir / ORTHOPHOTO).unlink(missing_ok=True)  # a rerun never shows an older one
    if not options.orthophoto.enabled:
        out["warnings"].append("no orthophoto: it was turned off in the survey's options")
    else:
        ing = _read_result(work_dir, IngestResult)
        sparse = SparseMap.load(work_dir / GEOREF_MAP)
        try:
            source = _view_images(work_dir, ing, sparse, options, inputs)
            made = write_orthophoto(
                work_dir,
                sparse,
                work_dir / DSM,
                source,
                work_dir / ORTHOPHOTO,
                options.orthophoto,
                Intrinsics.from_dict(ing.intrinsics).dist,
                progress,
            )
        except InputError as exc:
            out["warnings"].append(f"no orthophoto: {exc}")
        else:
            out["orthophoto"] = made.to_dict()
            out["warnings"] += made.warnings
    out["seconds"] = round(time.perf_counter() - start, 3)
    result = OrthophotoStageResult(**out)
    _write_result(work_dir, result)
    write_report(work_dir)
    progress(1.0)
    return result


def _view_images(
    work_dir: Path,
    ing: IngestResult,
    sparse: SparseMap,
    options: ReconstructionOptions,
    inputs: ReconstructionInputs | None,
) -> ViewImages:
    """Where the keyframes' colours come from: the images the map was made of (sfm's
    stills, a photo set), or for slam the frames stage's colour copy of its frames
    (else, in a work folder made before that copy, the survey's video)."""
    fr = _read_result(work_dir, FramesResult)
    if ing.method == "sfm" or ing.image_set:
        if fr.stills is not None and fr.still_times is not None:
            paths = sorted(str(p) for p in (work_dir / STILLS_DIR).glob("*.jpg"))
            return still_view_images(paths, fr.still_times, sparse)
        if ing.image_set:
            image_set = read_image_set(ing.image_set)
            paths = [m.path for m in image_set.images]
            return still_view_images(paths, image_set.image_times.tolist(), sparse)
        raise InputError("the frames stage wrote no stills to colour the orthophoto from")
    scan = read_frame_scan(work_dir / FRAMES_DIR / "frames.csv")
    frames = fr.frames or {}
    colour_size = frames.get("colour_size")
    if colour_size and (work_dir / FRAMES_DIR / COLOUR_VIDEO).is_file():
        return stored_view_images(
            work_dir / FRAMES_DIR,
            (int(colour_size[0]), int(colour_size[1])),
            sparse,
            scan,
            float(frames.get("fps") or 30.0),
        )
    video = inputs.paths()["video"] if inputs and inputs.video else ing.inputs["video"]
    if video is None or not Path(video).is_file():
        raise InputError("the survey's video is no longer where ingest read it")
    return video_view_images(Path(video), sparse, scan, options.orthophoto.colour_scale)


def _dense_point_spacing(sparse: SparseMap, gsd: float, options: ReconstructionOptions) -> float:
    """How far apart an SfM map's dense points lie on the ground: SGBM keeps every
    `stride`-th pixel of images reduced to `dense_width` (a 4000 px photo at 1280 px and
    stride 2 gives one point per 6 GSD). 0 for a SLAM map, which densifies at the
    processing size, one point per 2 GSD, where cells of 1.5 GSD are kept."""
    if "sfm" not in sparse.stats or sparse.size[0] <= 0:
        return 0.0
    scale = min(1.0, options.sfm.dense_width / sparse.size[0])
    return gsd / scale * DensifyOptions().stride


def _ground_sampling_distance(sparse: SparseMap) -> float:
    """Median camera height above the median ground height, over the focal length."""
    if sparse.point_xyz.size == 0 or sparse.kf_t.size == 0:
        return 0.1
    height = float(np.median(sparse.kf_centres()[:, 2]) - np.median(sparse.point_xyz[:, 2]))
    return max(abs(height), 0.5) / float(sparse.k[0, 0])


def write_report(work_dir: Path) -> dict[str, Any]:
    """report.json: what every stage that ran reported, the headline figures, the
    survey's quality verdict (`quality`, see quality.py) and every stage's warnings
    gathered in `warnings` (what the survey's API answer shows), each check the survey
    failed among them."""
    work_dir = Path(work_dir)
    stages = {}
    for stage in STAGES:
        path = work_dir / f"{stage}.json"
        if path.is_file():
            stages[stage] = json.loads(path.read_text(encoding="utf-8"))
    rec = stages.get("reconstruct", {})
    geo = stages.get("georeference", {})
    # Every warning of the stages in one list, each once, in stage order: a stage's own
    # (ingest's holds the flight log's: skipped blocks with their lines, the recording of
    # a joined SRT that was used) and those of the parts it reports (the log summary, the
    # time offset, SfM), which repeat some of them.
    warnings: list[str] = []
    for result in stages.values():
        parts = [result, *(v for v in result.values() if isinstance(v, dict))]
        warnings += [w for part in parts for w in part.get("warnings") or []]
    final_offset = geo.get("time_offset") or {}
    if "ambiguous_reason" in final_offset and final_offset["ambiguous_reason"] is None:
        # The offset the georeference settled supersedes what ingest and frames said of it.
        warnings = [w for w in warnings if not w.startswith(UNCERTAIN_OFFSET)]
    # A survey that misses its quality bounds says so in its warnings too, which is what
    # the survey's API answer and the page show of the report.
    quality = survey_quality(stages)
    warnings += failed_messages(quality)
    report = {
        "method": stages.get("ingest", {}).get("method"),
        "crs": geo.get("crs"),
        "timings_s": {s: d.get("seconds") for s, d in stages.items()},
        "total_s": round(sum(d.get("seconds") or 0.0 for d in stages.values()), 3),
        "real_time_factor": rec.get("real_time_factor"),
        "time_offset_s": geo.get("time_offset", {}).get("offset_s"),
        "residuals_m": [
            {"segment": s["segment"], **s.get("residuals_after_m", {})}
            for s in geo.get("segments", [])
        ],
        # Photo sets: the photos left out of the georeference, with their residuals.
        **(
            {"photo_outliers": [p for p in geo["photos"] if p["status"] == "outlier"]}
            if "photos" in geo
            else {}
        ),
        "quality": quality,
        "warnings": list(dict.fromkeys(warnings)),
        "stages": stages,
    }
    _write_json(work_dir / REPORT, report)
    return report


@dataclass
class ReconstructionContext:
    """What a reconstruction stage reads: the work folder, the options and the inputs
    (ingest needs them; frames takes the video from them when given)."""

    work_dir: Path
    options: ReconstructionOptions = field(default_factory=ReconstructionOptions)
    inputs: ReconstructionInputs | None = None


def _ingest_stage(context: ReconstructionContext, progress: ProgressFn) -> IngestResult:
    if context.inputs is None:
        raise InputError("the ingest stage needs the inputs")
    return ingest(context.inputs, context.work_dir, context.options, progress)


# Weights: shares of the progress bar from measured times (reconstruction dominates).
RECONSTRUCTION_PIPELINE: Pipeline[ReconstructionContext] = Pipeline(
    "reconstruction",
    (
        StageSpec(
            name="ingest",
            run=_ingest_stage,
            help="reading video and log",
            outputs=(Output("ingest.json"),),
            weight=0.02,
        ),
        StageSpec(
            name="frames",
            run=lambda c, p: frames(c.work_dir, c.options, p, c.inputs),
            help="choosing frames",
            inputs=("ingest.json",),
            outputs=(Output(FRAMES_DIR), Output("frames.json")),
            weight=0.2,
        ),
        StageSpec(
            name="reconstruct",
            run=lambda c, p: reconstruct(c.work_dir, c.options, p),
            help="3-D reconstruction",
            inputs=("ingest.json", "frames.json"),
            outputs=(Output(RECON_MAP), Output("reconstruct.json")),
            weight=0.55,
        ),
        StageSpec(
            name="georeference",
            run=lambda c, p: georeference(c.work_dir, c.options, p),
            help="onto the ground",
            inputs=("ingest.json", "frames.json", RECON_MAP),
            outputs=(
                Output(GEOREF_MAP),
                Output(TRAJECTORY),
                Output(TRAJECTORY_GEOJSON, "trajectory", GEOJSON),
                Output("georeference.json"),
            ),
            weight=0.08,
        ),
        StageSpec(
            name="dsm",
            run=lambda c, p: dsm(c.work_dir, c.options, p),
            help="DSM from the points",
            inputs=("georeference.json", GEOREF_MAP),
            outputs=(
                Output(DSM, "dsm", COG_MEDIA_TYPE),
                Output(POINTS, "points", "application/vnd.ply"),
                Output("dsm.json"),
            ),
            weight=0.15,
        ),
        StageSpec(
            name="orthophoto",
            run=lambda c, p: orthophoto(c.work_dir, c.options, p, c.inputs),
            help="orthophoto from the frames",
            inputs=("ingest.json", "frames.json", GEOREF_MAP, DSM),
            outputs=(
                Output(ORTHOPHOTO, "orthophoto", COG_MEDIA_TYPE, optional=True),
                Output(REPORT, "report", "application/json"),
                Output("orthophoto.json"),
            ),
            weight=0.06,
        ),
    ),
)
STAGES = RECONSTRUCTION_PIPELINE.names


def run_stage(
    stage: str,
    work_dir: Path,
    options: ReconstructionOptions | None = None,
    inputs: ReconstructionInputs | None = None,
    progress: ProgressFn = no_progress,
) -> dict[str, Any]:
    """Run one stage by name (ingest needs `inputs`; frames takes the video from them)."""
    context = ReconstructionContext(Path(work_dir), options or ReconstructionOptions(), inputs)
    return RECONSTRUCTION_PIPELINE.run_stage(stage, context, progress)


@dataclass
class ReconstructionResult:
    work_dir: Path
    results: dict[str, dict[str, Any]]
    seconds: float

    @property
    def dsm_path(self) -> Path:
        return self.work_dir / DSM

    def summary(self) -> dict[str, Any]:
        rec = self.results.get("reconstruct", {})
        geo = self.results.get("georeference", {})
        dsm_res = self.results.get("dsm", {}).get("dsm", {})
        return {
            "method": rec.get("method"),
            "dsm": str(self.dsm_path),
            "crs": geo.get("crs"),
            "resolution_m": dsm_res.get("resolution_m"),
            "completeness": dsm_res.get("completeness"),
            "real_time_factor": rec.get("real_time_factor"),
            "seconds": round(self.seconds, 2),
        }


def reconstruct_survey(
    inputs: ReconstructionInputs,
    work_dir: Path,
    options: ReconstructionOptions | None = None,
    progress: ProgressFn = no_progress,
    from_stage: str | None = None,
) -> ReconstructionResult:
    """Every stage in order (from `from_stage` on: the earlier ones must have run)."""
    context = ReconstructionContext(Path(work_dir), options or ReconstructionOptions(), inputs)
    run = RECONSTRUCTION_PIPELINE.run(context, progress, from_stage)
    return ReconstructionResult(run.work_dir, run.results, run.seconds)
