"""Scoring one method's detections on one pair: cells, slides, false alarms, rasterising."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pyproj import Transformer
from scipy import ndimage

from worker.detection_bench.detections import GridDetections, read_detections
from worker.detection_bench.metrics import (
    depth_class,
    false_alarms,
    patch_scores,
    score_pair,
    size_class,
    slide_results,
)
from worker.pairgen.pair import PAIR_CRS, DsmPair, SlideTruth


def grid_detections(mask: np.ndarray, volumes: dict[int, float] | None = None) -> GridDetections:
    """Detections made by hand: one feature per component, with the given volumes."""
    components, n = ndimage.label(mask, structure=np.ones((3, 3)))
    volumes = volumes or {}
    return GridDetections(
        mask,
        components.astype(np.int32),
        [frozenset({k}) for k in range(1, n + 1)],
        [volumes.get(k, 0.0) for k in range(1, n + 1)],
    )


def hand_pair(
    labels: np.ndarray,
    slides: list[SlideTruth],
    pixel: float = 0.5,
    surface: np.ndarray | None = None,
) -> DsmPair:
    """A flat pair whose observation error is +-0.1 m half and half: NMAD 0.14826 m,
    so LoD = 1.96 x 0.14826 = 0.2906 m."""
    shape = labels.shape
    error = np.where(np.arange(labels.size).reshape(shape) % 2 == 0, 0.1, -0.1)
    return DsmPair(
        generator="hand",
        seed=0,
        pixel_size=pixel,
        pre=np.zeros(shape, np.float32),
        post=error.astype(np.float32),
        true_dh=np.zeros(shape, np.float32),
        slide_labels=labels.astype(np.int16),
        slides=slides,
        surface_change=np.zeros(shape, bool) if surface is None else surface,
        observation_error=error.astype(np.float32),
        no_change=not slides,
    )


def slide(id_: int, area_px: int, depth: float, volume: float = 100.0) -> SlideTruth:
    return SlideTruth(id_, "shallow", area_px * 0.25, area_px, volume, 0.0, depth, 10.0)


def test_patch_f1_on_hand_built_cells():
    # 4 x 5 complete cells; the 10 extra rows and columns make incomplete cells: dropped.
    shape = (4 * 32 + 10, 5 * 32 + 10)
    labels = np.zeros(shape, np.int16)
    detected = np.zeros(shape, bool)
    valid = np.ones(shape, bool)
    labels[0:32, 0:32] = 1  # cell (0, 0): positive, detected -> tp
    detected[0:10, 0:20] = True  # 200 px > 102.4
    labels[32:64, 32:64].flat[:103] = 1  # cell (1, 1): 103 px > 10 % -> positive, missed -> fn
    labels[64:96, 64:96].flat[:102] = 1  # cell (2, 2): 102 px, not positive
    detected[64:96, 64:96].flat[:102] = True  # nor predicted positive
    detected[96:128, 96:128] = True  # cell (3, 3): fp
    detected[128:, :] = True  # incomplete edge cells: dropped
    detected[0:32, 128:160] = True  # cell (0, 4) has no valid pixel: dropped
    valid[0:32, 128:160] = False
    scores = patch_scores(labels, detected, valid)
    assert scores == {
        "cells": 19,
        "tp": 1,
        "fp": 1,
        "fn": 1,
        "precision": 0.5,
        "recall": 0.5,
        "f1": 0.5,
    }


def test_patch_f1_undefined_without_positives_and_zero_with_only_false_alarms():
    labels = np.zeros((64, 64), np.int16)
    valid = np.ones((64, 64), bool)
    nothing = patch_scores(labels, np.zeros((64, 64), bool), valid)
    assert (nothing["f1"], nothing["precision"], nothing["recall"]) == (None, None, None)
    alarm = np.zeros((64, 64), bool)
    alarm[:32, :32] = True
    scores = patch_scores(labels, alarm, valid)
    assert (scores["fp"], scores["precision"], scores["recall"], scores["f1"]) == (
        1,
        0.0,
        None,
        0.0,
    )


@pytest.mark.parametrize(("covered_px", "found"), [(100, True), (99, False)])
def test_slide_found_when_a_quarter_is_covered(covered_px, found):
    labels = np.zeros((60, 60), np.int16)
    labels[10:30, 10:30] = 1  # 400 px
    detected = np.zeros((60, 60), bool)
    detected[10:30, 10:30].flat[:covered_px] = True
    pair = hand_pair(labels, [slide(1, 400, 2.0)])
    (result,) = slide_results(pair, grid_detections(detected))
    assert result["coverage"] == pytest.approx(covered_px / 400)
    assert result["found"] is found
    assert (result["area_error"] is None) is not found


def test_depth_and_size_classes():
    assert [depth_class(x) for x in (0.0, 0.99, 1.0, 2.99, 3.0, 10.0)] == [
        "<1",
        "<1",
        "1-3",
        "1-3",
        ">=3",
        ">=3",
    ]
    assert [size_class(x) for x in (1, 99, 100, 899, 900)] == [
        "<10x10",
        "<10x10",
        "10x10-30x30",
        "10x10-30x30",
        ">=30x30",
    ]
    labels = np.zeros((80, 80), np.int16)
    labels[0:5, 0:5] = 1  # 25 px
    labels[20:40, 20:40] = 2  # 400 px
    labels[40:80, 40:80] = 3  # 1600 px
    # LoD 0.2906 m: 0.2 m is 0.69 LoD, 0.6 m 2.06 LoD, 1.0 m 3.44 LoD.
    pair = hand_pair(labels, [slide(1, 25, 0.2), slide(2, 400, 0.6), slide(3, 1600, 1.0)])
    results = slide_results(pair, GridDetections.empty(labels.shape))
    assert [r["depth_class"] for r in results] == ["<1", "1-3", ">=3"]
    assert [r["depth_lod"] for r in results] == pytest.approx([0.688, 2.064, 3.441], abs=1e-3)
    assert [r["size_class"] for r in results] == ["<10x10", "10x10-30x30", ">=30x30"]
    assert [r["deep_large"] for r in results] == [False, False, True]
    assert not any(r["found"] for r in results)


def test_false_alarm_area_per_km2_of_a_known_rectangle():
    # 100 x 100 px at 0.5 m: 2500 m2 = 0.0025 km2 valid.
    labels = np.zeros((100, 100), np.int16)
    labels[60:80, 60:80] = 1
    detected = np.zeros((100, 100), bool)
    detected[10:20, 10:30] = True  # 200 px = 50 m2 far from the slide
    detected[58:82, 58:82] = True  # the slide grown by 2 px: forgiven
    surface = np.zeros((100, 100), bool)
    surface[10:20, 20:40] = True  # a building: 200 px, half of it under the false alarm
    result = false_alarms(detected, labels, surface, np.ones((100, 100), bool), 0.5)
    assert result["false_alarm_m2"] == pytest.approx(50.0)
    assert result["valid_km2"] == pytest.approx(0.0025)
    assert result["false_alarm_m2_per_km2"] == pytest.approx(20_000.0)
    assert result["surface_change_m2"] == pytest.approx(50.0)
    assert result["surface_false_alarm_m2"] == pytest.approx(25.0)
    assert result["surface_false_alarm_share"] == pytest.approx(0.5)
    # Grown by 3 px the detection is no longer forgiven: a 1-px ring of 4 x 25 - 4 px.
    detected[57:83, 57:83] = True
    ring = false_alarms(detected, labels, surface, np.ones((100, 100), bool), 0.5)
    assert ring["false_alarm_m2"] == pytest.approx(50.0 + 100 * 0.25)
    # On a no-change twin every detection pixel is a false alarm.
    twin = false_alarms(detected, np.zeros_like(labels), surface, np.ones((100, 100), bool), 0.5)
    assert twin["false_alarm_m2"] == pytest.approx(np.count_nonzero(detected) * 0.25)


def test_area_and_volume_error_of_a_known_detection():
    labels = np.zeros((60, 60), np.int16)
    labels[10:30, 10:30] = 1  # 400 px, loss + gain 100 m3
    detected = np.zeros((60, 60), bool)
    detected[10:30, 8:33] = True  # 500 px on the slide: component 1
    detected[50:55, 50:55] = True  # elsewhere: component 2, must not count
    pair = hand_pair(labels, [slide(1, 400, 2.0, volume=100.0)])
    detections = grid_detections(detected, {1: 80.0, 2: 1000.0})
    (result,) = slide_results(pair, detections)
    assert result["found"]
    assert result["area_error"] == pytest.approx(0.25)
    assert result["volume_error"] == pytest.approx(-0.2)
    scored = score_pair(pair, detections)
    assert scored["detections"] == 2
    # The far square (25 px) and column 32, 3 px off the slide's edge (20 px).
    assert scored["false_alarm"]["false_alarm_m2"] == pytest.approx((25 + 20) * 0.25)


def test_wgs84_geojson_rasterises_onto_the_utm_grid(tmp_path):
    from rasterio.transform import from_origin

    transform = from_origin(500_000.0, 3_900_000.0, 0.2, 0.2)
    to_lonlat = Transformer.from_crs(PAIR_CRS, "EPSG:4326", always_xy=True)

    def ring(r0: int, r1: int, c0: int, c1: int) -> list[list[float]]:
        corners = [(c0, r1), (c1, r1), (c1, r0), (c0, r0), (c0, r1)]  # counter-clockwise
        return [list(to_lonlat.transform(*(transform * (c, r)))) for c, r in corners]

    features = [
        {
            "type": "Feature",
            "geometry": {"type": "Polygon", "coordinates": [ring(10, 20, 30, 50)]},
            "properties": {"volume_loss_m3": 5.0, "volume_gain_m3": 1.0},
        },
        {
            "type": "Feature",
            "geometry": {
                "type": "MultiPolygon",
                "coordinates": [[ring(40, 44, 0, 4)], [ring(40, 44, 60, 64)]],
            },
            "properties": {"volume_loss_m3": 2.0, "volume_gain_m3": 3.0},
        },
    ]
    path = tmp_path / "detections.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    detections = read_detections(path, transform, (64, 64), PAIR_CRS)
    expected = np.zeros((64, 64), bool)
    expected[10:20, 30:50] = True
    expected[40:44, 0:4] = True
    expected[40:44, 60:64] = True
    assert np.array_equal(detections.mask, expected)
    first = int(detections.components[15, 40])
    left, right = int(detections.components[42, 2]), int(detections.components[42, 62])
    assert detections.feature_components == [frozenset({first}), frozenset({left, right})]
    # The MultiPolygon's volume counts once although both its parts touch.
    assert detections.volume_on([left, right]) == pytest.approx(5.0)
    assert detections.volume_on([first, left]) == pytest.approx(11.0)
