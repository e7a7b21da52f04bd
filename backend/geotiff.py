"""Opening our raster files safely: GeoTIFFs only, checked before GDAL parses anything.

A VRT (or another format that refers to further files) could make GDAL read any file on
the machine. Rather than GDAL_SKIP=VRT, which also breaks the in-memory VRTs that rasterio
and rio-tiler build themselves (e.g. calculate_default_transform for tiles finer than a
DSM's overviews), every file the API hands to GDAL is first checked to be a TIFF and then
opened with the GTiff driver alone.
"""

from pathlib import Path

import rasterio

# TIFF and BigTIFF, little- and big-endian.
TIFF_MAGIC = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")


class NotGeoTiff(ValueError):
    """A file that is not a GeoTIFF: never handed to GDAL."""


def is_geotiff(path: Path | str) -> bool:
    with open(path, "rb") as head:
        return head.read(4) in TIFF_MAGIC


def open_geotiff(path: Path | str, overview_level: int | None = None) -> rasterio.DatasetReader:
    """Open `path` with GDAL's GTiff driver only; NotGeoTiff if it is no TIFF at all.
    `overview_level` opens that overview (0: the first) as if it were the image."""
    if not is_geotiff(path):
        raise NotGeoTiff(f"{Path(path).name} is not a GeoTIFF")
    if overview_level is not None:
        return rasterio.open(path, driver="GTiff", overview_level=overview_level)
    return rasterio.open(path, driver="GTiff")
