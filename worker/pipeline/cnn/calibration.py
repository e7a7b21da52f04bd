"""The decision rule's `min_score`, calibrated on pairs the model never saw as a test.

A cnn comparison keeps a landslide when the mean probability over its pixels (its
`score`) reaches the card's `min_score`. `calibrate_min_score` runs the comparison with
`min_score` 0 on no-change pairs (every group found is a false alarm) and on pairs with
slides (groups that touch a true landslide pixel), and places the threshold above the
highest false-alarm score with a margin, as long as that stays below the lowest score of
a real slide; otherwise it takes the midpoint and says so. Use no-change pairs that are
neither training nor benchmark data.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
from rasterio.enums import Resampling
from rasterio.features import rasterize
from rasterio.warp import reproject
from shapely.geometry import shape

from worker.pipeline.cnn.dataset import Pair
from worker.pipeline.comparison import ComparisonOptions, compare_dsms
from worker.pipeline.raster_io import write_geotiff

MARGIN = 0.05


@dataclass
class ScoreCalibration:
    min_score: float
    false_alarm_scores: list[float]
    landslide_scores: list[float]
    rule: str
    data: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "data": ", ".join(self.data),
            "false_alarm_scores": [round(s, 3) for s in self.false_alarm_scores],
            "landslide_scores_min": (
                round(min(self.landslide_scores), 3) if self.landslide_scores else None
            ),
            "rule": self.rule,
        }


def group_scores(
    pair: Pair, card: Path, work_dir: Path, threads: int = 2
) -> list[tuple[float, bool]]:
    """(score, touches a landslide pixel of the pair's mask) of every group the cnn
    comparison finds with min_score 0."""
    work = Path(work_dir)
    write_geotiff(work / "input" / "pre.tif", pair.pre, pair.transform, pair.crs)
    write_geotiff(work / "input" / "post.tif", pair.post, pair.transform, pair.crs)
    options = ComparisonOptions(method="cnn")
    options.cnn.model = str(card)
    options.cnn.min_score = 0.0
    options.cnn.num_threads = threads
    compare_dsms(work / "input" / "pre.tif", work / "input" / "post.tif", work / "cmp", options)
    features = json.loads((work / "cmp" / "detections.geojson").read_text())["features"]
    with rasterio.open(work / "cmp" / "pre_aligned.tif") as src:
        grid_transform, grid_shape = src.transform, src.shape
    landslide = np.zeros(grid_shape, np.uint8)
    reproject(
        (pair.mask == 1).astype(np.uint8),
        landslide,
        src_transform=pair.transform,
        src_crs=pair.crs,
        dst_transform=grid_transform,
        dst_crs=pair.crs,
        resampling=Resampling.nearest,
    )
    out = []
    for feature in features:
        footprint = rasterize(
            [shape(feature["geometry"])], out_shape=grid_shape, transform=grid_transform
        )
        touches = bool(np.any(landslide[footprint == 1]))
        out.append((float(feature["properties"]["score"]), touches))
    return out


def calibrate_min_score(
    card: Path,
    no_change: dict[str, Pair],
    slides: dict[str, Pair],
    work_dir: Path,
    threads: int = 2,
) -> ScoreCalibration:
    """`min_score` from the scores of false alarms and of real slides (see module doc)."""
    false_alarms: list[float] = []
    landslides: list[float] = []
    for name, pair in no_change.items():
        false_alarms += [s for s, _ in group_scores(pair, card, Path(work_dir) / name, threads)]
    for name, pair in slides.items():
        for score, touches in group_scores(pair, card, Path(work_dir) / name, threads):
            (landslides if touches else false_alarms).append(score)
    highest = max(false_alarms, default=0.0)
    lowest = min(landslides, default=1.0)
    candidate = math.ceil((highest + MARGIN) * 20) / 20  # up to the next 0.05
    if candidate < lowest:
        rule = "above the highest false-alarm score with a margin, below real slides"
        value = candidate
    else:
        rule = "midway between the highest false-alarm score and the lowest slide score"
        value = (highest + lowest) / 2
    return ScoreCalibration(
        min_score=round(value, 3),
        false_alarm_scores=sorted(false_alarms, reverse=True)[:5],
        landslide_scores=landslides,
        rule=rule,
        data=[*(f"{n} (no change)" for n in no_change), *(f"{n} (slides)" for n in slides)],
    )
