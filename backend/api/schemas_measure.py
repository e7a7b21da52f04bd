"""Request and answer bodies of the map's measurements (profile, volume)."""

from typing import Any, Literal

from pydantic import BaseModel, Field

from worker.pipeline.measure import MAX_PROFILE_SAMPLES


class LineGeometry(BaseModel):
    type: Literal["LineString"]
    # Up to 1000 vertices: a line drawn by hand has tens.
    coordinates: list[list[float]] = Field(min_length=2, max_length=1000)


class PolygonGeometry(BaseModel):
    type: Literal["Polygon"]
    coordinates: list[list[list[float]]] = Field(min_length=1, max_length=1)


class ProfileRequest(BaseModel):
    line: LineGeometry = Field(description="GeoJSON LineString in WGS84 lon/lat.")
    samples: int = Field(default=400, ge=2, le=MAX_PROFILE_SAMPLES)


class ProfileOut(BaseModel):
    distance_m: list[float]
    heights_m: dict[str, list[float | None]] = Field(
        description="Per DSM (pre and post for a comparison, the post one co-registered; "
        "dsm for a survey): heights along the line, null where it has none."
    )
    length_m: float
    step_m: float


class VolumeRequest(BaseModel):
    polygon: PolygonGeometry = Field(description="GeoJSON Polygon in WGS84 lon/lat.")


class VolumeOut(BaseModel):
    area_m2: float
    measured_m2: float
    cut_m3: float = Field(description="Material lost (post below pre), as a positive volume.")
    fill_m3: float = Field(description="Material gained.")
    net_m3: float = Field(description="fill − cut.")
    cut_beyond_lod_m3: float = Field(description="cut of the cells whose |Δh| exceeds the LoD.")
    fill_beyond_lod_m3: float
    lod_m: float | None = Field(description="Median level of detection (95 %) in the polygon.")
    cells: int


def geometry_dict(model: BaseModel) -> dict[str, Any]:
    return model.model_dump()
