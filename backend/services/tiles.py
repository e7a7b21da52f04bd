"""Map layers of surveys and comparisons: web-map tiles, TileJSON and WMTS capabilities.

A layer is a named style of one raster product that we own:

    survey      dsm        the DSM, colormap `terrain`, stretched to its 2nd..98th percentile
                hillshade  the DSM shaded (titiler's HillShade formula, sun from the north-west)
                orthophoto the true orthophoto (RGB, its alpha as the mask), as it is or moved
                           by a comparison's co-registration (its rotation and shift:
                           post_motion.py)
    comparison  dh         Δh = post − pre, colormap `rdbu_r`, symmetric around zero
                dsm        the co-registered post DSM, as the survey DSM
                hillshade  the co-registered post DSM shaded

Tiles are read with rio-tiler from the product's COG in the WebMercatorQuad grid
(EPSG:3857, 256 px). Only paths that the caller resolved from our own ids reach `Reader`.
"""

from __future__ import annotations

import io
import math
import threading
import xml.etree.ElementTree as ET
from collections import OrderedDict
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import cv2
import morecantile
import numpy as np
import rasterio
from affine import Affine
from PIL import Image
from rasterio.crs import CRS
from rasterio.enums import Resampling
from rasterio.io import DatasetReader
from rasterio.warp import reproject, transform_bounds
from rasterio.windows import Window
from rasterio.windows import bounds as window_bounds
from rio_tiler.colormap import cmap
from rio_tiler.errors import TileOutsideBounds
from rio_tiler.io import Reader
from rio_tiler.models import ImageData
from scipy import ndimage

from backend.geotiff import NotGeoTiff, is_geotiff, open_geotiff
from backend.services.post_motion import PostMotion, moved_image
from backend.services.tile_cache import DiskTileCache, FileIdentity, TileKey, file_identity

TMS = morecantile.tms.get("WebMercatorQuad")
WEB_MERCATOR = CRS.from_epsg(3857)
TILE_SIZE = 256
HILLSHADE_BUFFER = 3
MAX_ZOOM = 24
EARTH_CIRCUMFERENCE_M = 2 * math.pi * 6378137.0
# Most pixels of a product one tile may decode (SLIDEWATCH_TILE_MAX_READ_PIXELS): a tile of
# a COG reads at most about 4 x 256² pixels at any zoom (its overviews), so this bites only
# on a file without overviews seen from far out, whose read would grow with the file.
DEFAULT_MAX_READ_PIXELS = 4 * 1024 * 1024

__all__ = ["NotGeoTiff", "TileOutsideBounds", "is_geotiff", "open_geotiff"]


class LayerStyle:
    elevation = "elevation"
    difference = "difference"
    hillshade = "hillshade"
    image = "image"  # colour bands drawn as they are: no stretch, no colormap


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
    "orthophoto": LayerSpec("orthophoto", "orthophoto", LayerStyle.image, "Orthophoto", None),
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


class _StatsMemo:
    """The last files' stats, readable without reading the file (on the event loop)."""

    def __init__(self, max_files: int = 256) -> None:
        self.max_files = max_files
        self._stats: OrderedDict[tuple[FileIdentity, int], RasterStats] = OrderedDict()
        self._reading: dict[tuple[FileIdentity, int], threading.Lock] = {}
        self._lock = threading.Lock()

    def peek(self, identity: FileIdentity, max_read_pixels: int) -> RasterStats | None:
        with self._lock:
            return self._stats.get((identity, max_read_pixels))

    def get(self, identity: FileIdentity, max_read_pixels: int) -> RasterStats:
        """The stats, read once however many tiles ask at once (the first tiles of a layer
        all ask for its stretch: 20 reads of the file at once took seconds)."""
        key = (identity, max_read_pixels)
        stats = self.peek(*key)
        if stats is not None:
            return stats
        with self._lock:
            reading = self._reading.setdefault(key, threading.Lock())
        with reading:
            stats = self.peek(*key)
            if stats is None:
                stats = _raster_stats(identity, max_read_pixels)
                with self._lock:
                    self._stats[key] = stats
                    while len(self._stats) > self.max_files:
                        self._stats.popitem(last=False)
                    self._reading.pop(key, None)
        return stats


_STATS = _StatsMemo()


def raster_stats(path: Path, max_read_pixels: int = DEFAULT_MAX_READ_PIXELS) -> RasterStats:
    return _STATS.get(file_identity(path), max_read_pixels)


def _raster_stats(identity: FileIdentity, max_read_pixels: int) -> RasterStats:
    """Percentiles from a decimated read (the COG's overviews make it cheap). A file
    without overviews would be decoded whole for that: then the percentiles come from the
    central window of at most `max_read_pixels` instead, so that the read stays bounded."""
    with open_geotiff(identity.path) as src:
        scale = max(1.0, max(src.width, src.height) / 1024)
        shape = (max(1, int(src.height / scale)), max(1, int(src.width / scale)))
        factor = _overview_factor(src, scale)
        if math.ceil(src.width / factor) * math.ceil(src.height / factor) <= max_read_pixels:
            data = src.read(1, out_shape=shape, masked=True, resampling=Resampling.nearest)
        else:
            side = max(1, math.isqrt(max_read_pixels))
            width, height = min(side, src.width), min(side, src.height)
            window = Window((src.width - width) // 2, (src.height - height) // 2, width, height)
            data = src.read(1, window=window, masked=True)
    values = np.asarray(data.compressed(), dtype="float64")
    values = values[np.isfinite(values)]
    if values.size == 0:
        return RasterStats(0.0, 1.0, 1.0)
    p2, p98 = np.percentile(values, [2, 98])
    max_abs = float(np.percentile(np.abs(values), 98))
    return RasterStats(float(p2), float(p98), max(max_abs, 0.01))


def layer_info(path: Path) -> LayerInfo:
    return _layer_info(file_identity(path))


@lru_cache(maxsize=256)
def _layer_info(identity: FileIdentity) -> LayerInfo:
    path = identity.path
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


def nice_ceil(value: float) -> float:
    """The smallest of 1, 2, 2.5, 5 x a power of ten not below `value` (as the page's
    legends round)."""
    power = 10.0 ** math.floor(math.log10(value))
    for step in (1, 2, 2.5, 5, 10):
        if value <= step * power + 1e-9:
            return step * power
    return 10 * power


def _default_rescale(spec: LayerSpec, stats: RasterStats) -> tuple[float, float]:
    """The stretch drawn when none is asked for, as TileJSON announces it: to the mm, and
    Δh's a round extent around zero, which are the numbers the page asks for again
    (`?rescale=`), so that its tiles and a GIS's are the same tiles (one cache entry)."""
    if spec.style == LayerStyle.difference:
        extent = round(nice_ceil(max(stats.max_abs, 0.01)), 3)
        return -extent, extent  # zero change sits in the middle
    if stats.p98 <= stats.p2:
        return round(stats.p2 - 0.5, 3), round(stats.p2 + 0.5, 3)
    return round(stats.p2, 3), round(stats.p98, 3)


def default_rescale(
    spec: LayerSpec, path: Path, max_read_pixels: int = DEFAULT_MAX_READ_PIXELS
) -> tuple[float, float]:
    return _default_rescale(spec, raster_stats(path, max_read_pixels))


def known_default_rescale(
    spec: LayerSpec, identity: FileIdentity, max_read_pixels: int = DEFAULT_MAX_READ_PIXELS
) -> tuple[float, float] | None:
    """`default_rescale` if this process knows the file's stats already (no file read),
    else None."""
    with _STRETCHES_LOCK:
        stretch = _STRETCHES.get((identity, spec.name, max_read_pixels))
    if stretch is not None:
        return stretch
    stats = _STATS.peek(identity, max_read_pixels)
    return None if stats is None else _default_rescale(spec, stats)


# Default stretches this process has read from the notes beside the tiles.
_STRETCHES: OrderedDict[tuple[FileIdentity, str, int], tuple[float, float]] = OrderedDict()
_STRETCHES_LOCK = threading.Lock()


def stored_default_rescale(
    disk: DiskTileCache | None,
    group: str,
    spec: LayerSpec,
    path: Path,
    max_read_pixels: int = DEFAULT_MAX_READ_PIXELS,
) -> tuple[float, float]:
    """`default_rescale`, noted beside the file's tiles on disk by whoever reads it first
    (the worker rendering ahead, mostly), so that a process that starts asks the note (a
    file of a few bytes) rather than the raster (a read of its overview, 0.2-0.3 s under
    load, which the first tiles of each layer waited for)."""
    identity = file_identity(path)
    name = f"stretch-{spec.name}-{max_read_pixels}"
    note = disk.get_note(group, identity, name) if disk is not None else None
    if isinstance(note, list) and len(note) == 2:
        stretch = float(note[0]), float(note[1])
    else:
        stretch = default_rescale(spec, path, max_read_pixels)
        if disk is not None:
            disk.put_note(group, identity, name, list(stretch))
    with _STRETCHES_LOCK:
        _STRETCHES[(identity, spec.name, max_read_pixels)] = stretch
        while len(_STRETCHES) > 256:
            _STRETCHES.popitem(last=False)
    return stretch


def stretched(spec: LayerSpec) -> bool:
    """Whether the layer's colours come from a stretch (a default one if none is asked)."""
    return spec.style in (LayerStyle.elevation, LayerStyle.difference)


def tile_key(
    identity: FileIdentity,
    spec: LayerSpec,
    z: int,
    x: int,
    y: int,
    rescale: tuple[float, float] | None,
    colormap: str | None,
    group: str,
    motion: PostMotion | None = None,
) -> TileKey:
    """The cache key of a tile, the same wherever it is rendered (an API request, a worker
    rendering ahead): `rescale` is the stretch drawn (the default one resolved), so a
    request naming the default stretch and one naming none share their tile."""
    style = f"{spec.name}/{spec.style}"
    if motion:
        style += f"@{motion.tag}"  # a moved tile is another tile
    return TileKey(identity, style, z, x, y, rescale, colormap, group)


def _pixel_size_m(z: int, y: int) -> float:
    """Ground size of one pixel of tile row `y` at zoom `z` (Web Mercator, tile centre)."""
    lat = TMS.bounds(morecantile.Tile(0, y, z)).top
    lat_bottom = TMS.bounds(morecantile.Tile(0, y, z)).bottom
    centre = math.radians((lat + lat_bottom) / 2)
    return EARTH_CIRCUMFERENCE_M * math.cos(centre) / (TILE_SIZE * 2**z)


def _shade(elevation: np.ndarray, z_exaggeration: float) -> np.ndarray:
    """titiler's HillShade (sun azimuth 315°, altitude 45°), on a plain array: the same
    formula and values, without the masked-array arithmetic that took half a hillshade
    tile's time."""
    x, y = np.gradient(elevation)
    x *= z_exaggeration
    y *= z_exaggeration
    slope = np.pi / 2.0 - np.arctan(np.sqrt(x * x + y * y))
    aspect = np.arctan2(-x, y)
    azimuth, altitude = np.deg2rad(360.0 - 315), np.deg2rad(45.0)
    shaded = np.sin(altitude) * np.sin(slope) + np.cos(altitude) * np.cos(slope) * np.cos(
        azimuth - aspect
    )
    data = 255 * (shaded + 1) / 2
    data[data < 0] = 0
    return data.astype(np.uint8)


def _hillshade(img: ImageData, z: int, y: int) -> ImageData:
    valid = ~np.ma.getmaskarray(img.array[0])
    filled = np.ma.filled(img.array[0].astype("float32"), np.nan)
    # Fill holes with the nearest value so that gradients stay finite; masked again below.
    if not valid.all() and valid.any():
        index = ndimage.distance_transform_edt(~valid, return_distances=False, return_indices=True)
        filled = filled[tuple(index)]
    exaggeration = min(max(1.0 / _pixel_size_m(z, y), 1e-6), 1e6)
    with np.errstate(invalid="ignore"):
        shaded = _shade(np.nan_to_num(filled), exaggeration)
    b = HILLSHADE_BUFFER
    keep = ndimage.binary_erosion(valid, iterations=1)[b:-b, b:-b]
    shaded = shaded[b:-b, b:-b]
    window = Window(b, b, shaded.shape[1], shaded.shape[0])
    return ImageData(
        np.ma.MaskedArray(shaded[np.newaxis], mask=~keep[np.newaxis]),
        crs=img.crs,
        bounds=window_bounds(window, img.transform),
    )


class TileTooCostly(Exception):
    """A tile whose read would decode more of the product than the limit allows (a file
    without overviews seen from far out): refused rather than read."""

    def __init__(self, pixels: int, limit: int) -> None:
        super().__init__(
            f"this tile would read {pixels} pixels of the product, more than the limit of "
            f"{limit} (SLIDEWATCH_TILE_MAX_READ_PIXELS): zoom in"
        )
        self.pixels = pixels
        self.limit = limit


def _overview_factor(dataset: DatasetReader, wanted: float) -> int:
    """The decimation GDAL reads at for a resolution `wanted` times coarser than the file:
    the coarsest overview that is not coarser than asked (1: the full resolution)."""
    factor = 1
    for level in dataset.overviews(1):
        if factor < level <= wanted:
            factor = level
    return factor


def _tile_read(dataset: DatasetReader, z: int, x: int, y: int, buffer: int) -> tuple[int, int]:
    """The pixels of `dataset` that tile z/x/y (and `buffer` pixels around it) decodes, and
    the overview decimation it reads them at: the tile's footprint in the file at the level
    GDAL picks for the tile's resolution. Whole blocks are decoded, a little more; but the
    footprint is what grows without bound as one zooms out of a file without overviews."""
    west, south, east, north = TMS.xy_bounds(morecantile.Tile(x, y, z))
    margin = buffer * (east - west) / TILE_SIZE
    left, bottom, right, top = transform_bounds(
        WEB_MERCATOR,
        dataset.crs,
        west - margin,
        south - margin,
        east + margin,
        north + margin,
        densify_pts=21,
    )
    res_x, res_y = abs(dataset.res[0]), abs(dataset.res[1])
    size = TILE_SIZE + 2 * buffer
    factor = _overview_factor(
        dataset, min((right - left) / size / res_x, (top - bottom) / size / res_y)
    )
    d_left, d_bottom, d_right, d_top = dataset.bounds
    width = min(right, d_right) - max(left, d_left)
    height = min(top, d_top) - max(bottom, d_bottom)
    if width <= 0 or height <= 0:
        return 0, factor
    return math.ceil(width / res_x / factor) * math.ceil(height / res_y / factor), factor


def tile_read_pixels(dataset: DatasetReader, z: int, x: int, y: int, buffer: int = 0) -> int:
    """How many pixels of `dataset` tile z/x/y decodes (see `_tile_read`)."""
    return _tile_read(dataset, z, x, y, buffer)[0]


class _ReaderPool:
    """Open datasets kept for the next tile of the same file, instead of opening the file
    (and parsing its header and overviews) for every tile: a few per file and overview
    level, so that concurrent renders each have their own (a GDAL dataset is not safe to
    share between threads at once), for the files used last. Keeping them open also keeps
    their decoded blocks in GDAL's cache. A file replaced has another identity, so its old
    datasets are never handed out again and are closed as they age out."""

    def __init__(self, max_files: int = 32, per_file: int = 4) -> None:
        self.max_files = max_files
        self.per_file = per_file
        self._free: OrderedDict[tuple[FileIdentity, int | None], list[Reader]] = OrderedDict()
        self._lock = threading.Lock()

    @contextmanager
    def reader(self, path: Path, overview_level: int | None = None) -> Iterator[Reader]:
        """A reader of `path`, or of its overview `overview_level` (0: the first)."""
        key = (file_identity(path), overview_level)
        with self._lock:
            free = self._free.get(key)
            reader = free.pop() if free else None
        if reader is None:
            dataset = open_geotiff(path, overview_level=overview_level)
            reader = Reader(str(path), dataset=dataset, tms=TMS)
        try:
            yield reader
        finally:
            self._release(key, reader)

    def _release(self, key: tuple[FileIdentity, int | None], reader: Reader) -> None:
        closing = []
        with self._lock:
            free = self._free.setdefault(key, [])
            self._free.move_to_end(key)
            if len(free) < self.per_file:
                free.append(reader)
            else:
                closing.append(reader)
            while len(self._free) > self.max_files:
                _, old = self._free.popitem(last=False)
                closing.extend(old)
        for old_reader in closing:
            old_reader.dataset.close()


_READERS = _ReaderPool()


def _warp_tile(
    path: Path,
    dataset: DatasetReader,
    z: int,
    x: int,
    y: int,
    buffer: int,
    method: str,
    factor: int,
) -> ImageData:
    """Tile z/x/y (with `buffer` pixels around it) warped straight from the file into its
    256 px grid, from the overview of decimation `factor` (the one GDAL would choose):
    GDAL warps only the tile's pixels, where a WarpedVRT read (rio-tiler's way) warps the
    whole footprint at the file's resolution and then resamples it to the tile, twice the
    time for a tile coarser than the file. Needs the file's nodata (our products all have
    one)."""
    size = TILE_SIZE + 2 * buffer
    left, bottom, right, top = TMS.xy_bounds(morecantile.Tile(x, y, z))
    pixel_x, pixel_y = (right - left) / TILE_SIZE, (top - bottom) / TILE_SIZE
    transform = Affine(pixel_x, 0, left - buffer * pixel_x, 0, -pixel_y, top + buffer * pixel_y)
    levels = dataset.overviews(1)
    level = levels.index(factor) if factor in levels else None
    nodata = dataset.nodata
    warped = np.full((size, size), nodata, dtype=dataset.dtypes[0])
    with _READERS.reader(path, level) as source:
        reproject(
            rasterio.band(source.dataset, 1),
            warped,
            src_nodata=nodata,
            dst_transform=transform,
            dst_crs=WEB_MERCATOR,
            dst_nodata=nodata,
            resampling=Resampling[method],
        )
    invalid = np.isnan(warped) if np.isnan(nodata) else warped == nodata
    bounds = (
        transform.c,
        transform.f - size * pixel_y,
        transform.c + size * pixel_x,
        transform.f,
    )
    return ImageData(
        np.ma.MaskedArray(warped[np.newaxis], mask=invalid[np.newaxis]),
        crs=WEB_MERCATOR,
        bounds=bounds,
    )


def render_tile(
    path: Path,
    spec: LayerSpec,
    z: int,
    x: int,
    y: int,
    rescale: tuple[float, float] | None = None,
    colormap: str | None = None,
    max_read_pixels: int = DEFAULT_MAX_READ_PIXELS,
    motion: PostMotion | None = None,
) -> bytes:
    """A 256 px PNG of tile z/x/y; raises TileOutsideBounds outside the raster and
    TileTooCostly where the read would decode more than `max_read_pixels` of the file.
    An image layer may be drawn moved by a co-registration's `motion`."""
    if spec.style == LayerStyle.image:
        return _image_tile(path, z, x, y, max_read_pixels, motion)
    hillshade = spec.style == LayerStyle.hillshade
    buffer = HILLSHADE_BUFFER if hillshade else 0
    method = "cubic" if hillshade else "bilinear"
    with _READERS.reader(path) as reader:
        if not reader.tile_exists(x, y, z):
            raise TileOutsideBounds(f"Tile(x={x}, y={y}, z={z}) is outside bounds")
        pixels, factor = _tile_read(reader.dataset, z, x, y, buffer)
        if pixels > max_read_pixels:
            raise TileTooCostly(pixels, max_read_pixels)
        if reader.dataset.nodata is not None:
            img = _warp_tile(path, reader.dataset, z, x, y, buffer, method, factor)
        else:
            img = reader.tile(
                x,
                y,
                z,
                tilesize=TILE_SIZE,
                buffer=buffer,
                resampling_method=method,
                reproject_method=method,
            )
    if hillshade:
        img = _hillshade(img, z, y)
        if rescale is not None:
            img = img.rescale(in_range=(rescale,))
        name = colormap
    else:
        stretch = rescale or default_rescale(spec, path, max_read_pixels)
        img = img.rescale(in_range=(stretch,))
        name = colormap or spec.default_colormap
    return encode_png(img, name)


def _image_tile(
    path: Path,
    z: int,
    x: int,
    y: int,
    max_read_pixels: int,
    motion: PostMotion | None,
) -> bytes:
    """A colour tile: the tile's area read from the file, or where `motion` brings the
    data from (the file turned and shifted as the co-registration moved it), its alpha
    band as the mask."""
    with _READERS.reader(path) as reader:
        if not reader.tile_exists(x, y, z):
            raise TileOutsideBounds(f"Tile(x={x}, y={y}, z={z}) is outside bounds")
        pixels = tile_read_pixels(reader.dataset, z, x, y)
        if pixels > max_read_pixels:
            raise TileTooCostly(pixels, max_read_pixels)
        if not motion:
            img = reader.tile(x, y, z, tilesize=TILE_SIZE, resampling_method="bilinear",
                              reproject_method="bilinear")  # fmt: skip
        else:
            bounds = tuple(TMS.xy_bounds(morecantile.Tile(x, y, z)))
            img = moved_image(reader.dataset, bounds, WEB_MERCATOR, TILE_SIZE, motion)  # type: ignore[arg-type]
    return encode_rgba_png(img)


# zlib level of the tiles' PNGs: level 1 takes a fraction of the time of GDAL's default 6
# for files a few per cent larger (measured on Δh, DSM and hillshade tiles: README).
PNG_COMPRESS_LEVEL = 1


@lru_cache(maxsize=64)
def _lut(name: str) -> np.ndarray:
    """The colormap as a 256 x 4 (RGBA) table, as rio-tiler's apply_cmap uses it."""
    table = np.zeros((256, 4), dtype=np.uint8)
    for value, colour in cmap.get(name).items():
        if 0 <= int(value) < 256:
            table[int(value)] = colour if len(colour) == 4 else (*colour, 255)
    table.setflags(write=False)
    return table


def encode_png(img: ImageData, colormap: str | None) -> bytes:
    """The PNG of a one-band 8-bit tile, as rio-tiler's `render` would draw it (the same
    colours and transparency) but encoded by Pillow at a low zlib level, and, with a
    colormap, as a palette image: one byte a pixel to compress instead of four.

    Transparent (nodata) pixels take a palette index that no valid pixel of the tile
    uses, so the colours stay exactly those of the colormap; the rare tile that uses all
    256 is written as RGBA."""
    array = img.array
    if array.dtype != np.uint8 or array.shape[0] != 1:
        return img.render(img_format="PNG", colormap=cmap.get(colormap) if colormap else None)
    values = np.ascontiguousarray(array.data[0])
    valid = np.logical_and.reduce(~np.ma.getmaskarray(array), axis=0)
    height, width = values.shape
    out = io.BytesIO()
    if colormap is None:
        alpha = np.where(valid, 255, 0).astype(np.uint8)
        Image.fromarray(np.dstack([values, alpha]), "LA").save(
            out, "PNG", compress_level=PNG_COMPRESS_LEVEL
        )
        return out.getvalue()
    lut = _lut(colormap)
    alpha = lut[:, 3].copy()
    if not valid.all():
        unused = np.flatnonzero(np.bincount(values[valid], minlength=256) == 0)
        if unused.size == 0:
            rgba = lut[values]
            rgba[~valid, 3] = 0
            Image.fromarray(rgba, "RGBA").save(out, "PNG", compress_level=PNG_COMPRESS_LEVEL)
            return out.getvalue()
        values = np.where(valid, values, np.uint8(unused[0]))
        alpha[unused[0]] = 0
    image = Image.frombuffer("P", (width, height), values.tobytes(), "raw", "P", 0, 1)
    image.putpalette(lut[:, :3].tobytes(), rawmode="RGB")
    options: dict[str, object] = {"compress_level": PNG_COMPRESS_LEVEL}
    if (alpha < 255).any():
        options["transparency"] = alpha.tobytes()
    image.save(out, "PNG", **options)
    return out.getvalue()


# A photo's pixels seldom repeat far apart: zlib's search for earlier repeats costs time
# and finds little, so colour tiles look only for runs (transparency, a tile finer than the
# photo): faster than GDAL's PNG, smaller than Pillow's at level 1 (README).
_COLOUR_PNG = [
    cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESS_LEVEL,
    cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE,
]  # fmt: skip


def encode_rgba_png(img: ImageData) -> bytes:
    """The PNG of a colour tile (RGB, its mask as the alpha), pixel for pixel as
    rio-tiler's `render` draws it, but encoded by OpenCV (GDAL's zlib level 6 took most
    of an orthophoto tile's time)."""
    array = img.array
    if array.dtype != np.uint8 or array.shape[0] != 3:
        return img.render(img_format="PNG")
    bgra = np.empty((*array.shape[1:], 4), dtype=np.uint8)
    for band in range(3):
        bgra[..., 2 - band] = array.data[band]
    bgra[..., 3] = img.mask
    ok, png = cv2.imencode(".png", bgra, _COLOUR_PNG)
    if not ok:
        return img.render(img_format="PNG")
    return png.tobytes()


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
