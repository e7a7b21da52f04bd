"""`manifest.json`: what a simulation wrote, so that tests and benchmarks find every file
without guessing. Paths are relative to the manifest's directory.

Layout (``format: slidewatch-sim/1``)::

    {
      "format", "scenario", "seed", "created_by", "options",
      "crs", "frame" {origin, heights}, "grid" {width, height, res_m, west, north, ...},
      "scene" {mounds | valley ..., checkpoints [{name, e, n, u, lat, lon}]},
      "camera" {video intrinsics}, "image_camera" {stills intrinsics},
      "gnss" {error model}, "imu" {error model},
      "mask_classes" {"0": "stable", "1": "depletion ...", "2": "deposition ..."},
      "steps": [
        {"index": 1, "name": "step1", "date_local",
         "truth": {"dsm", "dem", "ortho", "mask", "mask_since_step1", "events"},
         "events": [{"name", "label", "index_in_events_raster", "depleted_m3", ...}],
         "nuisance": {...}, "fallen_trees", "vanished_trees",
         "surveys": [{"id", "kind", "video", "srt", "flight_log_csv", "trajectory",
                      "images_dir", "images_csv", "preview", "frames", "fps",
                      "start_local", "start_utc", "log_time_offset_s", "gnss" {...},
                      "flight" {...}, "render" {...}, "sun", "exposure"}]}
      ],
      "registration": [{"pattern", "shift_enu_m", "step", "reference_dsm",
                        "unshifted_dsm", "shifted_dsm", "mask"}],
      "volume_conservation": {"max_relative_error", "per_event": [...]},
      "timings_s": {...}
    }
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from worker.pipeline.atomic import write_text_atomic

FORMAT = "slidewatch-sim/1"
MANIFEST_NAME = "manifest.json"


@dataclass
class Manifest:
    """A loaded or freshly written manifest; `data` is the JSON document."""

    root: Path
    data: dict[str, Any] = field(default_factory=dict)

    @property
    def path(self) -> Path:
        return self.root / MANIFEST_NAME

    def resolve(self, rel: str | None) -> Path | None:
        """Absolute path of a file named in the manifest."""
        return None if rel is None else self.root / rel

    @property
    def steps(self) -> list[dict]:
        return self.data["steps"]

    def step(self, index: int) -> dict:
        for s in self.steps:
            if s["index"] == index:
                return s
        raise KeyError(f"no step {index} in {self.path}")

    def truth(self, index: int, key: str = "dsm") -> Path:
        rel = self.step(index)["truth"].get(key)
        if rel is None:
            raise KeyError(f"step {index} has no truth {key!r}")
        return self.root / rel

    def survey(self, index: int, number: int = 0) -> dict:
        return self.step(index)["surveys"][number]

    def files(self) -> list[Path]:
        """Every file the manifest names (each once, in order of appearance)."""
        out: list[Path] = []

        def walk(obj: Any) -> None:
            if isinstance(obj, dict):
                for k, v in obj.items():
                    if isinstance(v, str) and k in _PATH_KEYS:
                        out.append(self.root / v)
                    else:
                        walk(v)
            elif isinstance(obj, list):
                for v in obj:
                    walk(v)

        walk(self.data)
        return [p for p in dict.fromkeys(out) if p.exists()]

    def save(self) -> Path:
        """Write the manifest; `data` then holds exactly what a `load` would return."""
        self.root.mkdir(parents=True, exist_ok=True)
        text = json.dumps(self.data, indent=2, sort_keys=False) + "\n"
        write_text_atomic(self.path, text)
        normalised = json.loads(text)
        self.data.clear()
        self.data.update(normalised)
        return self.path

    @classmethod
    def load(cls, path: Path) -> Manifest:
        path = Path(path)
        if path.is_dir():
            path = path / MANIFEST_NAME
        data = json.loads(path.read_text(encoding="utf-8"))
        if data.get("format") != FORMAT:
            raise ValueError(f"{path}: not a {FORMAT} manifest")
        return cls(root=path.parent, data=data)


_PATH_KEYS = {
    "dsm",
    "dem",
    "ortho",
    "mask",
    "mask_since_step1",
    "events",
    "video",
    "srt",
    "flight_log_csv",
    "trajectory",
    "images_dir",
    "images_csv",
    "preview",
    "reference_dsm",
    "unshifted_dsm",
    "shifted_dsm",
}
