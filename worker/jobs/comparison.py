"""The comparison job: the comparison pipeline of its method (worker/pipeline/comparison.py),
one Celery task per stage over the comparison's folder in storage.

Everything stage-specific comes from the pipeline's stage specs: the stages of a job (its
method's), the products a stage's files become, how raster products are made into COGs,
and which stage's detections.geojson becomes the comparison's Detection rows.
"""

import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from sqlalchemy import delete
from sqlalchemy.orm import Session

from backend.db import model_registry
from backend.db.detections import detection_feature, detection_row
from backend.db.models import Comparison, Detection, Job, JobState
from backend.storage_layout import comparison_cog_file, comparison_file, comparison_folder
from worker.jobs.events import JobEvent, publish
from worker.jobs.kind import JobKindName
from worker.jobs.products import COG_MEDIA_TYPE, StorageJob, register_product
from worker.pipeline import comparison as pipeline
from worker.pipeline.atomic import write_text_atomic
from worker.pipeline.cog import write_cog
from worker.pipeline.comparison_layout import DETECTIONS_OUTPUT
from worker.pipeline.detection_methods import default_method, detection_method, detection_methods
from worker.pipeline.detection_record import read_detections
from worker.pipeline.progress import ProgressFn
from worker.pipeline.stages import Output


def stage_products(method: str, stage: str) -> tuple[Output, ...]:
    """The files of a stage of `method` that become the comparison's products."""
    return pipeline.comparison_pipeline(method).stage(stage).products()


class ComparisonJob(StorageJob):
    name = JobKindName.comparison
    # The default method's stages; a job records its own, by method (stages_for).
    stages: tuple[str, ...] = pipeline.stages_for(default_method())

    def stage_help(self, stage: str) -> str:
        """One line on what a stage does, from whichever method declares it."""
        for spec in (*pipeline.COMMON_STAGES, *(m.stage for m in detection_methods())):
            if spec.name == stage:
                return spec.help
        return ""

    def _comparison(self, session: Session, job: Job) -> Comparison:
        return self.owner(session, Comparison, job.comparison_id, job.id)

    def load_inputs(self, session: Session, job: Job) -> dict[str, Any]:
        comparison = self._comparison(session, job)
        dsm_paths = []
        for survey in (comparison.pre_survey, comparison.post_survey):
            dsm = next((p for p in survey.products if p.kind == "dsm"), None)
            if dsm is None:
                raise LookupError(f"survey {survey.id} has no DSM product")
            dsm_paths.append(str(self.storage.absolute(dsm.file.path)))
        options = dict(comparison.parameters)
        method = detection_method(comparison.method)
        if method.needs_model:
            # The parameters name a registered model ("name@version"); the library takes
            # the path of its card.
            chosen = dict(options.get(method.options_key) or {})
            reference = chosen.get("model")
            row = model_registry.find_model(session, reference) if reference else None
            row = row or model_registry.default_model(session)
            chosen["model"] = str(model_registry.card_path(row, self.storage)) if row else None
            options[method.options_key] = chosen
        return {
            "pre_path": dsm_paths[0],
            "post_path": dsm_paths[1],
            "work_dir": str(self.storage.absolute(comparison_folder(comparison.id))),
            "method": comparison.method,
            "options": options,
        }

    def run_stage(self, stage: str, inputs: dict[str, Any], progress: ProgressFn) -> dict[str, Any]:
        return pipeline.run_stage(
            stage,
            Path(inputs["pre_path"]),
            Path(inputs["post_path"]),
            Path(inputs["work_dir"]),
            pipeline.ComparisonOptions.from_dict(inputs["options"]),
            progress,
        )

    def store_stage_result(
        self, session: Session, job: Job, stage: str, result: dict[str, Any]
    ) -> None:
        comparison = self._comparison(session, job)
        for output in stage_products(comparison.method, stage):
            relative = comparison_file(comparison.id, output.file)
            media_type = output.media_type
            if output.raster_role is not None:
                # Same input, same COG: a stage stored again rewrites an identical file.
                cog = comparison_cog_file(comparison.id, output.file)
                write_cog(
                    self.storage.absolute(relative), self.storage.absolute(cog), output.raster_role
                )
                relative, media_type = cog, COG_MEDIA_TYPE
            register_product(
                session,
                self.storage,
                site_id=comparison.site_id,
                comparison_id=comparison.id,
                kind=output.product or output.file,
                relative=relative,
                media_type=media_type,
            )
            if output == DETECTIONS_OUTPUT:
                self._store_detections(session, comparison, relative)

    def _store_detections(self, session: Session, comparison: Comparison, relative: str) -> None:
        """The detections become rows; the product file is written again from the rows, so
        it has their ids and the API's fields."""
        path = self.storage.absolute(relative)
        detections = read_detections(path)
        session.execute(delete(Detection).where(Detection.comparison_id == comparison.id))
        rows = [detection_row(comparison.id, g, p) for g, p in detections]
        session.add_all(rows)
        session.flush()
        collection = json.loads(path.read_text(encoding="utf-8"))
        collection["features"] = [
            detection_feature(row, label=number) for number, row in enumerate(rows, start=1)
        ]
        write_text_atomic(path, json.dumps(collection, separators=(",", ":")))

    def on_success(self, session: Session, job: Job) -> None:
        comparison = self._comparison(session, job)
        results = {run.stage: run.result or {} for run in job.stages}
        detections = comparison.detections
        comparison.status = JobState.succeeded
        comparison.error = None
        comparison.finished_at = datetime.now(UTC)
        correction = pipeline.summarize(results)
        comparison.summary = {
            "detections": len(detections),
            "total_area_m2": round(sum(d.area_m2 for d in detections), 3),
            "total_volume_loss_m3": round(sum(d.volume_loss_m3 for d in detections), 3),
            "total_volume_gain_m3": round(sum(d.volume_gain_m3 for d in detections), 3),
            # What the co-registration did to the post DSM: the map states it and applies
            # it to the post survey's orthophoto tiles.
            "shift_m": correction["shift_m"],
            "rotation_deg": correction["rotation_deg"],
            "stages": results,
        }
        session.flush()
        publish(JobEvent.comparison_succeeded, self.context.settings, session, comparison)

    def on_retry(self, session: Session, job: Job) -> None:
        comparison = self._comparison(session, job)
        comparison.status, comparison.error, comparison.finished_at = JobState.queued, None, None

    def on_failure(self, session: Session, job: Job, reason: str) -> None:
        comparison = session.get(Comparison, job.comparison_id)
        if comparison is not None:
            comparison.status = JobState.failed
            comparison.error = reason
            comparison.finished_at = datetime.now(UTC)
