"""A generated pre/post DSM pair with its truth: the currency of the detection benchmark.

The pair generators (worker/pairgen/) are independent of the survey simulator
(worker/simulator/): other terrain, slide, surface and error models, so that a detector
tuned on one can be scored on the others.

Conventions:
- Arrays are float32 on one north-up grid, row 0 at the north edge, NaN where a DSM has
  no value; `pixel_size` in metres; the grid's CRS is a metric UTM zone.
- `true_dh` is the landslides' ground-surface change alone (post - pre, metres, 0 where
  none); `slide_labels` holds each slide's id (1..n) on the pixels it changed, 0 elsewhere.
- `surface_change` marks pixels whose surface changed for reasons that are not
  landslides (trees grown or felled, buildings built or removed): a detector should not
  report them unless they lie on a slide.
- `observation_error` = (post - pre) - true_dh - (surface change heights): what the
  surveys and their registration added. Its NMAD over the pair is `error_nmad_m`, the
  yardstick of the depth classes (a slide's depth in multiples of 1.96 * NMAD).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pyproj import CRS
from rasterio.transform import Affine, from_origin

from worker.pipeline.raster_io import write_geotiff

# Grid origin shared by every generated pair: UTM zone 54N (Japan), where the paper flew.
PAIR_CRS = CRS.from_epsg(32654)
PAIR_ORIGIN_EN = (500_000.0, 3_900_000.0)
PRE_FILE, POST_FILE, TRUTH_FILE, TRUTH_JSON = "pre.tif", "post.tif", "truth.tif", "truth.json"


class PairUnavailable(Exception):
    """A generator could not make this pair (e.g. a simulated flight failed to
    reconstruct); the message says why. The benchmark reports it and goes on."""


@dataclass
class SlideTruth:
    """One planted landslide: its footprint and size, in the pre survey's frame."""

    id: int
    kind: str  # rotational, translational, debris-flow, rockfall, shallow, deep-seated
    area_m2: float  # pixels where |true dh| > 0 times the pixel area
    area_px: int
    volume_loss_m3: float
    volume_gain_m3: float
    max_depth_m: float  # largest |true dh|
    length_m: float  # along the slope, scarp to toe


@dataclass
class DsmPair:
    generator: str
    seed: int
    pixel_size: float
    pre: np.ndarray
    post: np.ndarray
    true_dh: np.ndarray
    slide_labels: np.ndarray  # int16
    slides: list[SlideTruth]
    surface_change: np.ndarray  # bool
    observation_error: np.ndarray
    no_change: bool  # True for a twin without slides
    description: dict[str, Any] = field(default_factory=dict)  # the draws, for the report

    @property
    def shape(self) -> tuple[int, int]:
        return self.pre.shape

    @property
    def transform(self) -> Affine:
        east, north = PAIR_ORIGIN_EN
        return from_origin(east, north, self.pixel_size, self.pixel_size)

    @property
    def error_nmad_m(self) -> float:
        err = self.observation_error[np.isfinite(self.observation_error)]
        if err.size == 0:
            return float("nan")
        return float(1.4826 * np.median(np.abs(err - np.median(err))))

    def truth_dict(self) -> dict[str, Any]:
        return {
            "generator": self.generator,
            "seed": self.seed,
            "pixel_size": self.pixel_size,
            "shape": list(self.shape),
            "no_change": self.no_change,
            "error_nmad_m": self.error_nmad_m,
            "surface_change_px": int(np.count_nonzero(self.surface_change)),
            "slides": [asdict(s) for s in self.slides],
            "description": self.description,
        }

    def write(self, folder: Path) -> dict[str, Path]:
        """pre.tif, post.tif (float32 DSMs), truth.tif (uint8 slide ids) and truth.json."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        paths = {
            "pre": folder / PRE_FILE,
            "post": folder / POST_FILE,
            "truth": folder / TRUTH_FILE,
            "truth_json": folder / TRUTH_JSON,
        }
        write_geotiff(paths["pre"], self.pre, self.transform, PAIR_CRS)
        write_geotiff(paths["post"], self.post, self.transform, PAIR_CRS)
        write_geotiff(paths["truth"], self.slide_labels.astype(np.uint8), self.transform, PAIR_CRS)
        paths["truth_json"].write_text(json.dumps(self.truth_dict(), indent=1))
        return paths
