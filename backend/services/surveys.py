"""Create a survey from an uploaded DSM GeoTIFF.

The upload is kept as it came (the survey's source file); its `dsm` product is a
Cloud-Optimized GeoTIFF made from it, which GIS clients and the tile server read.
"""

from collections.abc import AsyncIterator
from datetime import datetime
from pathlib import Path

from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from backend.db.models import Product, Site, StoredFile, Survey, SurveyKind, SurveyStatus
from backend.geotiff import is_geotiff
from backend.raster_limits import RasterLimits, check_raster_limits
from backend.storage import LocalStorage, SavedFile, file_digest
from backend.storage_layout import site_surveys_folder
from worker.pipeline.cog import COG_MEDIA_TYPE, RasterRole, write_cog
from worker.pipeline.dsm_inspect import inspect_dsm
from worker.pipeline.errors import InputError


async def create_dsm_survey(
    session: Session,
    storage: LocalStorage,
    site: Site,
    chunks: AsyncIterator[bytes],
    *,
    name: str,
    captured_at: datetime,
    original_name: str | None,
    max_bytes: int,
    limits: RasterLimits,
) -> Survey:
    """Stream the upload to storage, check it is a usable DSM, then record it.

    Raises UploadTooLarge or InputError (RasterTooLarge beyond `limits`); in every failure
    the file is removed and no row is left behind.
    """
    folder = site_surveys_folder(site.id)
    saved: SavedFile = await storage.save_stream(chunks, folder, ".tif", max_bytes)
    return await _record_dsm_survey(
        session, storage, site, saved, name=name, captured_at=captured_at,
        original_name=original_name, limits=limits,
    )  # fmt: skip


async def create_dsm_survey_from_file(
    session: Session,
    storage: LocalStorage,
    site: Site,
    source: Path,
    *,
    name: str,
    captured_at: datetime,
    original_name: str | None,
    limits: RasterLimits,
) -> Survey:
    """As create_dsm_survey, from a complete file on disk (a finished resumable upload),
    which is moved into storage. Raises InputError; on failure the file is removed."""
    folder = site_surveys_folder(site.id)
    saved = await run_in_threadpool(storage.adopt_file, source, folder, ".tif")
    return await _record_dsm_survey(
        session, storage, site, saved, name=name, captured_at=captured_at,
        original_name=original_name, limits=limits,
    )  # fmt: skip


async def _record_dsm_survey(
    session: Session,
    storage: LocalStorage,
    site: Site,
    saved: SavedFile,
    *,
    name: str,
    captured_at: datetime,
    original_name: str | None,
    limits: RasterLimits,
) -> Survey:
    """Check the saved file is a usable DSM, make its COG and record both (or neither)."""
    label = f"the upload {original_name!r}" if original_name else "the upload"
    if not is_geotiff(storage.absolute(saved.relative_path)):
        # Never handed to GDAL: a VRT or other format could make it read any file.
        storage.delete(saved.relative_path)
        raise InputError(f"{label} is not a GeoTIFF (it is not a TIFF file)")
    cog_path = storage.new_relative_path(site_surveys_folder(site.id), ".cog.tif")
    try:
        # From the header alone, before GDAL decompresses anything: a small file may
        # declare more pixels than the server can afford to read.
        await run_in_threadpool(
            check_raster_limits, storage.absolute(saved.relative_path), limits, label
        )
        info = await run_in_threadpool(inspect_dsm, storage.absolute(saved.relative_path), label)
        await run_in_threadpool(
            write_cog,
            storage.absolute(saved.relative_path),
            storage.absolute(cog_path),
            RasterRole.elevation,
        )
        cog_size, cog_sha256 = await run_in_threadpool(file_digest, storage.absolute(cog_path))
        cog = StoredFile(
            path=cog_path,
            size_bytes=cog_size,
            sha256=cog_sha256,
            media_type=COG_MEDIA_TYPE,
            original_name=None,
        )
        stored = StoredFile(
            path=saved.relative_path,
            size_bytes=saved.size_bytes,
            sha256=saved.sha256,
            media_type="image/tiff",
            original_name=original_name,
        )
        survey = Survey(
            site=site,
            name=name,
            captured_at=captured_at,
            kind=SurveyKind.dsm,
            status=SurveyStatus.ready,
            crs=info.crs,
            footprint=info.footprint,
            resolution_m=float(max(info.resolution_m)),
            source_file=stored,
        )
        session.add_all([stored, cog, survey])
        session.flush()
        session.add(
            Product(site_id=site.id, survey_id=survey.id, kind="dsm", file_id=cog.id, crs=info.crs)
        )
        session.commit()
    except BaseException:
        session.rollback()
        storage.delete(saved.relative_path)
        storage.delete(cog_path)
        raise
    return survey
