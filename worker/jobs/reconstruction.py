"""The reconstruction job: a video + flight log, or an image set, to the survey's DSM.

Stages are the library's (worker.pipeline.reconstruction.RECONSTRUCTION_PIPELINE): ingest
-> frames -> reconstruct -> georeference -> dsm -> orthophoto, each run over the survey's
work folder in storage. A stage's files that its spec marks as products become the
survey's products: `trajectory` (GeoJSON flight path in WGS84) after georeference; `dsm`
(COG) and `points` (PLY) after dsm; `orthophoto` (RGBA COG, when the imagery could be
read) and `report` (timings and residuals) after orthophoto.

A video still arriving through a resumable upload is read from the upload's part file
as it grows (the library waits for its bytes). The frames stage then waits for the
upload to be handed over (its part file moves into the survey); a later stage finds
the video among the survey's files, or fails with the reason the upload was refused.
"""

import os
import time
from pathlib import Path
from typing import Any

from sqlalchemy.orm import Session

from backend.db.arriving_uploads import arriving_video, part_path
from backend.db.models import Job, Survey, SurveyKind, SurveyStatus, UploadState
from backend.storage_layout import survey_reconstruction_file, survey_reconstruction_folder
from worker.jobs.events import JobEvent, publish
from worker.jobs.kind import JobKindName
from worker.jobs.products import StorageJob, drop_product, register_product
from worker.pipeline import reconstruction as pipeline
from worker.pipeline.dsm_inspect import inspect_dsm
from worker.pipeline.errors import InputError
from worker.pipeline.progress import ProgressFn

IMAGES_DIR = "images"
ARRIVING_DIR = "arriving"  # a link named as the user's video to the upload still arriving
INPUTS_DIR = "inputs"  # links named as the user's video and log to the stored files


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
    name = JobKindName.reconstruction
    stages: tuple[str, ...] = pipeline.STAGES

    def stage_help(self, stage: str) -> str:
        return pipeline.RECONSTRUCTION_PIPELINE.stage(stage).help

    def _survey(self, session: Session, job: Job) -> Survey:
        return self.owner(session, Survey, job.survey_id, job.id)

    def load_inputs(self, session: Session, job: Job) -> dict[str, Any]:
        survey = self._survey(session, job)
        paths = {f.name: str(self.storage.absolute(f.file.path)) for f in survey.files}
        files = {f.role: paths[f.name] for f in survey.files if f.role != "image"}
        names = {f.role: f.name for f in survey.files if f.role != "image"}
        images = {f.name: paths[f.name] for f in survey.files if f.role == "image"}
        inputs: dict[str, Any] = {
            "kind": survey.kind.value,
            "video": files.get("video"),
            "log": files.get("log"),
            "names": names,
            "images": images,
            "work_dir": str(
                self.storage.absolute(survey_reconstruction_folder(survey.site_id, survey.id))
            ),
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
        stall_s = self.context.settings.upload_stall_timeout_s
        video, log = inputs["video"], inputs["log"]
        # The library names the files in its messages and report: the user's names.
        names = inputs.get("names", {})
        if log and "log" in names:
            _link_files({names["log"]: log}, work_dir / INPUTS_DIR)
            log = str(work_dir / INPUTS_DIR / names["log"])
        if inputs.get("video_bytes") is not None:
            _link_files({inputs["video_name"]: video}, work_dir / ARRIVING_DIR)
            video = str(work_dir / ARRIVING_DIR / inputs["video_name"])
        elif video and "video" in names:
            _link_files({names["video"]: video}, work_dir / INPUTS_DIR)
            video = str(work_dir / INPUTS_DIR / names["video"])
        source = pipeline.ReconstructionInputs(
            video=video,
            log=log,
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
        return result

    def store_stage_result(
        self, session: Session, job: Job, stage: str, result: dict[str, Any]
    ) -> None:
        survey = self._survey(session, job)
        for output in pipeline.RECONSTRUCTION_PIPELINE.stage(stage).products():
            relative = survey_reconstruction_file(survey.site_id, survey.id, output.file)
            if output.optional and not self.storage.absolute(relative).is_file():
                # Not made this time (the stage's result says why): an earlier run's
                # product of that kind no longer exists either.
                drop_product(session, survey.id, output.product or output.file)
                continue
            register_product(
                session,
                self.storage,
                site_id=survey.site_id,
                survey_id=survey.id,
                kind=output.product or output.file,
                relative=relative,
                media_type=output.media_type,
            )
        if stage != "dsm":
            return
        dsm = survey_reconstruction_file(survey.site_id, survey.id, pipeline.DSM)
        info = inspect_dsm(self.storage.absolute(dsm), "the DSM")
        survey.crs = info.crs
        survey.footprint = info.footprint
        survey.resolution_m = float(max(info.resolution_m))

    def on_success(self, session: Session, job: Job) -> None:
        survey = self._survey(session, job)
        survey.status, survey.error = SurveyStatus.ready, None
        session.flush()
        publish(JobEvent.survey_ready, self.context.settings, session, survey)

    def on_failure(self, session: Session, job: Job, reason: str) -> None:
        survey = session.get(Survey, job.survey_id)
        if survey is not None:
            survey.status, survey.error = SurveyStatus.failed, reason

    def on_retry(self, session: Session, job: Job) -> None:
        survey = self._survey(session, job)
        survey.status, survey.error = SurveyStatus.processing, None
