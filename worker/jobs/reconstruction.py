"""The reconstruction job: a video + flight log, or an image set, to the survey's DSM.

Stages are the library's (worker.pipeline.reconstruction): ingest -> frames ->
reconstruct -> georeference -> dsm, each run over the survey's work folder in storage.
When the dsm stage is stored, the survey gets its products: `dsm` (COG), `points` (PLY),
`trajectory` (GeoJSON flight path in WGS84) and `report` (timings and residuals).

A video still arriving through a resumable upload is read from the upload's part file
as it grows (the library waits for its bytes). The frames stage then waits for the
upload to be handed over (its part file moves into the survey); a later stage finds
the video among the survey's files, or fails with the reason the upload was refused.
"""

import json
import os
import time
from pathlib import Path
from typing import Any

from sqlalchemy.orm import Session

from backend.config import get_settings
from backend.db.models import Job, Survey, SurveyKind, SurveyStatus, UploadState
from backend.services.arriving_uploads import arriving_video, part_path
from worker.jobs.products import COG_MEDIA_TYPE, StorageJob, register_product
from worker.pipeline import reconstruction as pipeline
from worker.pipeline.atomic import write_text_atomic
from worker.pipeline.dsm_inspect import inspect_dsm
from worker.pipeline.errors import InputError
from worker.pipeline.progress import ProgressFn
from worker.pipeline.trajectory import read_trajectory_csv, trajectory_geojson

IMAGES_DIR = "images"
ARRIVING_DIR = "arriving"  # a link named as the user's video to the upload still arriving
TRAJECTORY_GEOJSON = "trajectory.geojson"
# Outputs of the dsm stage that become products: kind -> (file in the work folder, type).
PRODUCTS: dict[str, tuple[str, str]] = {
    "dsm": (pipeline.DSM, COG_MEDIA_TYPE),
    "points": (pipeline.POINTS, "application/vnd.ply"),
    "trajectory": (TRAJECTORY_GEOJSON, "application/geo+json"),
    "report": (pipeline.REPORT, "application/json"),
}


def survey_folder(survey: Survey) -> str:
    """Storage folder (relative) of a source survey's uploads and reconstruction."""
    return f"surveys/{survey.site_id}/{survey.id}"


def _link_files(files: dict[str, str], folder: Path) -> None:
    """Links named as uploaded (the library's messages name the user's files)."""
    folder.mkdir(parents=True, exist_ok=True)
    for name, target in files.items():
        link = folder / name
        if link.is_symlink() and os.readlink(link) == target:
            continue
        link.unlink(missing_ok=True)
        link.symlink_to(target)


def _wait_for_hand_over(part: Path, timeout_s: float, poll_s: float = 0.2) -> None:
    """Wait until a finished upload has left its part file (handed over to the survey, or
    refused): what the next stage reads depends on which (see the module doc)."""
    deadline = time.monotonic() + timeout_s
    while part.exists():
        if time.monotonic() > deadline:
            raise InputError(
                f"the video upload has all its bytes but was not checked within {timeout_s:.0f} s"
            )
        time.sleep(poll_s)


class ReconstructionJob(StorageJob):
    name = "reconstruction"
    stages: tuple[str, ...] = tuple(pipeline.STAGES)

    def _survey(self, session: Session, job: Job) -> Survey:
        return self.owner(session, Survey, job.survey_id, job.id)

    def load_inputs(self, session: Session, job: Job) -> dict[str, Any]:
        survey = self._survey(session, job)
        paths = {f.name: str(self.storage.absolute(f.file.path)) for f in survey.files}
        files = {f.role: paths[f.name] for f in survey.files if f.role != "image"}
        images = {f.name: paths[f.name] for f in survey.files if f.role == "image"}
        inputs: dict[str, Any] = {
            "kind": survey.kind.value,
            "video": files.get("video"),
            "log": files.get("log"),
            "images": images,
            "work_dir": str(self.storage.absolute(f"{survey_folder(survey)}/reconstruction")),
            "options": survey.options or {},
            "video_bytes": None,
            "video_refused": None,
        }
        upload = arriving_video(session, survey)
        if upload is not None and upload.state == UploadState.receiving:
            inputs["video"] = str(part_path(self.storage, upload))
            inputs["video_bytes"] = upload.length
            inputs["video_name"] = upload.filename
        elif upload is not None:
            inputs["video_refused"] = upload.error or f"the upload of {upload.filename} failed"
        return inputs

    def run_stage(self, stage: str, inputs: dict[str, Any], progress: ProgressFn) -> dict[str, Any]:
        work_dir = Path(inputs["work_dir"])
        if inputs.get("video_refused"):
            raise InputError(f"the video upload failed: {inputs['video_refused']}")
        stall_s = get_settings().upload_stall_timeout_s
        video = inputs["video"]
        if inputs.get("video_bytes") is not None:
            _link_files({inputs["video_name"]: video}, work_dir / ARRIVING_DIR)
            video = str(work_dir / ARRIVING_DIR / inputs["video_name"])
        source = pipeline.ReconstructionInputs(
            video=video,
            log=inputs["log"],
            video_bytes=inputs.get("video_bytes"),
            video_stall_timeout_s=stall_s,
        )
        if inputs["kind"] == SurveyKind.images.value:
            _link_files(inputs["images"], work_dir / IMAGES_DIR)
            source = pipeline.ReconstructionInputs(images=str(work_dir / IMAGES_DIR))
        options = pipeline.ReconstructionOptions.from_dict(inputs["options"])
        result = pipeline.run_stage(stage, work_dir, options, source, progress)
        if stage == "frames" and inputs.get("video_bytes") is not None:
            _wait_for_hand_over(Path(inputs["video"]), stall_s)
        if stage == "dsm":
            trajectory = read_trajectory_csv(work_dir / pipeline.TRAJECTORY)
            write_text_atomic(
                work_dir / TRAJECTORY_GEOJSON, json.dumps(trajectory_geojson(trajectory))
            )
        return result

    def store_stage_result(
        self, session: Session, job: Job, stage: str, result: dict[str, Any]
    ) -> None:
        if stage != "dsm":
            return
        survey = self._survey(session, job)
        folder = f"{survey_folder(survey)}/reconstruction"
        for kind, (file_name, media_type) in PRODUCTS.items():
            register_product(
                session,
                self.storage,
                site_id=survey.site_id,
                survey_id=survey.id,
                kind=kind,
                relative=f"{folder}/{file_name}",
                media_type=media_type,
            )
        info = inspect_dsm(self.storage.absolute(f"{folder}/{pipeline.DSM}"), "the DSM")
        survey.crs = info.crs
        survey.footprint = info.footprint
        survey.resolution_m = float(max(info.resolution_m))

    def on_success(self, session: Session, job: Job) -> None:
        survey = self._survey(session, job)
        survey.status, survey.error = SurveyStatus.ready, None

    def on_failure(self, session: Session, job: Job, reason: str) -> None:
        survey = session.get(Survey, job.survey_id)
        if survey is not None:
            survey.status, survey.error = SurveyStatus.failed, reason

    def on_retry(self, session: Session, job: Job) -> None:
        survey = self._survey(session, job)
        survey.status, survey.error = SurveyStatus.processing, None
