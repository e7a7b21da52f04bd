from fastapi import APIRouter, HTTPException, status
from fastapi.responses import FileResponse

from backend.api.access import SiteViewer
from backend.api.deps import SessionDep, StorageDep, owned_by_site
from backend.api.schemas import ProductOut
from backend.api.serializers import product_out
from backend.db.models import Product, Site
from backend.ids import RowId

router = APIRouter(prefix="/sites/{site_id}/products", tags=["products"])


def product_of_site(session: SessionDep, site: Site, product_id: RowId) -> Product:
    return owned_by_site(session, Product, site, product_id, "product")


@router.get("/{product_id}", response_model=ProductOut)
def get_product(product_id: RowId, site: SiteViewer, session: SessionDep) -> ProductOut:
    return product_out(product_of_site(session, site, product_id))


@router.get(
    "/{product_id}/file",
    summary="Download a product (supports HTTP Range requests, e.g. for GDAL /vsicurl/)",
    response_class=FileResponse,
)
def download_product(
    product_id: RowId, site: SiteViewer, session: SessionDep, storage: StorageDep
) -> FileResponse:
    product = product_of_site(session, site, product_id)
    path = storage.absolute(product.file.path)
    if not path.is_file():
        raise HTTPException(
            status.HTTP_404_NOT_FOUND, f"the file of product {product_id} is missing"
        )
    suffix = path.suffix
    return FileResponse(
        path,
        media_type=product.file.media_type,
        filename=f"{product.kind}-{product.survey_id or product.comparison_id}{suffix}",
    )
