"""One method's detections scored on one generated pair, on the pair's grid.

Patch F1 (the paper's cells): the grid cut into 32 x 32-pixel cells from the top-left
corner, incomplete edge cells dropped, and cells without a pixel valid in both DSMs
dropped. A cell is truly positive when more than 10 % of its 1024 pixels are slide
pixels (`slide_labels > 0`), predicted positive when more than 10 % are detection
pixels. Precision, recall and F1 are None where undefined (no predicted, no true, no
positive cells at all); the counts always apply.

Slides: a slide is found when detection pixels cover at least 25 % of its footprint.
Depth class: max_depth_m / LoD with LoD = 1.96 x the pair's error NMAD ("<1", "1-3",
">=3"); size class by footprint pixels ("<10x10" below 100, "10x10-30x30" below 900,
">=30x30"). For a found slide, area error = (pixels of the detection components touching
the slide - slide pixels) / slide pixels, and volume error = (loss + gain reported by the
detections on those components - the slide's loss + gain) / the slide's loss + gain.

False alarms: detection pixels outside every slide footprint grown by 2 pixels (edges
are forgiven), in m2 and in m2 per km2 of the pair's valid area (valid in both DSMs). On
a no-change twin every detection pixel is a false alarm. Surface-change false alarms are
those lying on `surface_change` pixels (trees, buildings).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import ndimage

from worker.detection_bench.detections import GridDetections, detection_mask
from worker.pairgen.pair import DsmPair, SlideTruth
from worker.pipeline.cnn.patches import CORE_PX, LABEL_FRACTION

CELL_PX = CORE_PX  # the paper's 32-pixel cell
FOUND_COVERAGE = 0.25
LOD_Z = 1.96
EDGE_TOLERANCE_PX = 2
DEPTH_CLASSES = ("<1", "1-3", ">=3")  # in multiples of the LoD
SIZE_CLASSES = ("<10x10", "10x10-30x30", ">=30x30")
DEEP_LOD, LARGE_PX = 3.0, 100  # "deep and large": >= 3 LoD and >= 10 x 10 pixels


def valid_pixels(pair: DsmPair) -> np.ndarray:
    return np.isfinite(pair.pre) & np.isfinite(pair.post)


def lod_m(pair: DsmPair) -> float:
    return LOD_Z * pair.error_nmad_m


def ratio(numerator: float, denominator: float) -> float | None:
    return numerator / denominator if denominator else None


def cell_counts(pixels: np.ndarray) -> np.ndarray:
    """Pixels set per complete 32 x 32 cell (rows x cols of cells)."""
    nr, nc = pixels.shape[0] // CELL_PX, pixels.shape[1] // CELL_PX
    blocks = pixels[: nr * CELL_PX, : nc * CELL_PX].reshape(nr, CELL_PX, nc, CELL_PX)
    return blocks.sum(axis=(1, 3), dtype=np.int64)


def patch_scores(slide_labels: np.ndarray, detected: np.ndarray, valid: np.ndarray) -> dict:
    """tp/fp/fn/precision/recall/f1 over the paper's cells (see the module doc)."""
    least = LABEL_FRACTION * CELL_PX * CELL_PX
    keep = cell_counts(valid) > 0
    truth = (cell_counts(slide_labels > 0) > least)[keep]
    predicted = (cell_counts(detected) > least)[keep]
    tp = int(np.count_nonzero(truth & predicted))
    fp = int(np.count_nonzero(~truth & predicted))
    fn = int(np.count_nonzero(truth & ~predicted))
    precision, recall = ratio(tp, tp + fp), ratio(tp, tp + fn)
    return {
        "cells": int(keep.sum()),
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "precision": precision,
        "recall": recall,
        "f1": ratio(2 * tp, 2 * tp + fp + fn),
    }


def depth_class(depth_in_lod: float) -> str:
    if depth_in_lod < 1:
        return DEPTH_CLASSES[0]
    return DEPTH_CLASSES[1] if depth_in_lod < 3 else DEPTH_CLASSES[2]


def size_class(area_px: int) -> str:
    if area_px < 100:
        return SIZE_CLASSES[0]
    return SIZE_CLASSES[1] if area_px < 900 else SIZE_CLASSES[2]


def slide_result(
    slide: SlideTruth,
    footprint: np.ndarray,
    detections: GridDetections,
    component_px: np.ndarray,
    lod: float,
) -> dict[str, Any]:
    """Found or missed, classes, and the area/volume errors of one slide."""
    area_px = int(np.count_nonzero(footprint))
    # A clean pair (no observation error) has LoD 0: every slide is deep then.
    in_lod = slide.max_depth_m / lod if lod > 0 else math.inf
    covered = int(np.count_nonzero(detections.mask & footprint))
    coverage = covered / area_px if area_px else 0.0
    found = area_px > 0 and coverage >= FOUND_COVERAGE
    result: dict[str, Any] = {
        "id": slide.id,
        "kind": slide.kind,
        "area_px": area_px,
        "max_depth_m": slide.max_depth_m,
        "depth_lod": in_lod if math.isfinite(in_lod) else None,
        "depth_class": depth_class(in_lod),
        "size_class": size_class(area_px),
        "deep_large": in_lod >= DEEP_LOD and area_px >= LARGE_PX,
        "coverage": coverage,
        "found": found,
        "area_error": None,
        "volume_error": None,
    }
    if found:
        touching = np.unique(detections.components[footprint])
        touching = touching[touching > 0]
        detected_px = int(component_px[touching].sum())
        result["area_error"] = (detected_px - area_px) / area_px
        true_volume = slide.volume_loss_m3 + slide.volume_gain_m3
        if true_volume > 0:
            volume = detections.volume_on(int(t) for t in touching)
            result["volume_error"] = (volume - true_volume) / true_volume
    return result


def slide_results(pair: DsmPair, detections: GridDetections) -> list[dict[str, Any]]:
    lod = lod_m(pair)
    component_px = np.bincount(detections.components.ravel())
    return [
        slide_result(s, pair.slide_labels == s.id, detections, component_px, lod)
        for s in pair.slides
    ]


def false_alarms(
    detected: np.ndarray,
    slide_labels: np.ndarray,
    surface_change: np.ndarray,
    valid: np.ndarray,
    pixel_size: float,
) -> dict[str, Any]:
    """Detection area outside the slides (see the module doc), overall and on surface
    changes."""
    footprints = slide_labels > 0
    if footprints.any():
        footprints = ndimage.binary_dilation(
            footprints, structure=np.ones((3, 3), dtype=bool), iterations=EDGE_TOLERANCE_PX
        )
    outside = detected & ~footprints
    surface = surface_change.astype(bool) & ~footprints
    pixel_area = pixel_size * pixel_size
    valid_km2 = float(np.count_nonzero(valid)) * pixel_area / 1e6
    area = float(np.count_nonzero(outside)) * pixel_area
    surface_area = float(np.count_nonzero(surface)) * pixel_area
    surface_false = float(np.count_nonzero(outside & surface)) * pixel_area
    return {
        "false_alarm_m2": area,
        "valid_km2": valid_km2,
        "false_alarm_m2_per_km2": ratio(area, valid_km2),
        "surface_change_m2": surface_area,
        "surface_false_alarm_m2": surface_false,
        "surface_false_alarm_share": ratio(surface_false, surface_area),
    }


def score_pair(pair: DsmPair, detections: GridDetections) -> dict[str, Any]:
    """Everything measured of one method's detections on one pair (JSON-able)."""
    valid = valid_pixels(pair)
    return {
        "detections": detections.features,
        "detected_m2": float(np.count_nonzero(detections.mask)) * pair.pixel_size**2,
        "patch": patch_scores(pair.slide_labels, detections.mask, valid),
        "slides": slide_results(pair, detections),
        "false_alarm": false_alarms(
            detections.mask, pair.slide_labels, pair.surface_change, valid, pair.pixel_size
        ),
    }


__all__ = [
    "DEPTH_CLASSES",
    "SIZE_CLASSES",
    "depth_class",
    "detection_mask",
    "false_alarms",
    "lod_m",
    "patch_scores",
    "ratio",
    "score_pair",
    "size_class",
    "slide_results",
]
