"""Check an uploaded DSM and describe it: CRS, size, resolution, footprint, value range."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
from rasterio.errors import RasterioError

from worker.pipeline.errors import InputError
from worker.pipeline.geo import crs_to_string, footprint_lonlat, geojson_rfc7946, pixel_size_m


@dataclass
class DsmInfo:
    """What the API stores about an uploaded DSM. Elevations are from band 1."""

    crs: str  # "EPSG:xxxx" when the CRS has an EPSG code, else WKT
    width: int
    height: int
    band_count: int
    resolution_m: tuple[float, float]  # (x, y); approximate at the centre for lon/lat
    bounds: tuple[float, float, float, float]  # left, bottom, right, top in the native CRS
    footprint: dict[str, Any]  # GeoJSON Polygon, WGS84 lon/lat, RFC 7946
    nodata: float | None
    valid_fraction: float
    min_elevation_m: float
    max_elevation_m: float
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["resolution_m"] = list(self.resolution_m)
        data["bounds"] = list(self.bounds)
        if self.nodata is not None and not math.isfinite(self.nodata):
            data["nodata"] = str(self.nodata)  # NaN is not valid JSON
        return data


def inspect_dsm(path: Path, label: str | None = None) -> DsmInfo:
    """Open `path`, read every block, and describe it; raise InputError if it is unusable.

    `label` names the file in error messages (e.g. the name a user uploaded it under).
    """
    path = Path(path)
    name = label or path.name
    if not path.is_file():
        raise InputError(f"{name} does not exist or is not a file")
    try:
        src = rasterio.open(path)
    except RasterioError as exc:
        raise InputError(f"{name} is not a GeoTIFF, nor any raster file that can be read") from exc
    with src:
        if src.driver != "GTiff":
            raise InputError(f"{name} is not a GeoTIFF (it is a {src.driver} file)")
        if src.crs is None:
            raise InputError(
                f"{name} has no coordinate reference system (CRS); "
                "export the DSM as a georeferenced GeoTIFF"
            )
        if src.transform.is_identity:
            raise InputError(f"{name} has no georeferencing (no geotransform)")
        try:
            count, low, high = _scan_band1(src)
        except RasterioError as exc:
            raise InputError(
                f"{name} is truncated or corrupt: part of its image data could not be read"
            ) from exc
        if count == 0:
            raise InputError(f"{name} contains only nodata: no valid elevation values")
        notes = []
        if src.count > 1:
            notes.append(f"{src.count} bands: elevations are read from band 1")
        bounds = tuple(float(b) for b in src.bounds)
        return DsmInfo(
            crs=crs_to_string(src.crs),
            width=src.width,
            height=src.height,
            band_count=src.count,
            resolution_m=pixel_size_m(src.transform, src.crs, (src.height, src.width)),
            bounds=bounds,  # type: ignore[arg-type]
            footprint=geojson_rfc7946(footprint_lonlat(bounds, src.crs)),  # type: ignore[arg-type]
            nodata=None if src.nodata is None else float(src.nodata),
            valid_fraction=count / (src.width * src.height),
            min_elevation_m=low,
            max_elevation_m=high,
            notes=notes,
        )


def _scan_band1(src: rasterio.DatasetReader) -> tuple[int, float, float]:
    """Read every block of every band (so truncation is caught); stats of band 1."""
    count, low, high = 0, math.inf, -math.inf
    for _, window in src.block_windows(1):
        blocks = src.read(window=window, masked=True)
        band1 = blocks[0]
        values = band1.compressed()
        values = values[np.isfinite(values)]
        if values.size:
            count += int(values.size)
            low = min(low, float(values.min()))
            high = max(high, float(values.max()))
    return count, low, high
