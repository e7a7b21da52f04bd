"""What the job kinds working in file storage share: the storage, their owner row, products."""

from pathlib import Path
from typing import TypeVar

import rasterio
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.db.models import Product
from backend.db.stored_files import record_stored_file
from backend.storage import LocalStorage
from worker.jobs.context import JobContext
from worker.pipeline.cog import COG_MEDIA_TYPE

T = TypeVar("T")
__all__ = ["COG_MEDIA_TYPE", "StorageJob", "raster_crs", "register_product"]


class StorageJob:
    """Base of the job kinds whose stages work in the platform's file storage."""

    def __init__(self, context: JobContext | None = None) -> None:
        # None: a kind asked only what it declares (stages, help) or to reset its owner row.
        self._context = context

    @property
    def context(self) -> JobContext:
        if self._context is None:
            raise RuntimeError(f"the {type(self).__name__} runs stages only with a JobContext")
        return self._context

    @property
    def storage(self) -> LocalStorage:
        return self.context.storage

    def owner(self, session: Session, model: type[T], owner_id: int | None, job_id: int) -> T:
        """The row the job works for (its comparison, its survey)."""
        row = session.get(model, owner_id)
        if row is None:
            raise LookupError(f"{model.__name__.lower()} {owner_id} of job {job_id} is gone")
        return row


def raster_crs(path: Path) -> str | None:
    with rasterio.open(path) as src:
        return src.crs.to_string() if src.crs else None


def drop_product(session: Session, survey_id: int, kind: str) -> None:
    """Forget the survey's product `kind`, if it has one (its file is kept as stored)."""
    product = session.scalar(
        select(Product).where(Product.survey_id == survey_id, Product.kind == kind)
    )
    if product is not None:
        session.delete(product)
        session.flush()


def register_product(
    session: Session,
    storage: LocalStorage,
    *,
    site_id: int,
    kind: str,
    relative: str,
    media_type: str,
    survey_id: int | None = None,
    comparison_id: int | None = None,
) -> Product:
    """Create or update the product `kind` of its owner; idempotent (a rerun stores again)."""
    path = storage.absolute(relative)
    stored = record_stored_file(session, storage, relative, media_type)
    if (survey_id is None) == (comparison_id is None):
        raise ValueError("a product belongs to exactly one survey or one comparison")
    owner = (
        Product.survey_id == survey_id
        if survey_id is not None
        else Product.comparison_id == comparison_id
    )
    product = session.scalar(select(Product).where(owner, Product.kind == kind))
    crs = raster_crs(path) if media_type.startswith("image/tiff") else None
    if product is None:
        product = Product(
            site_id=site_id,
            survey_id=survey_id,
            comparison_id=comparison_id,
            kind=kind,
            file_id=stored.id,
            crs=crs,
        )
        session.add(product)
    else:
        product.file_id, product.crs = stored.id, crs
    session.flush()
    return product
