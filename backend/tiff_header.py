"""What a TIFF file declares about its images, read from its header alone.

The sizes a TIFF declares cost nothing to write and everything to read: a 1.5 MB DEFLATE
file can declare 20000 × 20000 pixels in one strip, which GDAL decompresses whole. This
module reads the image file directories (IFDs) with plain file reads, never GDAL, and
never touches pixel data, so that raster_limits can refuse such a file before any pixel
is decompressed. Classic TIFF and BigTIFF, either byte order.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

# A file that chains more image directories than this is refused: no GeoTIFF needs so
# many (a COG has one per overview and mask), and a loop of offsets must end.
MAX_DIRECTORIES = 256
# Entries of one directory: real ones have a few dozen tags.
MAX_ENTRIES = 4096

_WIDTH, _LENGTH, _BITS, _COMPRESSION = 256, 257, 258, 259
_SAMPLES, _ROWS_PER_STRIP, _PLANAR = 277, 278, 284
_STRIP_BYTES, _TILE_WIDTH, _TILE_LENGTH, _TILE_BYTES = 279, 322, 323, 325
_WANTED = {
    _WIDTH, _LENGTH, _BITS, _COMPRESSION, _SAMPLES, _ROWS_PER_STRIP, _PLANAR,
    _STRIP_BYTES, _TILE_WIDTH, _TILE_LENGTH, _TILE_BYTES,
}  # fmt: skip
# TIFF field types: struct code and size of one value (integers only are of use here).
_TYPES = {1: "B", 3: "H", 4: "I", 16: "Q", 6: "b", 8: "h", 9: "i", 17: "q"}


class BadTiffHeader(ValueError):
    """The header cannot be read as a TIFF's; the message says where it breaks."""


@dataclass(frozen=True)
class TiffImage:
    """One image directory: its size, its blocks (tiles or strips) and their bytes."""

    width: int
    height: int
    samples: int
    bits_per_sample: int
    block_width: int
    block_height: int
    planar_separate: bool
    compressed_bytes: int  # the sum of the declared byte counts of its blocks

    @property
    def pixels(self) -> int:
        return self.width * self.height

    @property
    def bytes_per_pixel(self) -> float:
        return self.samples * self.bits_per_sample / 8

    @property
    def decompressed_bytes(self) -> int:
        return int(self.pixels * self.bytes_per_pixel)

    @property
    def block_bytes(self) -> int:
        """Bytes one block takes once decompressed (GDAL decompresses blocks whole)."""
        per_pixel = self.bits_per_sample / 8 if self.planar_separate else self.bytes_per_pixel
        return int(self.block_width * self.block_height * per_pixel)


@dataclass(frozen=True)
class _Format:
    order: str  # "<" or ">"
    big: bool  # BigTIFF: 8-byte counts and offsets

    @property
    def offset_code(self) -> str:
        return "Q" if self.big else "I"


def read_tiff_images(path: Path | str) -> list[TiffImage]:
    """Every image directory of the file, in order; BadTiffHeader if it is not a TIFF."""
    with open(path, "rb") as handle:
        size = handle.seek(0, 2)
        handle.seek(0)
        fmt, offset = _read_header(handle)
        images: list[TiffImage] = []
        seen: set[int] = set()
        while offset:
            if offset in seen or len(seen) >= MAX_DIRECTORIES:
                raise BadTiffHeader(f"more than {MAX_DIRECTORIES} image directories, or a loop")
            if offset >= size:
                raise BadTiffHeader(f"an image directory lies beyond the end of the file ({size})")
            seen.add(offset)
            tags, offset = _read_directory(handle, fmt, offset, size)
            images.append(_image(tags))
        return images


def _read_header(handle: BinaryIO) -> tuple[_Format, int]:
    head = handle.read(16)
    if len(head) < 8 or head[:2] not in (b"II", b"MM"):
        raise BadTiffHeader("not a TIFF file")
    order = "<" if head[:2] == b"II" else ">"
    (magic,) = struct.unpack(order + "H", head[2:4])
    if magic == 42:
        return _Format(order, big=False), struct.unpack(order + "I", head[4:8])[0]
    if magic == 43 and len(head) == 16:
        return _Format(order, big=True), struct.unpack(order + "Q", head[8:16])[0]
    raise BadTiffHeader("not a TIFF file")


def _read_directory(
    handle: BinaryIO, fmt: _Format, offset: int, size: int
) -> tuple[dict[int, list[int]], int]:
    """The directory's tags of use here, and the offset of the next directory (0: none)."""
    count_code, entry_size = ("Q", 20) if fmt.big else ("H", 12)
    handle.seek(offset)
    count = _unpack(handle, fmt.order + count_code)[0]
    if count > MAX_ENTRIES:
        raise BadTiffHeader(f"an image directory with {count} entries")
    entries = handle.read(count * entry_size)
    if len(entries) < count * entry_size:
        raise BadTiffHeader("the file ends inside an image directory")
    following = _unpack(handle, fmt.order + fmt.offset_code)[0]
    tags: dict[int, list[int]] = {}
    value_size = 8 if fmt.big else 4
    for start in range(0, len(entries), entry_size):
        entry = entries[start : start + entry_size]
        tag, kind = struct.unpack(fmt.order + "HH", entry[:4])
        if tag not in _WANTED or kind not in _TYPES:
            continue
        (n,) = struct.unpack(fmt.order + fmt.offset_code, entry[4 : 4 + value_size])
        tags[tag] = _values(handle, fmt, kind, n, entry[4 + value_size :], size)
    return tags, following


def _values(
    handle: BinaryIO, fmt: _Format, kind: int, n: int, field: bytes, size: int
) -> list[int]:
    code = _TYPES[kind]
    length = n * struct.calcsize(code)
    if length > size:
        raise BadTiffHeader(f"a tag declares {n} values, more than the file holds")
    if length <= len(field):
        data = field[:length]
    else:
        (where,) = struct.unpack(fmt.order + fmt.offset_code, field)
        handle.seek(where)
        data = handle.read(length)
        if len(data) < length:
            raise BadTiffHeader("a tag's values lie beyond the end of the file")
    return list(struct.unpack(f"{fmt.order}{n}{code}", data))


def _unpack(handle: BinaryIO, code: str) -> tuple[int, ...]:
    data = handle.read(struct.calcsize(code))
    if len(data) < struct.calcsize(code):
        raise BadTiffHeader("the file ends inside its header")
    return struct.unpack(code, data)


def _first(tags: dict[int, list[int]], tag: int, default: int) -> int:
    values = tags.get(tag)
    return int(values[0]) if values else default


def _image(tags: dict[int, list[int]]) -> TiffImage:
    if _WIDTH not in tags or _LENGTH not in tags:
        raise BadTiffHeader("an image directory without a width or a height")
    width, height = _first(tags, _WIDTH, 0), _first(tags, _LENGTH, 0)
    tiled = _TILE_WIDTH in tags and _TILE_LENGTH in tags
    if tiled:
        block_width, block_height = _first(tags, _TILE_WIDTH, 0), _first(tags, _TILE_LENGTH, 0)
        byte_counts = tags.get(_TILE_BYTES, [])
    else:
        # Without RowsPerStrip the whole image is one strip.
        block_width = width
        block_height = min(_first(tags, _ROWS_PER_STRIP, height), height)
        byte_counts = tags.get(_STRIP_BYTES, [])
    return TiffImage(
        width=width,
        height=height,
        samples=max(1, _first(tags, _SAMPLES, 1)),
        bits_per_sample=max(tags.get(_BITS, [1]) or [1]),
        block_width=block_width,
        block_height=block_height,
        planar_separate=_first(tags, _PLANAR, 1) == 2,
        compressed_bytes=sum(byte_counts),
    )
