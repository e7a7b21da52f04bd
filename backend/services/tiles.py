"""Map layers of surveys and comparisons: web-map tiles, TileJSON and WMTS capabilities.

A layer is a named style of one raster product that we own:

    survey      dsm        the DSM, colormap `terrain`, stretched to its 2nd..98th percentile
                hillshade  the DSM shaded (titiler's HillShade, sun from the north-west)
    comparison  dh         Δh = post − pre, colormap `rdbu_r`, symmetric around zero
                dsm        the co-registered post DSM, as the survey DSM
                hillshade  the co-registered post DSM shaded

Tiles are read with rio-tiler from the product's COG in the WebMercatorQuad grid
(EPSG:3857, 256 px). Only paths that the caller resolved from our own ids reach `Reader`.
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import morecantile
import numpy as np
from rasterio.enums import Resampling
from rio_tiler.colormap import cmap
from rio_tiler.errors import TileOutsideBounds
from rio_tiler.io import Reader
from rio_tiler.models import ImageData
from scipy import ndimage
from titiler.core.algorithm import HillShade

from backend.geotiff import NotGeoTiff, is_geotiff, open_geotiff

TMS = morecantile.tms.get("WebMercatorQuad")
TILE_SIZE = 256
HILLSHADE_BUFFER = 3
MAX_ZOOM = 24
EARTH_CIRCUMFERENCE_M = 2 * math.pi * 6378137.0

__all__ = ["NotGeoTiff", "TileOutsideBounds", "is_geotiff", "open_geotiff"]


class LayerStyle:
    elevation = "elevation"
    difference = "difference"
    hillshade = "hillshade"


@dataclass(frozen=True)
class LayerSpec:
    name: str
    product_kind: str
    style: str
    title: str
    default_colormap: str | None


SURVEY_LAYERS: dict[str, LayerSpec] = {
    "dsm": LayerSpec("dsm", "dsm", LayerStyle.elevation, "DSM", "terrain"),
    "hillshade": LayerSpec("hillshade", "dsm", LayerStyle.hillshade, "Hillshade", None),
}
COMPARISON_LAYERS: dict[str, LayerSpec] = {
    "dh": LayerSpec("dh", "dh", LayerStyle.difference, "Δh (post − pre)", "rdbu_r"),
    "dsm": LayerSpec(
        "dsm", "post_coregistered", LayerStyle.elevation, "DSM (post, co-registered)", "terrain"
    ),
    "hillshade": LayerSpec(
        "hillshade", "post_coregistered", LayerStyle.hillshade, "Hillshade (post)", None
    ),
}
LAYERS = {"surveys": SURVEY_LAYERS, "comparisons": COMPARISON_LAYERS}


class BadStyle(ValueError):
    """A rescale or colormap that cannot be used; the message says why."""


@dataclass(frozen=True)
class RasterStats:
    p2: float
    p98: float
    max_abs: float  # 98th percentile of |value|, for symmetric stretches


@dataclass(frozen=True)
class LayerInfo:
    bounds: tuple[float, float, float, float]  # lon/lat
    minzoom: int
    maxzoom: int


def _key(path: Path) -> tuple[str, int, int]:
    stat = os.stat(path)
    return str(path), stat.st_mtime_ns, stat.st_size


def raster_stats(path: Path) -> RasterStats:
    return _raster_stats(*_key(path))


@lru_cache(maxsize=256)
def _raster_stats(path: str, _mtime: int, _size: int) -> RasterStats:
    """Percentiles from a decimated read (the COG's overviews make it cheap)."""
    with open_geotiff(path) as src:
        scale = max(1.0, max(src.width, src.height) / 1024)
        shape = (max(1, int(src.height / scale)), max(1, int(src.width / scale)))
        data = src.read(1, out_shape=shape, masked=True, resampling=Resampling.nearest)
    values = np.asarray(data.compressed(), dtype="float64")
    values = values[np.isfinite(values)]
    if values.size == 0:
        return RasterStats(0.0, 1.0, 1.0)
    p2, p98 = np.percentile(values, [2, 98])
    max_abs = float(np.percentile(np.abs(values), 98))
    return RasterStats(float(p2), float(p98), max(max_abs, 0.01))


def layer_info(path: Path) -> LayerInfo:
    return _layer_info(*_key(path))


@lru_cache(maxsize=256)
def _layer_info(path: str, _mtime: int, _size: int) -> LayerInfo:
    with open_geotiff(path) as dataset, Reader(path, dataset=dataset, tms=TMS) as reader:
        bounds = tuple(float(b) for b in reader.get_geographic_bounds(TMS.rasterio_geographic_crs))
        return LayerInfo(bounds, int(reader.minzoom), min(int(reader.maxzoom) + 2, MAX_ZOOM))  # type: ignore[arg-type]


def parse_rescale(value: str | None) -> tuple[float, float] | None:
    if value is None:
        return None
    try:
        low, high = (float(v) for v in value.split(","))
    except ValueError:
        raise BadStyle(f"rescale {value!r} must be two numbers: min,max") from None
    if not (math.isfinite(low) and math.isfinite(high)) or low >= high:
        raise BadStyle(f"rescale {value!r}: min must be smaller than max")
    return low, high


def check_colormap(name: str | None) -> str | None:
    if name is not None and name not in cmap.list():
        raise BadStyle(f"unknown colormap {name!r}; e.g. terrain, viridis, rdbu_r, balance")
    return name


def default_rescale(spec: LayerSpec, path: Path) -> tuple[float, float]:
    stats = raster_stats(path)
    if spec.style == LayerStyle.difference:
        return -stats.max_abs, stats.max_abs  # zero change sits in the middle
    if stats.p98 <= stats.p2:
        return stats.p2 - 0.5, stats.p2 + 0.5
    return stats.p2, stats.p98


def _pixel_size_m(z: int, y: int) -> float:
    """Ground size of one pixel of tile row `y` at zoom `z` (Web Mercator, tile centre)."""
    lat = TMS.bounds(morecantile.Tile(0, y, z)).top
    lat_bottom = TMS.bounds(morecantile.Tile(0, y, z)).bottom
    centre = math.radians((lat + lat_bottom) / 2)
    return EARTH_CIRCUMFERENCE_M * math.cos(centre) / (TILE_SIZE * 2**z)


def _hillshade(img: ImageData, z: int, y: int) -> ImageData:
    valid = ~np.ma.getmaskarray(img.array[0])
    filled = np.ma.filled(img.array.astype("float32"), np.nan)
    # Fill holes with the nearest value so that gradients stay finite; masked again below.
    if not valid.all() and valid.any():
        index = ndimage.distance_transform_edt(~valid, return_distances=False, return_indices=True)
        filled[0] = filled[0][tuple(index)]
    algorithm = HillShade(
        azimuth=315,
        angle_altitude=45.0,
        buffer=HILLSHADE_BUFFER,
        z_exaggeration=min(max(1.0 / _pixel_size_m(z, y), 1e-6), 1e6),
    )
    with np.errstate(invalid="ignore"):
        shaded = algorithm(ImageData(np.nan_to_num(filled), crs=img.crs, bounds=img.bounds))
    b = HILLSHADE_BUFFER
    keep = ndimage.binary_erosion(valid, iterations=1)[b:-b, b:-b]
    data = np.ma.MaskedArray(shaded.array.data, mask=~keep[np.newaxis])
    return ImageData(data, crs=shaded.crs, bounds=shaded.bounds)


def render_tile(
    path: Path,
    spec: LayerSpec,
    z: int,
    x: int,
    y: int,
    rescale: tuple[float, float] | None = None,
    colormap: str | None = None,
) -> bytes:
    """A 256 px PNG of tile z/x/y; raises TileOutsideBounds outside the raster."""
    with open_geotiff(path) as dataset, Reader(str(path), dataset=dataset, tms=TMS) as reader:
        if spec.style == LayerStyle.hillshade:
            img = reader.tile(
                x,
                y,
                z,
                tilesize=TILE_SIZE,
                buffer=HILLSHADE_BUFFER,
                resampling_method="cubic",
                reproject_method="cubic",
            )
            img = _hillshade(img, z, y)
            if rescale is not None:
                img = img.rescale(in_range=(rescale,))
            name = colormap
        else:
            img = reader.tile(
                x,
                y,
                z,
                tilesize=TILE_SIZE,
                resampling_method="bilinear",
                reproject_method="bilinear",
            )
            img = img.rescale(in_range=(rescale or default_rescale(spec, path),))
            name = colormap or spec.default_colormap
    return img.render(img_format="PNG", colormap=cmap.get(name) if name else None)


# --- WMTS -------------------------------------------------------------------------------

NS = {
    "": "http://www.opengis.net/wmts/1.0",
    "ows": "http://www.opengis.net/ows/1.1",
    "xlink": "http://www.w3.org/1999/xlink",
}


@dataclass(frozen=True)
class WmtsLayer:
    identifier: str
    title: str
    abstract: str
    info: LayerInfo
    template: str  # with {TileMatrix}, {TileCol}, {TileRow}


def _q(prefix: str, tag: str) -> str:
    return f"{{{NS[prefix]}}}{tag}"


def _sub(parent: ET.Element, prefix: str, tag: str, text: str | None = None, **attrs: str):
    element = ET.SubElement(parent, _q(prefix, tag), attrs)
    if text is not None:
        element.text = text
    return element


def wmts_capabilities(title: str, self_url: str, layers: list[WmtsLayer]) -> bytes:
    """A RESTful WMTS 1.0.0 GetCapabilities document for `layers` in WebMercatorQuad."""
    for prefix, uri in NS.items():
        ET.register_namespace(prefix, uri)
    root = ET.Element(_q("", "Capabilities"), {"version": "1.0.0"})
    ident = _sub(root, "ows", "ServiceIdentification")
    _sub(ident, "ows", "Title", title)
    _sub(ident, "ows", "ServiceType", "OGC WMTS")
    _sub(ident, "ows", "ServiceTypeVersion", "1.0.0")
    operations = _sub(root, "ows", "OperationsMetadata")
    for name in ("GetCapabilities", "GetTile"):
        op = _sub(operations, "ows", "Operation", name=name)
        get = _sub(_sub(_sub(op, "ows", "DCP"), "ows", "HTTP"), "ows", "Get")
        get.set(_q("xlink", "href"), self_url)
        constraint = _sub(get, "ows", "Constraint", name="GetEncoding")
        _sub(_sub(constraint, "ows", "AllowedValues"), "ows", "Value", "RESTful")
    contents = _sub(root, "", "Contents")
    max_zoom = max((layer.info.maxzoom for layer in layers), default=MAX_ZOOM)
    for layer in layers:
        element = _sub(contents, "", "Layer")
        _sub(element, "ows", "Title", layer.title)
        _sub(element, "ows", "Abstract", layer.abstract)
        west, south, east, north = layer.info.bounds
        box = _sub(element, "ows", "WGS84BoundingBox", crs="urn:ogc:def:crs:OGC:2:84")
        _sub(box, "ows", "LowerCorner", f"{west:.7f} {south:.7f}")
        _sub(box, "ows", "UpperCorner", f"{east:.7f} {north:.7f}")
        _sub(element, "ows", "Identifier", layer.identifier)
        style = _sub(element, "", "Style", isDefault="true")
        _sub(style, "ows", "Identifier", "default")
        _sub(element, "", "Format", "image/png")
        link = _sub(element, "", "TileMatrixSetLink")
        _sub(link, "", "TileMatrixSet", TMS.id)
        limits = _sub(link, "", "TileMatrixSetLimits")
        for z in range(layer.info.minzoom, layer.info.maxzoom + 1):
            first = TMS.tile(west, north, z)
            last = TMS.tile(east, south, z)
            limit = _sub(limits, "", "TileMatrixLimits")
            _sub(limit, "", "TileMatrix", str(z))
            _sub(limit, "", "MinTileRow", str(first.y))
            _sub(limit, "", "MaxTileRow", str(last.y))
            _sub(limit, "", "MinTileCol", str(first.x))
            _sub(limit, "", "MaxTileCol", str(last.x))
        _sub(
            element,
            "",
            "ResourceURL",
            format="image/png",
            resourceType="tile",
            template=layer.template,
        )
    matrix_set = _sub(contents, "", "TileMatrixSet")
    _sub(matrix_set, "ows", "Identifier", TMS.id)
    _sub(matrix_set, "ows", "SupportedCRS", "urn:ogc:def:crs:EPSG::3857")
    _sub(matrix_set, "", "WellKnownScaleSet", "urn:ogc:def:wkss:OGC:1.0:GoogleMapsCompatible")
    for z in range(0, max_zoom + 1):
        matrix = TMS.matrix(z)
        element = _sub(matrix_set, "", "TileMatrix")
        _sub(element, "ows", "Identifier", str(z))
        _sub(element, "", "ScaleDenominator", repr(matrix.scaleDenominator))
        x0, y0 = matrix.pointOfOrigin
        _sub(element, "", "TopLeftCorner", f"{x0!r} {y0!r}")
        _sub(element, "", "TileWidth", str(matrix.tileWidth))
        _sub(element, "", "TileHeight", str(matrix.tileHeight))
        _sub(element, "", "MatrixWidth", str(matrix.matrixWidth))
        _sub(element, "", "MatrixHeight", str(matrix.matrixHeight))
    metadata = _sub(root, "", "ServiceMetadataURL")
    metadata.set(_q("xlink", "href"), self_url)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True)
