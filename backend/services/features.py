"""Features for OGC API – Features: sites, survey footprints and detected landslides.

Plain SQL over the portable schema (no spatial extension), so it runs on SQLite and
PostgreSQL alike: detections are filtered by their bounding-box columns in the database;
sites and survey footprints, of which a deployment has few, are filtered in Python.
Geometries are GeoJSON in WGS84 lon/lat (CRS84), as stored.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from shapely.geometry import shape
from shapely.ops import unary_union
from sqlalchemy import Select, func, select
from sqlalchemy.orm import Session, aliased

from backend.db.models import Comparison, Detection, JobState, Site, Survey, SurveyStatus
from backend.geojson_input import is_area_of_interest
from worker.pipeline.geo import geojson_rfc7946

BBox = tuple[float, float, float, float]


@dataclass(frozen=True)
class Interval:
    """A closed time interval; None for an open end. An instant has start == end."""

    start: datetime | None
    end: datetime | None

    def contains(self, moment: datetime | None) -> bool:
        if moment is None:
            return False
        moment = aware(moment)
        return (self.start is None or moment >= self.start) and (
            self.end is None or moment <= self.end
        )


@dataclass(frozen=True)
class FeatureQuery:
    limit: int = 100
    offset: int = 0
    bbox: BBox | None = None
    datetime: Interval | None = None
    site_id: int | None = None
    comparison_id: int | None = None
    # The sites whose features the caller may see; None: every site.
    visible: frozenset[int] | None = None


@dataclass(frozen=True)
class Collection:
    id: str
    title: str
    description: str
    temporal: bool  # whether `datetime` filters it


COLLECTIONS: dict[str, Collection] = {
    c.id: c
    for c in (
        Collection(
            "sites",
            "Monitored sites",
            "Each monitored slope: its area of interest, or else the extent of its surveys.",
            temporal=False,
        ),
        Collection(
            "surveys",
            "Survey footprints",
            "The ground covered by each survey's DSM; datetime is when it was flown.",
            temporal=True,
        ),
        Collection(
            "detections",
            "Detected landslides",
            "Landslides found by the comparisons of all sites, with area, volumes, largest "
            "|Δh| and score; datetime is when the later survey of the comparison was flown.",
            temporal=True,
        ),
    )
}


def aware(moment: datetime) -> datetime:
    # SQLite returns naive datetimes for timezone-aware columns; they are stored in UTC.
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)


def rfc3339(moment: datetime | None) -> str | None:
    if moment is None:
        return None
    return aware(moment).astimezone(UTC).isoformat().replace("+00:00", "Z")


def _intersects(bounds: BBox | None, bbox: BBox) -> bool:
    if bounds is None:
        return False
    return not (
        bounds[2] < bbox[0] or bounds[0] > bbox[2] or bounds[3] < bbox[1] or bounds[1] > bbox[3]
    )


# --- sites ------------------------------------------------------------------------------


def _site_geometry(site: Site) -> dict[str, Any] | None:
    # A site saved before areas were checked may hold one that is no GeoJSON: its
    # surveys' extent stands in for it rather than break the collection for everyone.
    if site.area_of_interest and is_area_of_interest(site.area_of_interest):
        return site.area_of_interest
    footprints = [shape(s.footprint) for s in site.surveys if s.footprint]
    if not footprints:
        return None
    return geojson_rfc7946(unary_union(footprints).convex_hull)


def _site_feature(site: Site) -> dict[str, Any]:
    captured = [s.captured_at for s in site.surveys]
    return {
        "type": "Feature",
        "id": site.id,
        "geometry": _site_geometry(site),
        "properties": {
            "name": site.name,
            "description": site.description,
            "surveys": len(site.surveys),
            "latest_survey_at": rfc3339(max(captured)) if captured else None,
            "created_at": rfc3339(site.created_at),
        },
    }


# --- surveys ----------------------------------------------------------------------------


def _survey_feature(survey: Survey) -> dict[str, Any]:
    return {
        "type": "Feature",
        "id": survey.id,
        "geometry": survey.footprint,
        "properties": {
            "site_id": survey.site_id,
            "name": survey.name,
            "datetime": rfc3339(survey.captured_at),
            "kind": str(survey.kind),
            "status": str(survey.status),
            "crs": survey.crs,
            "resolution_m": survey.resolution_m,
        },
    }


def _surveys_query(q: FeatureQuery) -> Select:
    query = select(Survey).order_by(Survey.id)
    if q.site_id is not None:
        query = query.where(Survey.site_id == q.site_id)
    if q.visible is not None:
        query = query.where(Survey.site_id.in_(q.visible))
    if q.datetime is not None:
        if q.datetime.start is not None:
            query = query.where(Survey.captured_at >= q.datetime.start)
        if q.datetime.end is not None:
            query = query.where(Survey.captured_at <= q.datetime.end)
    return query


# --- detections -------------------------------------------------------------------------

_Post = aliased(Survey)
_Earlier = aliased(Detection)
# A detection's label, 1…n in its comparison (as in the page, its GeoJSON and the report):
# how many of its comparison's detections come before it, itself included.
_LABEL = (
    select(func.count())
    .where(_Earlier.comparison_id == Detection.comparison_id, _Earlier.id <= Detection.id)
    .correlate(Detection)
    .scalar_subquery()
)


def _detections_query(q: FeatureQuery) -> Select:
    query = (
        select(Detection, Comparison, _Post.captured_at, _LABEL)
        .join(Comparison, Detection.comparison_id == Comparison.id)
        .join(_Post, Comparison.post_survey_id == _Post.id)
        .where(Comparison.status == JobState.succeeded)
    )
    if q.site_id is not None:
        query = query.where(Comparison.site_id == q.site_id)
    if q.visible is not None:
        query = query.where(Comparison.site_id.in_(q.visible))
    if q.comparison_id is not None:
        query = query.where(Detection.comparison_id == q.comparison_id)
    if q.bbox is not None:
        min_x, min_y, max_x, max_y = q.bbox
        query = query.where(
            Detection.max_lon >= min_x,
            Detection.min_lon <= max_x,
            Detection.max_lat >= min_y,
            Detection.min_lat <= max_y,
        )
    if q.datetime is not None:
        if q.datetime.start is not None:
            query = query.where(_Post.captured_at >= q.datetime.start)
        if q.datetime.end is not None:
            query = query.where(_Post.captured_at <= q.datetime.end)
    return query


def _detection_feature(
    detection: Detection, comparison: Comparison, observed_at: datetime, label: int
) -> dict[str, Any]:
    return {
        "type": "Feature",
        "id": detection.id,
        "geometry": detection.geometry,
        "properties": {
            "site_id": comparison.site_id,
            "comparison_id": comparison.id,
            "label": label,
            "pre_survey_id": comparison.pre_survey_id,
            "post_survey_id": comparison.post_survey_id,
            "datetime": rfc3339(observed_at),
            "area_m2": round(detection.area_m2, 3),
            "volume_loss_m3": round(detection.volume_loss_m3, 3),
            "volume_gain_m3": round(detection.volume_gain_m3, 3),
            "max_abs_dh_m": round(detection.max_abs_dh_m, 3),
            "score": round(detection.score, 4),
            "method": detection.method,
            **_uncertainty_properties(detection.uncertainty),
        },
    }


# Flat, always present (null where unknown): GIS clients (QGIS, OGR) read one typed column
# per property, not nested objects, and infer the columns from the features they see.
_INTERVALS = ("area_m2_ci95", "volume_loss_m3_ci95", "volume_gain_m3_ci95")


def _uncertainty_properties(uncertainty: dict[str, Any] | None) -> dict[str, float | None]:
    """The detection's 95 % intervals as `<name>_low`/`<name>_high`, and its LoD."""
    values = uncertainty or {}
    flat: dict[str, float | None] = {}
    for name in _INTERVALS:
        interval = values.get(name)
        low, high = interval if interval else (None, None)
        flat[f"{name}_low"], flat[f"{name}_high"] = low, high
    flat["lod_m"] = values.get("lod_m")
    return flat


# --- queries ----------------------------------------------------------------------------


def query_features(
    session: Session, collection_id: str, q: FeatureQuery
) -> tuple[list[dict[str, Any]], int]:
    """One page of features of a collection, and how many match in all."""
    if collection_id == "detections":
        query = _detections_query(q)
        matched = session.scalar(select(func.count()).select_from(query.subquery())) or 0
        rows = session.execute(query.order_by(Detection.id).limit(q.limit).offset(q.offset))
        return [_detection_feature(*row) for row in rows], matched
    if collection_id == "surveys":
        surveys = [
            s
            for s in session.scalars(_surveys_query(q))
            if q.bbox is None or (s.footprint and _intersects(shape(s.footprint).bounds, q.bbox))
        ]
        page = surveys[q.offset : q.offset + q.limit]
        return [_survey_feature(s) for s in page], len(surveys)
    if collection_id == "sites":
        query = select(Site).order_by(Site.id)
        if q.site_id is not None:
            query = query.where(Site.id == q.site_id)
        if q.visible is not None:
            query = query.where(Site.id.in_(q.visible))
        features = [_site_feature(site) for site in session.scalars(query)]
        if q.bbox is not None:
            features = [
                f
                for f in features
                if f["geometry"] and _intersects(shape(f["geometry"]).bounds, q.bbox)
            ]
        return features[q.offset : q.offset + q.limit], len(features)
    raise KeyError(collection_id)


def get_feature(
    session: Session, collection_id: str, feature_id: int, visible: frozenset[int] | None = None
) -> dict[str, Any] | None:
    """One feature; None when there is none, or it is of a site not in `visible`."""
    if collection_id == "detections":
        row = session.execute(
            _detections_query(FeatureQuery(visible=visible)).where(Detection.id == feature_id)
        ).first()
        return _detection_feature(*row) if row else None
    if collection_id == "surveys":
        survey = session.get(Survey, feature_id)
        seen = survey is not None and (visible is None or survey.site_id in visible)
        return _survey_feature(survey) if seen else None  # type: ignore[arg-type]
    if collection_id == "sites":
        site = session.get(Site, feature_id)
        seen = site is not None and (visible is None or site.id in visible)
        return _site_feature(site) if seen else None  # type: ignore[arg-type]
    raise KeyError(collection_id)


def collection_extent(
    session: Session, collection_id: str, visible: frozenset[int] | None = None
) -> tuple[BBox | None, tuple[str | None, str | None] | None]:
    """Spatial extent (CRS84) and temporal extent of what the caller sees of a collection
    (the sites in `visible`; None: all)."""
    if collection_id == "detections":
        seen = [] if visible is None else [Comparison.site_id.in_(visible)]
        bounds = session.execute(
            select(
                func.min(Detection.min_lon),
                func.min(Detection.min_lat),
                func.max(Detection.max_lon),
                func.max(Detection.max_lat),
                func.min(_Post.captured_at),
                func.max(_Post.captured_at),
            )
            .join(Comparison, Detection.comparison_id == Comparison.id)
            .join(_Post, Comparison.post_survey_id == _Post.id)
            .where(Comparison.status == JobState.succeeded, *seen)
        ).one()
        bbox = None if bounds[0] is None else tuple(float(b) for b in bounds[:4])
        return bbox, (_maybe_rfc3339(bounds[4]), _maybe_rfc3339(bounds[5]))  # type: ignore[return-value]
    if collection_id == "surveys":
        query = select(Survey).where(Survey.status == SurveyStatus.ready)
        if visible is not None:
            query = query.where(Survey.site_id.in_(visible))
        surveys = list(session.scalars(query))
        footprints = [shape(s.footprint) for s in surveys if s.footprint]
        bbox = tuple(unary_union(footprints).bounds) if footprints else None
        times = [s.captured_at for s in surveys]
        interval = (rfc3339(min(times)), rfc3339(max(times))) if times else (None, None)
        return bbox, interval  # type: ignore[return-value]
    if collection_id == "sites":
        geometries = [
            shape(f["geometry"])
            for f in (_site_feature(s) for s in session.scalars(_sites(visible)))
            if f["geometry"]
        ]
        return (tuple(unary_union(geometries).bounds) if geometries else None), None  # type: ignore[return-value]
    raise KeyError(collection_id)


def _sites(visible: frozenset[int] | None) -> Select:
    query = select(Site)
    return query if visible is None else query.where(Site.id.in_(visible))


def _maybe_rfc3339(value: Any) -> str | None:
    if value is None:
        return None
    if isinstance(value, str):  # SQLite aggregates return the stored text
        value = datetime.fromisoformat(value)
    return rfc3339(value)
