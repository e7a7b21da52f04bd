"""Delete sites, surveys and comparisons with everything that hangs on them, files included.

Rows go first, in one transaction (the database cascades to children); files are removed
only after the commit, so a failed delete never leaves rows pointing at missing files. The
map tiles of what was deleted leave the tile cache with the files.
"""

from pathlib import Path

from sqlalchemy import delete, or_, select
from sqlalchemy.orm import Session

from backend.db.arriving_uploads import part_relative_path
from backend.db.models import (
    Comparison,
    Product,
    Report,
    Site,
    StoredFile,
    Survey,
    SurveyFile,
    Upload,
    UploadState,
)
from backend.services.tile_cache import forget_tiles, group_name
from backend.storage import LocalStorage
from backend.storage_layout import comparison_folder, site_uploads_folder, survey_folder


class StillInUse(Exception):
    pass


def _files_of(session: Session, *conditions) -> list[StoredFile]:
    product_files = select(Product.file_id).where(or_(*conditions))
    return list(session.scalars(select(StoredFile).where(StoredFile.id.in_(product_files))))


def _source_files_of(session: Session, *conditions) -> list[StoredFile]:
    """The uploaded originals of surveys (their DSM product is a COG made from it)."""
    sources = select(Survey.source_file_id).where(or_(*conditions))
    return list(session.scalars(select(StoredFile).where(StoredFile.id.in_(sources))))


def _uploads_of(session: Session, *conditions) -> list[StoredFile]:
    """The video, log and photo files of source surveys."""
    uploads = select(SurveyFile.file_id).join(Survey).where(or_(*conditions))
    return list(session.scalars(select(StoredFile).where(StoredFile.id.in_(uploads))))


def _report_files_of(session: Session, site_id: int) -> list[StoredFile]:
    reports = select(Report.pdf_file_id, Report.html_file_id).where(Report.site_id == site_id)
    ids = {i for row in session.execute(reports) for i in row if i is not None}
    return list(session.scalars(select(StoredFile).where(StoredFile.id.in_(ids))))


def _remove(
    session: Session,
    storage: LocalStorage,
    files: list[StoredFile],
    folders: list[str],
    tile_cache_dir: Path | None = None,
    tile_groups: list[str] | None = None,
) -> None:
    paths = [f.path for f in files]
    session.execute(delete(StoredFile).where(StoredFile.id.in_([f.id for f in files])))
    session.commit()
    for path in paths:
        storage.delete(path)
    for folder in folders:
        storage.delete_tree(folder)
    if tile_cache_dir is not None:
        forget_tiles(tile_cache_dir, tile_groups or [])


def delete_comparison(
    session: Session,
    storage: LocalStorage,
    comparison: Comparison,
    tile_cache_dir: Path | None = None,
) -> None:
    """`tile_cache_dir`: the disk tile cache its map tiles are removed from."""
    files = _files_of(session, Product.comparison_id == comparison.id)
    session.execute(delete(Comparison).where(Comparison.id == comparison.id))
    _remove(
        session, storage, files, [comparison_folder(comparison.id)],
        tile_cache_dir, [group_name("comparisons", comparison.id)],
    )  # fmt: skip


def delete_survey(
    session: Session, storage: LocalStorage, survey: Survey, tile_cache_dir: Path | None = None
) -> None:
    users = session.scalars(
        select(Comparison.id).where(
            or_(Comparison.pre_survey_id == survey.id, Comparison.post_survey_id == survey.id)
        )
    ).all()
    if users:
        raise StillInUse(
            f"survey {survey.id} is used by comparisons {', '.join(map(str, users))}; "
            "delete them first"
        )
    files = _files_of(session, Product.survey_id == survey.id)
    files += _source_files_of(session, Survey.id == survey.id)
    files += _uploads_of(session, Survey.id == survey.id)
    folder = survey_folder(survey.site_id, survey.id)
    # Its files still arriving go too: nothing could take them any more.
    unfinished = _unfinished_uploads_of(session, survey)
    parts = [part_relative_path(u) for u in unfinished]
    for upload in unfinished:
        session.delete(upload)
    session.execute(delete(Survey).where(Survey.id == survey.id))
    _remove(session, storage, files, [folder], tile_cache_dir, [group_name("surveys", survey.id)])
    for part in parts:
        storage.delete(part)


def _unfinished_uploads_of(session: Session, survey: Survey) -> list[Upload]:
    uploads = session.scalars(
        select(Upload).where(
            Upload.site_id == survey.site_id,
            Upload.purpose == "survey_file",
            Upload.state != UploadState.complete,
        )
    )
    return [u for u in uploads if (u.details or {}).get("survey_id") == survey.id]


def delete_site(
    session: Session, storage: LocalStorage, site: Site, tile_cache_dir: Path | None = None
) -> None:
    comparison_ids = session.scalars(
        select(Comparison.id).where(Comparison.site_id == site.id)
    ).all()
    files = _files_of(session, Product.site_id == site.id)
    files += _source_files_of(session, Survey.site_id == site.id)
    files += _uploads_of(session, Survey.site_id == site.id)
    files += _report_files_of(session, site.id)
    folders = [comparison_folder(c) for c in comparison_ids]
    folders += [survey_folder(site.id, s.id) for s in site.surveys]
    groups = [group_name("comparisons", c) for c in comparison_ids]
    groups += [group_name("surveys", s.id) for s in site.surveys]
    # Unfinished resumable uploads (services/uploads.py): no row points at their bytes.
    folders.append(site_uploads_folder(site.id))
    session.execute(delete(Site).where(Site.id == site.id))
    _remove(session, storage, files, folders, tile_cache_dir, groups)
