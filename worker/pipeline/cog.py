"""Cloud-Optimized GeoTIFFs: every raster product is served to GIS clients as a COG.

A COG keeps its tiles and overviews in an order that HTTP Range reads can use, so QGIS,
GDAL's /vsicurl/ and the tile server read only the parts they show. Elevations are
deflate-compressed with the floating-point predictor and averaged into overviews; masks
and classes use the integer predictor and nearest-neighbour overviews, so no class value
is invented. CRS and nodata are kept. The output is written atomically and depends only on
the input, so converting again gives the same file.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import numpy as np
import rasterio
from rio_cogeo.cogeo import cog_translate, cog_validate
from rio_cogeo.profiles import cog_profiles

from worker.pipeline.atomic import atomic_path
from worker.pipeline.errors import InputError

BLOCK_SIZE = 256
COG_MEDIA_TYPE = "image/tiff; application=geotiff; profile=cloud-optimized"


class RasterRole(StrEnum):
    elevation = "elevation"  # continuous values: DSM, Δh
    mask = "mask"  # classes: significance, stable terrain
    image = "image"  # colour bands with alpha: the orthophoto


@dataclass(frozen=True)
class CogResult:
    path: Path
    width: int
    height: int
    overviews: list[int]
    crs: str | None
    nodata: float | None


def write_cog(src_path: Path, dst_path: Path, role: RasterRole | str) -> CogResult:
    """Convert the GeoTIFF at `src_path` into a COG at `dst_path` (atomically)."""
    role = RasterRole(role)
    with rasterio.open(src_path) as src:
        if src.crs is None:
            raise InputError(f"{Path(src_path).name} has no CRS; a COG product needs one")
        floating = np.issubdtype(np.dtype(src.dtypes[0]), np.floating)
        nodata = src.nodata
    profile = cog_profiles.get("deflate")
    profile.update(
        blockxsize=BLOCK_SIZE,
        blockysize=BLOCK_SIZE,
        predictor=3 if floating else 2,
    )
    # Colours average into overviews like heights do; classes must not be averaged.
    resampling = "nearest" if role == RasterRole.mask else "average"
    with atomic_path(Path(dst_path)) as tmp:
        cog_translate(
            str(src_path),
            str(tmp),
            profile,
            nodata=nodata,
            overview_resampling=resampling,
            in_memory=False,
            quiet=True,
            use_cog_driver=False,
            config={"GDAL_NUM_THREADS": "2", "GDAL_TIFF_OVR_BLOCKSIZE": str(BLOCK_SIZE)},
        )
        valid, errors, _warnings = cog_validate(str(tmp), quiet=True)
        if not valid:
            raise RuntimeError(f"the COG made from {src_path} is not valid: {errors}")
    with rasterio.open(dst_path) as cog:
        return CogResult(
            path=Path(dst_path),
            width=cog.width,
            height=cog.height,
            overviews=cog.overviews(1),
            crs=cog.crs.to_string() if cog.crs else None,
            nodata=cog.nodata,
        )
