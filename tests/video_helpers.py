"""Videos as an upload delivers them: index first (faststart), and bytes that arrive over time."""

import threading
import time
from pathlib import Path

import av


def faststart_copy(source: Path, target: Path) -> Path:
    """The same packets in an MP4 whose index (`moov`) comes before the media data, as the
    map uploads a camera's video."""
    options = {"movflags": "faststart"}
    with av.open(str(source)) as src, av.open(str(target), "w", "mp4", options=options) as out:
        stream_in = src.streams.video[0]
        stream_out = out.add_stream_from_template(stream_in)
        for packet in src.demux(stream_in):
            if packet.dts is None:
                continue
            packet.stream = stream_out
            out.mux(packet)
    return target


def top_level_boxes(path: Path) -> list[str]:
    """The types of an MP4's top-level boxes, in file order."""
    types, at, data = [], 0, path.read_bytes()
    while at + 8 <= len(data):
        size = int.from_bytes(data[at : at + 4], "big")
        if size == 1:
            size = int.from_bytes(data[at + 8 : at + 16], "big")
        elif size == 0:
            size = len(data) - at
        types.append(data[at + 4 : at + 8].decode("latin-1"))
        at += max(size, 8)
    return types


def moov_before_mdat(path: Path) -> bool:
    types = top_level_boxes(path)
    return "moov" in types and "mdat" in types and types.index("moov") < types.index("mdat")


class SlowWriter(threading.Thread):
    """Appends `data` to `path` in `pieces` equal parts, `pause_s` apart; stops after
    `stop_after` pieces when given (an upload that stalls)."""

    def __init__(
        self, data: bytes, path: Path, pieces: int, pause_s: float, stop_after: int | None = None
    ) -> None:
        super().__init__(daemon=True)
        self.data, self.path, self.pieces, self.pause_s = data, path, pieces, pause_s
        self.stop_after = stop_after
        self.last_piece_at: float | None = None  # just before the last piece was written

    def run(self) -> None:
        step = -(-len(self.data) // self.pieces)
        with open(self.path, "ab") as fh:
            for k, offset in enumerate(range(0, len(self.data), step)):
                if self.stop_after is not None and k >= self.stop_after:
                    return
                time.sleep(self.pause_s)
                if offset + step >= len(self.data):
                    self.last_piece_at = time.monotonic()
                fh.write(self.data[offset : offset + step])
                fh.flush()
