"""A method's `detections.geojson` (WGS84 lon/lat, RFC 7946) read onto a pair's grid.

Gives the detection pixels (a polygon burns the pixels whose centre it covers), their
8-connected components, and which components each feature lies on, so that the volumes
the method reported (`volume_loss_m3`, `volume_gain_m3`) can be summed per slide.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pyproj import CRS, Transformer
from rasterio.transform import Affine
from scipy import ndimage
from shapely.geometry import shape as to_shape
from shapely.geometry.base import BaseGeometry

EIGHT_CONNECTED = np.ones((3, 3), dtype=bool)


@dataclass
class GridDetections:
    mask: np.ndarray  # bool, detection pixels
    components: np.ndarray  # int32, 8-connected components of `mask` (1..n), 0 elsewhere
    feature_components: list[frozenset[int]] = field(default_factory=list)
    feature_volume_m3: list[float] = field(default_factory=list)  # loss + gain per feature

    @classmethod
    def empty(cls, shape: tuple[int, int]) -> GridDetections:
        """Nothing detected (also how a failed run is scored)."""
        return cls(np.zeros(shape, dtype=bool), np.zeros(shape, dtype=np.int32))

    @property
    def features(self) -> int:
        return len(self.feature_volume_m3)

    def volume_on(self, component_ids: Iterable[int]) -> float:
        """Loss + gain reported by the features lying on any of these components, each
        feature counted once (a cnn detection's depletion and deposit may be two parts)."""
        ids = set(component_ids)
        return float(
            sum(
                volume
                for parts, volume in zip(
                    self.feature_components, self.feature_volume_m3, strict=True
                )
                if parts & ids
            )
        )


def detection_mask(
    detections_geojson_path: Path, transform: Affine, shape: tuple[int, int], crs: Any
) -> np.ndarray:
    """The detections burnt into a bool mask on the grid (`crs`: a metric CRS)."""
    # The paper benchmark's rasteriser already does this (WGS84 -> grid CRS, pixel
    # centres); imported here because its module loads torch, which metrics do not need.
    from worker.training.evaluation import rasterize_detections

    return rasterize_detections(Path(detections_geojson_path), tuple(shape), transform, crs)


def read_detections(
    detections_geojson_path: Path, transform: Affine, shape: tuple[int, int], crs: Any
) -> GridDetections:
    """Mask, components and per-feature volumes of a detections file on the grid."""
    mask = detection_mask(detections_geojson_path, transform, shape, crs)
    components, _ = ndimage.label(mask, structure=EIGHT_CONNECTED)
    components = components.astype(np.int32)
    collection = json.loads(Path(detections_geojson_path).read_text())
    to_grid = Transformer.from_crs("EPSG:4326", CRS.from_user_input(crs), always_xy=True)
    parts: list[frozenset[int]] = []
    volumes: list[float] = []
    for feature in collection.get("features", []):
        props = feature.get("properties") or {}
        volumes.append(
            float(props.get("volume_loss_m3") or 0.0) + float(props.get("volume_gain_m3") or 0.0)
        )
        geometry = to_shape(feature["geometry"])
        parts.append(_components_under(geometry, components, to_grid, transform))
    return GridDetections(mask, components, parts, volumes)


def _components_under(
    geometry: BaseGeometry, components: np.ndarray, to_grid: Transformer, transform: Affine
) -> frozenset[int]:
    """The components on which a feature's polygons lie, found from one interior point
    per polygon (cheaper than burning every feature apart, and enough: polygons follow
    pixel edges of the same grid, so an interior point falls on a burnt pixel)."""
    polygons = getattr(geometry, "geoms", [geometry])
    found: set[int] = set()
    height, width = components.shape
    for polygon in polygons:
        point = polygon.representative_point()
        x, y = to_grid.transform(point.x, point.y)
        col, row = ~transform * (x, y)
        r, c = int(np.floor(row)), int(np.floor(col))
        if not (0 <= r < height and 0 <= c < width):
            continue
        label = int(components[r, c])
        if label == 0:
            # A point on a pixel edge may round onto the unburnt side: look next door.
            window = components[max(r - 1, 0) : r + 2, max(c - 1, 0) : c + 2]
            labels = window[window > 0]
            label = int(labels[0]) if labels.size else 0
        if label:
            found.add(label)
    return frozenset(found)


__all__ = ["GridDetections", "detection_mask", "read_detections"]
