"""`slidewatch reconstruct`: a DSM from drone video + flight log, or from an image set.

    slidewatch reconstruct --video V.mp4 --log L.srt --out DIR [--method slam|sfm]
    slidewatch reconstruct --images DIR --out DIR

Writes DIR/dsm.tif, DIR/points.ply, DIR/trajectory.csv, DIR/trajectory.geojson and
DIR/report.json (and every stage's working files, see worker/pipeline/reconstruction.py);
prints a one-line JSON summary. Unusable input exits with status 2 and a message that
says what is wrong.
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from worker.pipeline.errors import InputError
from worker.pipeline.georef import METHODS as GEOREF_METHODS
from worker.pipeline.ingest.camera import CameraOverride
from worker.pipeline.reconstruction import (
    METHODS,
    STAGES,
    ReconstructionInputs,
    ReconstructionOptions,
    reconstruct_survey,
)

EXIT_INPUT_ERROR = 2


@click.command("reconstruct")
@click.option("--video", type=click.Path(path_type=Path), help="Drone video (MP4/MOV).")
@click.option(
    "--log",
    "log_path",
    type=click.Path(path_type=Path),
    help="Flight log: DJI SRT, AirData/PhantomHelp/Litchi CSV, or a generic CSV.",
)
@click.option("--images", type=click.Path(path_type=Path), help="Folder of geotagged JPEG images.")
@click.option("--out", "out_dir", required=True, type=click.Path(path_type=Path))
@click.option("--method", type=click.Choice(METHODS), default="auto", show_default=True)
@click.option(
    "--georef",
    type=click.Choice(GEOREF_METHODS),
    default="similarity",
    show_default=True,
    help="paper4: the paper's four-point transform (reference).",
)
@click.option("--resolution", type=float, default=None, help="DSM pixel size in metres.")
@click.option("--median/--mean", default=False, help="Cell statistic of the DSM.")
@click.option("--png/--no-png", default=False, help="Also write the grey-scale DSM PNG.")
@click.option("--camera", default=None, help="Camera model (EXIF code or table name).")
@click.option("--fx", type=float, default=None, help="Focal length in pixels of the video.")
@click.option("--hfov", type=float, default=None, help="Horizontal field of view, degrees.")
@click.option(
    "--readout-ms",
    type=click.FloatRange(min=0.0),
    default=None,
    help="Video: the time over which the camera reads a frame's rows (rolling shutter, "
    "10-35 ms on consumer drones); the slam method then models it.",
)
@click.option(
    "--time-offset",
    type=float,
    default=None,
    help="log time = video time + this (seconds); estimated when not given.",
)
@click.option(
    "--recording",
    type=click.IntRange(min=1),
    default=None,
    help="Of an SRT file joined from several recordings, the one to use (as the log's "
    "warning numbers them); by default the one that matches the video.",
)
@click.option(
    "--position-sigma",
    type=(float, float),
    default=None,
    metavar="H V",
    help="The log's position accuracy (1-sigma, m, horizontal and vertical) when it "
    "states none, e.g. 0.02 0.04 for an RTK drone: the georeference is checked against it.",
)
@click.option("--width", type=int, default=640, show_default=True)
@click.option("--height", type=int, default=360, show_default=True)
@click.option(
    "--from-stage",
    type=click.Choice(STAGES),
    default="ingest",
    show_default=True,
    help="Resume: stages before this one must have run in --out.",
)
def reconstruct(
    video: Path | None,
    log_path: Path | None,
    images: Path | None,
    out_dir: Path,
    method: str,
    georef: str,
    resolution: float | None,
    median: bool,
    png: bool,
    camera: str | None,
    fx: float | None,
    hfov: float | None,
    readout_ms: float | None,
    time_offset: float | None,
    recording: int | None,
    position_sigma: tuple[float, float] | None,
    width: int,
    height: int,
    from_stage: str,
) -> None:
    """Reconstruct a survey into a DSM; print a one-line JSON summary."""
    options = ReconstructionOptions(method=method, time_offset_s=time_offset, recording=recording)
    options.camera = CameraOverride(model=camera, fx=fx, hfov_deg=hfov, readout_ms=readout_ms)
    if fx is not None:
        options.camera.width = None
    options.frames.width, options.frames.height = width, height
    options.georef.georef.method = georef
    if position_sigma is not None:
        h, v = position_sigma
        options.georef.georef.position_sigma_m = (h, h, v)
    options.dsm.resolution_m = resolution
    options.dsm.statistic = "median" if median else "mean"
    options.dsm.png = png
    inputs = ReconstructionInputs(
        video=str(video) if video else None,
        log=str(log_path) if log_path else None,
        images=str(images) if images else None,
    )
    try:
        result = reconstruct_survey(inputs, out_dir, options, from_stage=from_stage)
    except InputError as exc:
        click.echo(f"error: {exc}", err=True)
        raise SystemExit(EXIT_INPUT_ERROR) from exc
    click.echo(json.dumps(result.summary()))
