"""A comparison's detections as GIS files: GeoPackage, KML and Shapefile (zipped).

Written by OGR through pyogrio (GDAL bundled in its wheel), from the same features as the
API's GeoJSON: the same label (1…n), the same flat fields. A shapefile is several files and
its field names are cut at 10 characters, so it is sent as one zip with short names chosen
here (not OGR's truncation, which could make two fields alike).
"""

from __future__ import annotations

import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pyogrio.raw import write
from shapely import to_wkb
from shapely.geometry import MultiPolygon, Polygon, shape

from backend.db.detections import detection_labels, detection_properties
from backend.db.models import Comparison


@dataclass(frozen=True)
class ExportFormat:
    driver: str
    suffix: str  # of the file sent
    media_type: str


FORMATS: dict[str, ExportFormat] = {
    "gpkg": ExportFormat("GPKG", "gpkg", "application/geopackage+sqlite3"),
    "kml": ExportFormat("KML", "kml", "application/vnd.google-earth.kml+xml"),
    "shp": ExportFormat("ESRI Shapefile", "shp.zip", "application/zip"),
}

# (field, shapefile name): every name fits the shapefile's 10 characters.
_FIELDS = (
    ("label", "label"),
    ("detection_id", "det_id"),
    ("comparison_id", "comp_id"),
    ("area_m2", "area_m2"),
    ("volume_loss_m3", "vol_loss"),
    ("volume_gain_m3", "vol_gain"),
    ("max_abs_dh_m", "max_dh_m"),
    ("score", "score"),
    ("method", "method"),
)


def _rows(comparison: Comparison) -> list[dict[str, Any]]:
    labels = detection_labels(comparison)
    rows = []
    for row in comparison.detections:
        properties = detection_properties(row).to_dict()
        rows.append(
            {
                "label": labels[row.id],
                "detection_id": row.id,
                "comparison_id": comparison.id,
                **{name: properties[name] for name, _ in _FIELDS[3:]},
                "geometry": row.geometry,
            }
        )
    return rows


def _multi(geometry: dict[str, Any]) -> MultiPolygon:
    # One geometry type per layer (shapefiles and GeoPackages declare it).
    found = shape(geometry)
    return MultiPolygon([found]) if isinstance(found, Polygon) else found


def write_detections(comparison: Comparison, kind: str, folder: Path) -> Path:
    """Write the detections in `kind` (a key of FORMATS) under `folder`; the file to send."""
    spec = FORMATS[kind]
    rows = _rows(comparison)
    name = f"comparison-{comparison.id}-detections"
    short = kind == "shp"
    fields = [short_name if short else field for field, short_name in _FIELDS]
    data = [
        np.array([r["label"] for r in rows], dtype=np.int32),
        np.array([r["detection_id"] for r in rows], dtype=np.int64),
        np.array([r["comparison_id"] for r in rows], dtype=np.int64),
        *(np.array([r[f] for r in rows], dtype=np.float64) for f, _ in _FIELDS[3:8]),
        np.array([r["method"] for r in rows], dtype=object),
    ]
    geometry = np.array([to_wkb(_multi(r["geometry"])) for r in rows], dtype=object)
    target = folder / (f"{name}.shp" if short else f"{name}.{spec.suffix}")
    write(
        str(target),
        geometry,
        data,
        fields,
        driver=spec.driver,
        geometry_type="MultiPolygon",
        crs="EPSG:4326",
        layer=name,
        encoding="UTF-8" if short else None,
    )
    if not short:
        return target
    archive = folder / f"{name}.{spec.suffix}"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as bundle:
        for part in sorted(folder.glob(f"{name}.*")):
            if part != archive:
                bundle.write(part, part.name)
    return archive


def export_bytes(comparison: Comparison, kind: str) -> bytes:
    """The file's bytes (small: a comparison has tens of detections, not millions)."""
    with tempfile.TemporaryDirectory(prefix="slidewatch-export-") as folder:
        return write_detections(comparison, kind, Path(folder)).read_bytes()
