"""The comparison job: align, co-register, difference, then score (scored method), vectorize
(threshold method) or detect (cnn method) two survey DSMs."""

import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from shapely.geometry import shape
from sqlalchemy import delete
from sqlalchemy.orm import Session

from backend.db.models import Comparison, Detection, Job, JobState
from backend.services import alerts, models
from worker.jobs.products import COG_MEDIA_TYPE, StorageJob, register_product
from worker.pipeline import comparison as pipeline
from worker.pipeline.cog import RasterRole, write_cog
from worker.pipeline.difference import LOD_FILE
from worker.pipeline.progress import ProgressFn

_DETECTIONS = {"detections": (pipeline.DETECTIONS, "application/geo+json")}
# Files of a stage that become downloadable products, by product kind. Rasters are served as
# Cloud-Optimized GeoTIFFs made from the stage's file (role: how overviews are resampled).
STAGE_PRODUCTS: dict[str, dict[str, tuple[str, str]]] = {
    "coregister": {"post_coregistered": ("post_coregistered.tif", "image/tiff")},
    "difference": {
        "dh": ("dh.tif", "image/tiff"),
        "significance": ("significance.tif", "image/tiff"),
        "lod": (LOD_FILE, "image/tiff"),
    },
    "vectorize": _DETECTIONS,
    "score": _DETECTIONS,
    "detect": {
        "probability": ("probability.tif", "image/tiff"),
        "cells": ("cells.geojson", "application/geo+json"),
        **_DETECTIONS,
    },
}
RASTER_ROLES: dict[str, RasterRole] = {
    "post_coregistered": RasterRole.elevation,
    "dh": RasterRole.elevation,
    "significance": RasterRole.mask,
    # Continuous fields in metres or 0-1: overviews average them, as elevations.
    "lod": RasterRole.elevation,
    "probability": RasterRole.elevation,
}
# Stages whose detections.geojson becomes the comparison's Detection rows.
DETECTION_STAGES = ("vectorize", "score", "detect")
# Properties of a detection feature kept together in Detection.uncertainty (threshold and
# scored methods; the cnn method's features have none of them).
UNCERTAINTY_KEYS = ("area_m2_ci95", "volume_loss_m3_ci95", "volume_gain_m3_ci95", "lod_m")


def comparison_folder(comparison_id: int) -> str:
    """Storage folder (relative) that holds a comparison's work files and products."""
    return f"comparisons/{comparison_id}"


class ComparisonJob(StorageJob):
    name = "comparison"
    # The threshold method's stages; a job records its own, by method (stages_for).
    stages: tuple[str, ...] = tuple(pipeline.STAGES)

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
        if comparison.method == "cnn":
            # The parameters name a registered model ("name@version"); the library takes
            # the path of its card.
            cnn = dict(options.get("cnn") or {})
            row = models.find_model(session, cnn.get("model") or "") if cnn.get("model") else None
            row = row or models.default_model(session)
            cnn["model"] = str(models.card_path(row, self.storage)) if row else None
            options["cnn"] = cnn
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
        folder = comparison_folder(comparison.id)
        for kind, (file_name, media_type) in STAGE_PRODUCTS.get(stage, {}).items():
            relative = f"{folder}/{file_name}"
            if kind in RASTER_ROLES:
                # Same input, same COG: a stage stored again rewrites an identical file.
                cog = f"{folder}/cog/{file_name}"
                write_cog(
                    self.storage.absolute(relative), self.storage.absolute(cog), RASTER_ROLES[kind]
                )
                relative, media_type = cog, COG_MEDIA_TYPE
            register_product(
                session,
                self.storage,
                site_id=comparison.site_id,
                comparison_id=comparison.id,
                kind=kind,
                relative=relative,
                media_type=media_type,
            )
        if stage in DETECTION_STAGES:
            self._store_detections(session, comparison, f"{folder}/{pipeline.DETECTIONS}")

    def _store_detections(self, session: Session, comparison: Comparison, relative: str) -> None:
        collection = json.loads(self.storage.absolute(relative).read_text())
        session.execute(delete(Detection).where(Detection.comparison_id == comparison.id))
        for feature in collection["features"]:
            props = feature["properties"]
            min_lon, min_lat, max_lon, max_lat = geometry_bbox(feature["geometry"])
            session.add(
                Detection(
                    comparison_id=comparison.id,
                    geometry=feature["geometry"],
                    min_lon=min_lon,
                    min_lat=min_lat,
                    max_lon=max_lon,
                    max_lat=max_lat,
                    area_m2=props["area_m2"],
                    volume_loss_m3=props["volume_loss_m3"],
                    volume_gain_m3=props["volume_gain_m3"],
                    max_abs_dh_m=props["max_abs_dh_m"],
                    score=props["score"],
                    method=props.get("method", comparison.method),
                    model_version=props.get("model"),
                    uncertainty=uncertainty_of(props),
                )
            )

    def on_success(self, session: Session, job: Job) -> None:
        comparison = self._comparison(session, job)
        results = {run.stage: run.result or {} for run in job.stages}
        detections = comparison.detections
        comparison.status = JobState.succeeded
        comparison.error = None
        comparison.finished_at = datetime.now(UTC)
        comparison.summary = {
            "detections": len(detections),
            "total_area_m2": round(sum(d.area_m2 for d in detections), 3),
            "total_volume_loss_m3": round(sum(d.volume_loss_m3 for d in detections), 3),
            "total_volume_gain_m3": round(sum(d.volume_gain_m3 for d in detections), 3),
            "stages": results,
        }
        session.flush()
        alerts.guarded(alerts.comparison_succeeded, session, comparison)

    def on_retry(self, session: Session, job: Job) -> None:
        comparison = self._comparison(session, job)
        comparison.status, comparison.error, comparison.finished_at = JobState.queued, None, None

    def on_failure(self, session: Session, job: Job, reason: str) -> None:
        comparison = session.get(Comparison, job.comparison_id)
        if comparison is not None:
            comparison.status = JobState.failed
            comparison.error = reason
            comparison.finished_at = datetime.now(UTC)


def uncertainty_of(props: dict[str, Any]) -> dict[str, Any] | None:
    """The feature's intervals and LoD, None when it has none of them (cnn)."""
    kept = {key: props[key] for key in UNCERTAINTY_KEYS if props.get(key) is not None}
    return kept or None


def geometry_bbox(geometry: dict[str, Any]) -> tuple[float, float, float, float]:
    min_x, min_y, max_x, max_y = shape(geometry).bounds
    return min_x, min_y, max_x, max_y
