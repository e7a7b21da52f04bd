"""Limits on the rasters users upload, checked from the TIFF header before any pixel is read.

What a raster costs to read is what its header declares (pixels, bytes per block once
decompressed), not what its file weighs; these limits refuse, from the header alone, a
raster that would cost more than the server is willing to spend, naming the limit and the
setting that raises it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from backend.config import Settings
from backend.tiff_header import BadTiffHeader, TiffImage, read_tiff_images
from worker.pipeline.errors import InputError


class RasterTooLarge(InputError):
    """A raster beyond one of the limits; the message names the limit and its setting."""


@dataclass(frozen=True)
class RasterLimits:
    max_pixels: int
    max_dimension: int
    max_block_bytes: int
    max_compression_ratio: float

    @classmethod
    def from_settings(cls, settings: Settings) -> RasterLimits:
        return cls(
            max_pixels=settings.max_raster_pixels,
            max_dimension=settings.max_raster_dimension,
            max_block_bytes=settings.max_raster_block_bytes,
            max_compression_ratio=settings.max_raster_compression_ratio,
        )


def check_raster_limits(path: Path, limits: RasterLimits, label: str) -> list[TiffImage]:
    """The file's images if it is within `limits`; RasterTooLarge (or InputError for a
    header that cannot be read) otherwise. Reads the header only."""
    try:
        images = read_tiff_images(path)
    except BadTiffHeader as exc:
        raise InputError(
            f"{label} is not a readable GeoTIFF: its header is broken ({exc})"
        ) from None
    if not images:
        raise InputError(f"{label} is not a readable GeoTIFF: it holds no image")
    main = images[0]
    if main.pixels > limits.max_pixels:
        raise RasterTooLarge(
            f"{label} has {main.width} × {main.height} = {main.pixels} pixels, more than the "
            f"limit of {limits.max_pixels} (SLIDEWATCH_MAX_RASTER_PIXELS)"
        )
    for image in images:
        _check_image(image, limits, label)
    size = max(1, Path(path).stat().st_size)
    ratio = sum(image.decompressed_bytes for image in images) / size
    if ratio > limits.max_compression_ratio:
        raise RasterTooLarge(
            f"{label} would decompress to {ratio:.0f} times its {size} bytes, more than the "
            f"limit of {limits.max_compression_ratio:g} (SLIDEWATCH_MAX_RASTER_COMPRESSION_RATIO)"
        )
    return images


def _check_image(image: TiffImage, limits: RasterLimits, label: str) -> None:
    if min(image.width, image.height) < 1:
        raise InputError(f"{label} declares an image of {image.width} × {image.height} pixels")
    if max(image.width, image.height) > limits.max_dimension:
        raise RasterTooLarge(
            f"{label} declares an image of {image.width} × {image.height} pixels, wider or "
            f"taller than the limit of {limits.max_dimension} (SLIDEWATCH_MAX_RASTER_DIMENSION)"
        )
    if image.block_bytes > limits.max_block_bytes:
        raise RasterTooLarge(
            f"{label} stores its pixels in blocks of {image.block_width} × "
            f"{image.block_height} that take {image.block_bytes} bytes each once "
            f"decompressed, more than the limit of {limits.max_block_bytes} "
            "(SLIDEWATCH_MAX_RASTER_BLOCK_BYTES); write it tiled, e.g. "
            "gdal_translate -co TILED=YES"
        )
