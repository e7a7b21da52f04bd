"""Verdicts on detections (confirmed / false alarm) and their export as training labels.

PUT    /sites/{site_id}/comparisons/{comparison_id}/detections/{detection_id}/feedback
GET    /sites/{site_id}/comparisons/{comparison_id}/detections/{detection_id}/feedback
DELETE /sites/{site_id}/comparisons/{comparison_id}/detections/{detection_id}/feedback
GET    /sites/{site_id}/training-labels      GeoJSON, one feature per verdict
GET    /sites/{site_id}/comparisons/{comparison_id}/detections/{detection_id}/history
"""

from fastapi import APIRouter, HTTPException, Response, status
from fastapi.responses import JSONResponse

from backend.api.access import SignedIn, SiteAnalyst, SiteViewer
from backend.api.deps import SessionDep
from backend.api.routes.comparisons import comparison_of_site
from backend.api.schemas_map import DetectionHistoryOut, FeedbackIn, FeedbackOut
from backend.db.models import Detection, DetectionFeedback, Site
from backend.ids import RowId
from backend.services.detection_history import detection_history
from backend.services.feedback import give_verdict, training_labels, withdraw_verdict

router = APIRouter(prefix="/sites/{site_id}", tags=["feedback on detections"])
DETECTION = "/comparisons/{comparison_id}/detections/{detection_id}"


def detection_of(
    session: SessionDep, site: Site, comparison_id: RowId, detection_id: RowId
) -> Detection:
    comparison = comparison_of_site(session, site, comparison_id)
    detection = session.get(Detection, detection_id)
    if detection is None or detection.comparison_id != comparison.id:
        raise HTTPException(
            status.HTTP_404_NOT_FOUND,
            f"detection {detection_id} not found in comparison {comparison_id}",
        )
    return detection


@router.put(f"{DETECTION}/feedback", response_model=FeedbackOut)
def put_feedback(
    comparison_id: RowId,
    detection_id: RowId,
    body: FeedbackIn,
    site: SiteAnalyst,
    session: SessionDep,
    token: SignedIn,
) -> DetectionFeedback:
    """Your verdict on the detection; giving it again changes it."""
    detection = detection_of(session, site, comparison_id, detection_id)
    return give_verdict(session, detection, token, body.verdict, body.note)


@router.get(f"{DETECTION}/feedback", response_model=list[FeedbackOut])
def list_feedback(
    comparison_id: RowId, detection_id: RowId, site: SiteViewer, session: SessionDep
) -> list[DetectionFeedback]:
    """Everyone's verdicts on the detection, with who and when."""
    return list(detection_of(session, site, comparison_id, detection_id).feedback)


@router.delete(f"{DETECTION}/feedback", status_code=status.HTTP_204_NO_CONTENT)
def delete_feedback(
    comparison_id: RowId,
    detection_id: RowId,
    site: SiteAnalyst,
    session: SessionDep,
    token: SignedIn,
) -> Response:
    """Withdraw your verdict."""
    detection = detection_of(session, site, comparison_id, detection_id)
    if not withdraw_verdict(session, detection, token):
        raise HTTPException(
            status.HTTP_404_NOT_FOUND, f"you gave no verdict on detection {detection_id}"
        )
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.get(
    "/training-labels",
    summary="Verdicts as training labels: GeoJSON polygons with label 1 (landslide) or 0",
    response_class=JSONResponse,
    responses={200: {"content": {"application/geo+json": {}}}},
)
def get_training_labels(site: SiteViewer, session: SessionDep) -> JSONResponse:
    return JSONResponse(
        training_labels(session, site.id),
        media_type="application/geo+json",
        headers={"Content-Disposition": f'attachment; filename="site-{site.id}-labels.geojson"'},
    )


@router.get(
    f"{DETECTION}/history",
    response_model=list[DetectionHistoryOut],
    summary="The same ground in the site's other comparisons: a landslide over time",
)
def get_history(
    comparison_id: RowId, detection_id: RowId, site: SiteViewer, session: SessionDep
) -> list[DetectionHistoryOut]:
    """This detection and every detection of the site's other comparisons whose polygon
    overlaps it, in the order of their post surveys, with the share of this detection's
    area each covers."""
    detection = detection_of(session, site, comparison_id, detection_id)
    return [DetectionHistoryOut(**vars(entry)) for entry in detection_history(session, detection)]
