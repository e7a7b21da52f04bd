from fastapi import APIRouter, HTTPException, Response, status
from fastapi.responses import JSONResponse
from sqlalchemy import select

from backend.api.access import SignedIn, SiteAnalyst, SiteManager, SiteViewer
from backend.api.deps import CeleryDep, SessionDep, SettingsDep, StorageDep, owned_by_site
from backend.api.schemas import (
    ComparisonCreate,
    ComparisonCreated,
    ComparisonOut,
    ComparisonUpdate,
    ProductOut,
)
from backend.api.serializers import comparison_out, detection_feature, job_out, product_out
from backend.db.detections import detection_labels
from backend.db.models import Comparison, Job, Site
from backend.ids import RowId
from backend.services.audit import record
from backend.services.comparisons import AlreadyCompared, ComparisonRejected, create_comparison
from backend.services.deletion import delete_comparison
from worker.jobs.control import QueueUnavailable

router = APIRouter(prefix="/sites/{site_id}/comparisons", tags=["comparisons"])


def comparison_of_site(session: SessionDep, site: Site, comparison_id: RowId) -> Comparison:
    return owned_by_site(session, Comparison, site, comparison_id, "comparison")


def _job_of(session: SessionDep, comparison: Comparison) -> Job | None:
    return session.scalar(
        select(Job).where(Job.comparison_id == comparison.id).order_by(Job.id.desc()).limit(1)
    )


@router.post(
    "",
    response_model=ComparisonCreated,
    status_code=status.HTTP_202_ACCEPTED,
    responses={
        200: {
            "model": ComparisonCreated,
            "description": "The same comparison exists (same surveys, method and "
            "parameters, not failed): it is answered with `existing` true and nothing is "
            "queued. Send `run_again` true to make a new one anyway.",
        }
    },
)
def create(
    body: ComparisonCreate,
    site: SiteAnalyst,
    session: SessionDep,
    celery: CeleryDep,
    storage: StorageDep,
    token: SignedIn,
) -> ComparisonCreated | JSONResponse:
    """Compare two surveys of this site: queues a job and returns at once."""
    try:
        comparison, job = create_comparison(
            celery,
            session,
            site,
            body.pre_survey_id,
            body.post_survey_id,
            body.method,
            body.parameters,
            name=body.name,
            reuse=not body.run_again,
        )
    except AlreadyCompared as exc:
        same = exc.comparison
        latest = _job_of(session, same)
        answer = ComparisonCreated(
            comparison=comparison_out(same, latest, storage),
            job=job_out(latest) if latest else None,
            existing=True,
        )
        return JSONResponse(answer.model_dump(mode="json"), status_code=status.HTTP_200_OK)
    except ComparisonRejected as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None
    except QueueUnavailable as exc:
        raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE, str(exc)) from None
    record(
        session, token, "comparison.create", site=site,
        target=f"comparison {comparison.id}", details={"run_again": body.run_again},
    )  # fmt: skip
    session.commit()
    return ComparisonCreated(comparison=comparison_out(comparison, job, storage), job=job_out(job))


@router.get("", response_model=list[ComparisonOut])
def list_comparisons(
    site: SiteViewer, session: SessionDep, storage: StorageDep
) -> list[ComparisonOut]:
    query = select(Comparison).where(Comparison.site_id == site.id).order_by(Comparison.id)
    return [comparison_out(c, _job_of(session, c), storage) for c in session.scalars(query)]


@router.get("/{comparison_id}", response_model=ComparisonOut)
def get_comparison(
    comparison_id: RowId, site: SiteViewer, session: SessionDep, storage: StorageDep
) -> ComparisonOut:
    comparison = comparison_of_site(session, site, comparison_id)
    return comparison_out(comparison, _job_of(session, comparison), storage)


@router.get(
    "/{comparison_id}/detections",
    summary="Detected changes as a GeoJSON FeatureCollection (RFC 7946, WGS84 lon/lat)",
    response_class=JSONResponse,
    responses={200: {"content": {"application/geo+json": {}}}},
)
def get_detections(comparison_id: RowId, site: SiteViewer, session: SessionDep) -> JSONResponse:
    comparison = comparison_of_site(session, site, comparison_id)
    labels = detection_labels(comparison)
    collection = {
        "type": "FeatureCollection",
        "features": [detection_feature(d, labels[d.id]) for d in comparison.detections],
    }
    return JSONResponse(collection, media_type="application/geo+json")


@router.get("/{comparison_id}/products", response_model=list[ProductOut])
def list_comparison_products(
    comparison_id: RowId, site: SiteViewer, session: SessionDep
) -> list[ProductOut]:
    comparison = comparison_of_site(session, site, comparison_id)
    return [product_out(p) for p in comparison.products]


@router.patch("/{comparison_id}", response_model=ComparisonOut, summary="Rename a comparison")
def update_comparison(
    comparison_id: RowId,
    body: ComparisonUpdate,
    site: SiteAnalyst,
    session: SessionDep,
    storage: StorageDep,
    token: SignedIn,
) -> ComparisonOut:
    comparison = comparison_of_site(session, site, comparison_id)
    comparison.name = body.name.strip()
    record(
        session, token, "comparison.update", site=site, target=f"comparison {comparison.id}",
        details={"fields": ["name"]},
    )  # fmt: skip
    session.commit()
    return comparison_out(comparison, _job_of(session, comparison), storage)


@router.delete(
    "/{comparison_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Delete a comparison with its detections, their verdicts, its products and jobs",
)
def remove_comparison(
    comparison_id: RowId,
    site: SiteManager,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    token: SignedIn,
) -> Response:
    comparison = comparison_of_site(session, site, comparison_id)
    record(session, token, "comparison.delete", site=site, target=f"comparison {comparison.id}")
    delete_comparison(session, storage, comparison, tile_cache_dir=settings.tile_cache_dir)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
