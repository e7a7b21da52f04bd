"""GeoTIFFs that declare far more pixels than their file weighs: decompression bombs.

Written byte by byte (no GDAL), so that a test can make one of 200 megapixels in
milliseconds: every block is the same DEFLATE stream of zeros, written once per block as
a real bomb is, and the file is a valid GeoTIFF in UTM zone 32N that GDAL opens.
"""

import struct
import time
import zlib
from dataclasses import dataclass
from pathlib import Path

import httpx

FLOAT32 = 3
DEFLATE = 8


def write_bomb(
    path: Path,
    width: int,
    height: int,
    *,
    block: tuple[int, int] | None = (512, 512),
    pixel_size_m: float = 0.05,
    header_only: bool = False,
) -> Path:
    """A float32 DEFLATE GeoTIFF of zeros; `block` (width, height) tiles it, None makes
    the whole image one strip. `header_only`: each block is one byte, for sizes whose
    zeros would not fit on a disk (the header declares them all the same)."""
    block_width, block_height = block or (width, height)
    zeros = b"\0" if header_only else zlib.compress(bytes(block_width * block_height * 4), 9)
    tiled = block is not None
    across = -(-width // block_width) if tiled else 1
    down = -(-height // block_height)
    blocks = across * down
    geokeys = [1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, 32632]
    header_size = 8
    # Tags (sorted), each (tag, type, values); arrays are placed after the directory.
    layout: list[tuple[int, int, list[int] | list[float]]] = [
        (256, 4, [width]),
        (257, 4, [height]),
        (258, 3, [32]),
        (259, 3, [DEFLATE]),
        (262, 3, [1]),
        (277, 3, [1]),
        (284, 3, [1]),
        (339, 3, [FLOAT32]),
    ]
    if tiled:
        layout += [(322, 3, [block_width]), (323, 3, [block_height])]
        offsets_tag, counts_tag = 324, 325
    else:
        layout += [(278, 4, [block_height])]
        offsets_tag, counts_tag = 273, 279
    layout += [
        (offsets_tag, 4, [0] * blocks),  # filled in below
        (counts_tag, 4, [len(zeros)] * blocks),
        (33550, 12, [pixel_size_m, pixel_size_m, 0.0]),
        (33922, 12, [0.0, 0.0, 0.0, 500000.0, 5100000.0, 0.0]),
        (34735, 3, geokeys),
    ]
    layout.sort(key=lambda entry: entry[0])
    directory_size = 2 + 12 * len(layout) + 4
    sizes = {3: 2, 4: 4, 12: 8}
    extra_start = header_size + directory_size
    extra_size = sum(
        sizes[kind] * len(values) for _, kind, values in layout if sizes[kind] * len(values) > 4
    )
    data_start = extra_start + extra_size
    offsets = [data_start + i * len(zeros) for i in range(blocks)]
    codes = {3: "H", 4: "I", 12: "d"}
    entries, extra = b"", b""
    for tag, kind, values in layout:
        if tag == offsets_tag:
            values = offsets
        packed = struct.pack(f"<{len(values)}{codes[kind]}", *values)
        if len(packed) <= 4:
            field = packed.ljust(4, b"\0")
        else:
            field = struct.pack("<I", extra_start + len(extra))
            extra += packed
        entries += struct.pack("<HHI", tag, kind, len(values)) + field
    with open(path, "wb") as out:
        out.write(b"II*\0" + struct.pack("<I", header_size))
        out.write(struct.pack("<H", len(layout)) + entries + struct.pack("<I", 0))
        out.write(extra)
        for _ in range(blocks):
            out.write(zeros)
    return path


def memory_kib(pid: int) -> dict[str, int]:
    """A process's resident set now (VmRSS) and its peak (VmHWM), KiB, from /proc."""
    fields = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        name, _, value = line.partition(":")
        if name in ("VmRSS", "VmHWM"):
            fields[name] = int(value.split()[0])
    return fields


@dataclass
class BombAnswer:
    response: httpx.Response
    seconds: float
    before_kib: dict[str, int]
    after_kib: dict[str, int]

    @property
    def peak_growth_mib(self) -> float:
        """How far the process's peak rose above its resident set before the upload."""
        return (self.after_kib["VmHWM"] - self.before_kib["VmRSS"]) / 1024


def upload_bomb(
    client: httpx.Client, surveys_url: str, data: bytes, pid: int, reset_peak: bool = False
) -> BombAnswer:
    """Upload `data` as a DSM survey to a running API process `pid`, timing the answer and
    reading the process's memory around it; `reset_peak` first resets its peak (VmHWM,
    `/proc/PID/clear_refs`) so that the peak read after is the upload's own."""
    if reset_peak:
        Path(f"/proc/{pid}/clear_refs").write_text("5")
    before = memory_kib(pid)
    started = time.perf_counter()
    response = client.post(
        surveys_url,
        params={"captured_at": "2026-06-01T10:00:00Z", "filename": "bomb.tif"},
        content=data,
        headers={"Content-Type": "image/tiff"},
    )
    return BombAnswer(response, time.perf_counter() - started, before, memory_kib(pid))
