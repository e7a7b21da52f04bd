"""Raster files of the pipeline: elevation and mask GeoTIFFs read, written and warped.

Elevation rasters are float32 with nodata written as -9999 in files and NaN in memory;
masks are uint8 with nodata 255. Every write is atomic.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import rasterio
import rasterio.warp
from pyproj import CRS
from rasterio.crs import CRS as RioCRS
from rasterio.enums import MaskFlags, Resampling
from rasterio.transform import Affine

from worker.pipeline.atomic import atomic_path

NODATA = -9999.0
MASK_NODATA = 255
# A resampled pixel counts as valid only when (nearly) all of its bilinear weight comes
# from valid source pixels, so nodata never bleeds into elevations.
_MIN_VALID_WEIGHT = 0.999


def read_elevation(path: Path, window: Any = None) -> tuple[np.ndarray, dict[str, Any]]:
    """Band 1 as float32 with NaN for nodata (and for NaN/inf values), plus the profile."""
    # Compressed blocks are decoded on every core (GDAL_NUM_THREADS: a config option,
    # which drivers without threads ignore, where an open option would be logged).
    with rasterio.Env(GDAL_NUM_THREADS="ALL_CPUS"), rasterio.open(path) as src:
        if src.mask_flag_enums[0] == (MaskFlags.nodata,):
            # The usual case, the nodata value is the mask: compared in place, with no
            # masked array (half the time on large rasters).
            array = src.read(1, window=window, out_dtype=np.float32)
            array[array == np.float32(src.nodata)] = np.nan
        else:
            array = np.ma.filled(src.read(1, window=window, masked=True).astype(np.float32), np.nan)
        profile = dict(src.profile)
        if window is not None:
            profile["transform"] = src.window_transform(window)
            profile["height"], profile["width"] = array.shape
    array[~np.isfinite(array)] = np.nan
    return array, profile


def write_geotiff(
    path: Path,
    array: np.ndarray,
    transform: Affine,
    crs: RioCRS | CRS | str,
    nodata: float | None = None,
    tags: dict[str, str] | None = None,
) -> None:
    """Write one band atomically as a tiled, deflate-compressed GeoTIFF.

    Float arrays are written as float32 with NaN replaced by -9999 (the declared nodata);
    uint8 arrays are written as they are with nodata 255 unless told otherwise.
    """
    if array.dtype == np.uint8:
        data = array
        nodata = MASK_NODATA if nodata is None else nodata
        predictor = 2
    else:
        data = np.where(np.isfinite(array), array, NODATA).astype(np.float32)
        nodata = NODATA if nodata is None else nodata
        predictor = 3
    height, width = data.shape
    profile = {
        "driver": "GTiff",
        "height": height,
        "width": width,
        "count": 1,
        "dtype": data.dtype.name,
        "crs": RioCRS.from_user_input(crs),
        "transform": transform,
        "nodata": nodata,
        "compress": "deflate",
        "predictor": predictor,
        "tiled": True,
        "blockxsize": 256,
        "blockysize": 256,
        # Blocks are compressed on every core; the file is the same byte for byte.
        "num_threads": "all_cpus",
    }
    with atomic_path(Path(path)) as tmp, rasterio.open(tmp, "w", **profile) as dst:
        dst.write(data, 1)
        if tags:
            dst.update_tags(**tags)


def warp_elevation(
    array: np.ndarray,
    src_transform: Affine,
    src_crs: RioCRS | CRS,
    dst_transform: Affine,
    dst_crs: RioCRS | CRS,
    dst_shape: tuple[int, int],
    num_threads: int = 2,
) -> np.ndarray:
    """Bilinear resampling of an elevation array (NaN = nodata) onto a destination grid.

    A destination pixel is valid only if all source pixels that contribute to it are
    valid, so nodata never blends into elevations (holes grow by at most one pixel).
    """
    valid = np.isfinite(array)
    src = np.where(valid, array, NODATA).astype(np.float32)
    out = np.full(dst_shape, NODATA, dtype=np.float32)
    weight = np.zeros(dst_shape, dtype=np.float32)
    common = {
        "src_transform": src_transform,
        "src_crs": src_crs,
        "dst_transform": dst_transform,
        "dst_crs": dst_crs,
        "resampling": Resampling.bilinear,
        "num_threads": num_threads,
        "tolerance": 0.0,
    }
    rasterio.warp.reproject(src, out, src_nodata=NODATA, dst_nodata=NODATA, **common)
    rasterio.warp.reproject(valid.astype(np.float32), weight, dst_nodata=0.0, **common)
    out[(weight < _MIN_VALID_WEIGHT) | (out == NODATA)] = np.nan
    return out
