"""The decision rule's `min_score`, calibrated on pairs the model never saw as a test.

A cnn comparison keeps a landslide when the mean probability over its pixels (its
`score`) reaches the card's `min_score`. `calibrate_min_score` runs the comparison with
`min_score` 0 on no-change pairs (every group found is a false alarm) and on pairs with
slides (a group that touches a true landslide pixel is a landslide, others are false
alarms). When a threshold separates the two, it is placed above the highest false-alarm
score with a margin (rounded up to 0.05), below every landslide. Otherwise it is the
score that maximises the F1 of the kept area (landslide area kept against false-alarm
area kept and landslide area dropped), and the result says so. Use no-change pairs that
are neither training nor benchmark data.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from pyproj import Transformer
from rasterio.features import rasterize
from shapely.geometry import shape

from worker.pipeline.comparison import ComparisonOptions, compare_dsms
from worker.pipeline.raster_io import write_geotiff
from worker.training.dataset import Pair

MARGIN = 0.05


@dataclass(frozen=True)
class Group:
    """A landslide the comparison found: its score, area and whether it is real."""

    score: float
    area_m2: float
    landslide: bool


@dataclass
class ScoreCalibration:
    min_score: float
    false_alarms: list[Group]
    landslides: list[Group]
    rule: str
    area_f1: float
    data: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        def table(groups: list[Group]) -> list[list[float]]:
            ordered = sorted(groups, key=lambda g: -g.score)
            return [[round(g.score, 3), round(g.area_m2, 1)] for g in ordered]

        return {
            "data": ", ".join(self.data),
            "false_alarms_score_area_m2": table(self.false_alarms),
            "landslides_score_area_m2": table(self.landslides),
            "rule": self.rule,
            "kept_area_f1": round(self.area_f1, 3),
        }


def area_f1(groups: list[Group], min_score: float) -> float:
    """F1 of the kept area: landslide area kept vs. false-alarm area kept and landslide
    area dropped."""
    kept_true = sum(g.area_m2 for g in groups if g.landslide and g.score >= min_score)
    kept_false = sum(g.area_m2 for g in groups if not g.landslide and g.score >= min_score)
    dropped_true = sum(g.area_m2 for g in groups if g.landslide and g.score < min_score)
    denominator = 2 * kept_true + kept_false + dropped_true
    return 2 * kept_true / denominator if denominator else 1.0


def choose_min_score(groups: list[Group]) -> tuple[float, str]:
    """The threshold and the rule that gave it (see the module doc)."""
    highest = max((g.score for g in groups if not g.landslide), default=0.0)
    lowest = min((g.score for g in groups if g.landslide), default=1.0)
    separating = math.ceil((highest + MARGIN) * 20) / 20  # up to the next 0.05
    if separating <= lowest:
        return (
            separating,
            "above the highest false alarm with a margin, below every landslide",
        )
    candidates = sorted({0.0, *(g.score for g in groups)})
    best = max(candidates, key=lambda t: (area_f1(groups, t), -t))
    return best, "no score separates false alarms from landslides: the F1 of the kept area is best"


def found_groups(pair: Pair, card: Path, work_dir: Path, threads: int = 2) -> list[Group]:
    """Every group the cnn comparison finds with min_score 0; a group is a landslide when
    it touches a landslide pixel of the pair's mask."""
    work = Path(work_dir)
    write_geotiff(work / "input" / "pre.tif", pair.pre, pair.transform, pair.crs)
    write_geotiff(work / "input" / "post.tif", pair.post, pair.transform, pair.crs)
    options = ComparisonOptions(method="cnn")
    options.detection.model = str(card)
    options.detection.min_score = 0.0
    options.detection.num_threads = threads
    compare_dsms(work / "input" / "pre.tif", work / "input" / "post.tif", work / "cmp", options)
    features = json.loads((work / "cmp" / "detections.geojson").read_text())["features"]
    to_grid = Transformer.from_crs("EPSG:4326", pair.crs, always_xy=True)
    landslide = pair.mask == 1
    out = []
    for feature in features:  # GeoJSON is WGS84; the mask is on the pair's grid
        geometry = shapely.transform(
            shape(feature["geometry"]), lambda xy: np.column_stack(to_grid.transform(*xy.T))
        )
        footprint = rasterize([geometry], out_shape=landslide.shape, transform=pair.transform)
        touches = bool(np.any(landslide[footprint == 1]))
        props = feature["properties"]
        out.append(Group(float(props["score"]), float(props["area_m2"]), touches))
    return out


def calibrate_min_score(
    card: Path,
    no_change: dict[str, Pair],
    slides: dict[str, Pair],
    work_dir: Path,
    threads: int = 2,
) -> ScoreCalibration:
    """`min_score` from the scores of false alarms and of real slides (see module doc)."""
    groups: list[Group] = []
    for name, pair in no_change.items():
        found = found_groups(pair, card, Path(work_dir) / name, threads)
        groups += [Group(g.score, g.area_m2, False) for g in found]
    for name, pair in slides.items():
        groups += found_groups(pair, card, Path(work_dir) / name, threads)
    value, rule = choose_min_score(groups)
    return ScoreCalibration(
        min_score=round(value, 3),
        false_alarms=[g for g in groups if not g.landslide],
        landslides=[g for g in groups if g.landslide],
        rule=rule,
        area_f1=area_f1(groups, value),
        data=[*(f"{n} (no change)" for n in no_change), *(f"{n} (slides)" for n in slides)],
    )
