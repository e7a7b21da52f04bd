"""Tables 6 and 7 replicated: patch-wise precision, recall and F1 per detector and pattern.

Protocol (the paper's "Training and Test"): the test pair is Step1 -> Step5; the test
patches are those of the paper's grid (42-pixel patches, stride 10, origins from the
raster's top-left corner) whose 32-pixel centre lies wholly in the test region (mound A
on paper-mounds; everything on the hillslope) and whose window has data in both DSMs.
Truth per patch: the 10 % rule on the simulator's mask. The post DSM of the test pair
gets the registration error of each pattern (Table 4; times the scenario's scale, 10
at full scale), applied with the simulator's registration.shift_dsm.

Detectors, each giving a label per test patch:

- cnn_fixed / cnn_loose: the paper's PatchNet on the raw pair (no co-registration, as in
  the paper), probability >= 0.5.
- threshold_20cm / threshold_30cm: |post - pre| > t on the raw pair (the paper's Fig. 9
  binarisation); a patch is positive when more than 10 % of its centre is above t. At
  full scale the thresholds are scaled like the registration error (2 m / 3 m).
- lod: the platform's threshold comparison, its default method (align -> coregister ->
  difference -> vectorize, the per-pixel LoD95 of the error model learnt from the
  difference): its polygons rasterised on the grid, then the 10 % rule. The minimum
  polygon area scales with the pixel size: 25 m2 at 20 cm (625 pixels).
- lod_uniform: the same with one NMAD for the whole raster (the simple baseline the
  default must not fall below).
- best: the comparison's cnn method (align -> coregister -> difference -> detect with
  SlideNet): its landslide polygons (pixels with probability >= the model's pixel
  threshold, grouped, kept when their score reaches the card's min_score) rasterised on
  the grid, then the 10 % rule.
- scored: the comparison's scored method on the same first stages (its score
  stage: significant-change candidates scored by the calibrated scorer), rasterised
  likewise.

Also measured: a no-change pair (nuisance only: vegetation growth and the scenario's
small surface changes, plus a registration error) on which any detection is a false
alarm.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
import rasterio.features
import shapely
from pyproj import Transformer
from shapely.geometry import shape as to_shape

from worker.pipeline.cnn.inference import predict_patches
from worker.pipeline.cnn.patches import (
    PATCH_PX,
    centre_fractions,
    centres_inside,
    label_from_fraction,
    patch_origins,
    usable_windows,
)
from worker.pipeline.cnn.registry import LoadedModel
from worker.pipeline.comparison import ComparisonOptions, compare_dsms, run_stage
from worker.pipeline.methods.threshold import BASELINE_OPTIONS
from worker.pipeline.raster_io import write_geotiff
from worker.training.dataset import DatasetManifest, load_pair
from worker.training.training import binary_metrics

PAPER_TABLES = {
    "cnn_fixed": {
        "A": (0.731, 0.864, 0.792),
        "B": (0.667, 0.818, 0.735),
        "C": (0.477, 0.955, 0.636),
        "D": (0.739, 0.773, 0.756),
    },
    "cnn_loose": {
        "A": (0.826, 0.864, 0.844),
        "B": (0.792, 0.864, 0.826),
        "C": (0.731, 0.864, 0.792),
        "D": (0.810, 0.773, 0.791),
    },
}
METHOD_ORDER = (
    "cnn_fixed",
    "cnn_loose",
    "threshold_20cm",
    "threshold_30cm",
    "lod",
    "lod_uniform",
    "best",
    "scored",
)
LOD_MIN_AREA_PX = 625  # 25 m2 at 20 cm, the platform's default minimum area


def lod_options(pixel_size_m: float, error_model: str = "heteroscedastic") -> ComparisonOptions:
    """The threshold method as this protocol runs it: its per-pixel error model (the
    default) or one NMAD for the raster and no volume test ("uniform", the baseline, as
    the generator benchmark runs it), the minimum area scaled with the pixel size."""
    chosen = BASELINE_OPTIONS if error_model == "uniform" else {}
    options = ComparisonOptions.from_dict({"method": "threshold", **chosen})
    options.detection.min_area_m2 = LOD_MIN_AREA_PX * pixel_size_m**2
    return options


@dataclass
class TestPatches:
    rows: np.ndarray  # 1-D grid origins
    cols: np.ndarray
    selected: np.ndarray  # (len(rows), len(cols)) bool: test patches
    truth: np.ndarray  # (len(rows), len(cols)) uint8 labels

    @property
    def count(self) -> int:
        return int(self.selected.sum())


@dataclass
class PatternRun:
    pattern: str
    shift_m: tuple[float, float, float]
    predictions: dict[str, np.ndarray] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)


def test_patches(
    pre: np.ndarray, post: np.ndarray, mask: np.ndarray, region: np.ndarray
) -> TestPatches:
    rows, cols = patch_origins(pre.shape)
    truth = label_from_fraction(centre_fractions(mask, rows, cols))
    selected = centres_inside(region, rows, cols) & usable_windows(pre, post, rows, cols, mask)
    return TestPatches(rows, cols, selected, truth)


def patch_labels_from_pixels(pixels: np.ndarray, patches: TestPatches) -> np.ndarray:
    """The 10 % rule on a boolean pixel mask, over the test grid."""
    return label_from_fraction(
        centre_fractions(pixels.astype(np.uint8), patches.rows, patches.cols)
    )


def patchnet_labels(
    loaded: LoadedModel, pre: np.ndarray, post: np.ndarray, px: float, patches: TestPatches
) -> np.ndarray:
    ri, ci = np.nonzero(patches.selected)
    offsets = np.arange(PATCH_PX)
    index_r = patches.rows[ri][:, None, None] + offsets[None, :, None]
    index_c = patches.cols[ci][:, None, None] + offsets[None, None, :]
    prob = predict_patches(loaded.model, pre[index_r, index_c], post[index_r, index_c], px)
    labels = np.zeros(patches.selected.shape, dtype=np.uint8)
    labels[ri, ci] = prob >= float(loaded.card.decision.get("patch_threshold", 0.5))
    return labels


def rasterize_detections(geojson_path: Path, shape: tuple[int, int], transform, crs) -> np.ndarray:
    """Detections (WGS84 GeoJSON) burnt into a bool mask on a metric grid."""
    collection = json.loads(Path(geojson_path).read_text())
    to_metric = Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    geoms = []
    for feature in collection["features"]:
        geom = to_shape(feature["geometry"])
        geoms.append(
            shapely.transform(geom, lambda xy: np.column_stack(to_metric.transform(*xy.T)))
        )
    if not geoms:
        return np.zeros(shape, dtype=bool)
    burnt = rasterio.features.rasterize(
        [(g, 1) for g in geoms], out_shape=shape, transform=transform, fill=0, dtype="uint8"
    )
    return burnt.astype(bool)


def _scaled_label(t_m: float, scale: float) -> str:
    return f"threshold_{round(t_m * 100)}cm" if scale == 1 else f"threshold_{t_m * scale:g}m"


def evaluate_pattern(
    pattern: str,
    shift_m: tuple[float, float, float],
    pre: np.ndarray,
    post_clean: np.ndarray,
    mask: np.ndarray,
    region: np.ndarray,
    transform,
    crs,
    pixel_size_m: float,
    scale: float,
    models: dict[str, LoadedModel],
    work_dir: Path,
    best: LoadedModel | None,
    threads: int = 2,
) -> tuple[PatternRun, TestPatches]:
    """Every detector on one pattern; returns predictions over the test grid."""
    from worker.simulator.registration import shift_dsm

    run = PatternRun(pattern, shift_m)
    post = shift_dsm(post_clean, pixel_size_m, shift_m).astype(np.float32)
    post[~np.isfinite(post_clean)] = np.nan
    patches = test_patches(pre, post, mask, region)

    for key, loaded in models.items():
        t0 = time.perf_counter()
        run.predictions[key] = patchnet_labels(loaded, pre, post, pixel_size_m, patches)
        run.seconds[key] = time.perf_counter() - t0

    dh = post - pre
    for t_m in (0.2, 0.3):
        t0 = time.perf_counter()
        with np.errstate(invalid="ignore"):
            above = np.abs(dh) > t_m * scale
        key = "threshold_20cm" if t_m == 0.2 else "threshold_30cm"
        run.predictions[key] = patch_labels_from_pixels(above, patches)
        run.seconds[key] = time.perf_counter() - t0
        run.extra[f"{key}_label"] = _scaled_label(t_m, scale)

    work = Path(work_dir) / f"pattern-{pattern}"
    inputs = work / "input"
    write_geotiff(inputs / "pre.tif", pre, transform, crs)
    write_geotiff(inputs / "post.tif", post, transform, crs)
    t0 = time.perf_counter()
    result = compare_dsms(
        inputs / "pre.tif", inputs / "post.tif", work / "comparison", lod_options(pixel_size_m)
    )
    run.seconds["lod"] = time.perf_counter() - t0
    with rasterio.open(work / "comparison" / "pre_aligned.tif") as src:
        grid_ok = src.shape == pre.shape and src.transform.almost_equals(transform)
        aligned_transform, aligned_crs = src.transform, src.crs
    if not grid_ok:
        raise RuntimeError("the aligned grid differs from the input grid")
    lod_pixels = rasterize_detections(
        result.detections_path, pre.shape, aligned_transform, aligned_crs
    )
    run.predictions["lod"] = patch_labels_from_pixels(lod_pixels, patches)
    run.extra["coregister"] = {
        k: result.results["coregister"][k]
        for k in ("shift_east_m", "shift_north_m", "shift_up_m", "nmad_before_m", "nmad_after_m")
    }
    run.extra["lod_m"] = result.results["difference"]["lod_m"]

    t0 = time.perf_counter()
    baseline = compare_dsms(
        inputs / "pre.tif",
        inputs / "post.tif",
        work / "comparison-uniform",
        lod_options(pixel_size_m, "uniform"),
    )
    run.seconds["lod_uniform"] = time.perf_counter() - t0
    run.predictions["lod_uniform"] = patch_labels_from_pixels(
        rasterize_detections(baseline.detections_path, pre.shape, aligned_transform, aligned_crs),
        patches,
    )
    run.extra["lod_uniform_m"] = baseline.results["difference"]["lod_m"]

    if best is not None:
        options = ComparisonOptions(method="cnn")
        options.detection.model = str(best.path.with_suffix(".json"))
        options.detection.num_threads = threads
        t0 = time.perf_counter()
        detect = run_stage(
            "detect", inputs / "pre.tif", inputs / "post.tif", work / "comparison", options
        )
        seconds = time.perf_counter() - t0
        # Co-registration is part of this detector: count it too.
        run.seconds["best"] = seconds + result.results["coregister"]["seconds"]
        found = rasterize_detections(
            work / "comparison" / "detections.geojson", pre.shape, aligned_transform, aligned_crs
        )
        run.predictions["best"] = patch_labels_from_pixels(found, patches)
        run.extra["best_detections"] = detect["detections"]

    # The default method, on the same first stages (alignment, co-registration, LoD).
    t0 = time.perf_counter()
    scored = run_stage(
        "score",
        inputs / "pre.tif",
        inputs / "post.tif",
        work / "comparison",
        ComparisonOptions(method="scored"),
    )
    run.seconds["scored"] = time.perf_counter() - t0 + result.results["coregister"]["seconds"]
    found = rasterize_detections(
        work / "comparison" / "detections.geojson", pre.shape, aligned_transform, aligned_crs
    )
    run.predictions["scored"] = patch_labels_from_pixels(found, patches)
    run.extra["scored_detections"] = scored["detections"]
    return run, patches


def score(run: PatternRun, patches: TestPatches) -> dict[str, dict[str, float]]:
    truth = patches.truth[patches.selected] == 1
    return {
        key: binary_metrics(truth, labels[patches.selected] == 1)
        for key, labels in run.predictions.items()
    }


def evaluate_manifest(
    manifest: DatasetManifest,
    work_dir: Path,
    patch_models: dict[str, LoadedModel],
    best: LoadedModel | None,
    patterns: list[str] | None = None,
    log=print,
    threads: int = 2,
) -> dict[str, Any]:
    """The Tables 6/7 benchmark on a dataset's test pair and region."""
    if not manifest.test:
        raise ValueError(f"dataset {manifest.name} defines no test")
    spec = manifest.pair(manifest.test["pair"])
    pair = load_pair(spec)
    with rasterio.open(manifest.regions[manifest.test["region"]]) as src:
        region = src.read(1) == 1
    all_patterns = {k: tuple(v) for k, v in manifest.test["patterns"].items()}
    scale = float(manifest.raw.get("registration_scale", 1.0)) or 1.0
    if "registration_scale" not in manifest.raw:
        scale = 10.0 if pair.pixel_size_m > 0.1 else 1.0
    results: dict[str, Any] = {"patterns": {}, "seconds": {}, "extra": {}}
    for pattern in patterns or sorted(all_patterns):
        t0 = time.perf_counter()
        run, patches = evaluate_pattern(
            pattern,
            all_patterns[pattern],
            pair.pre,
            pair.post,
            pair.mask,
            region,
            pair.transform,
            pair.crs,
            pair.pixel_size_m,
            scale,
            patch_models,
            work_dir,
            best,
            threads,
        )
        results["patterns"][pattern] = score(run, patches)
        results["seconds"][pattern] = run.seconds
        results["extra"][pattern] = run.extra
        results["test_patches"] = patches.count
        results["positive_patches"] = int((patches.truth[patches.selected] == 1).sum())
        log(
            f"pattern {pattern}: "
            + ", ".join(f"{k} F1 {v['f1']:.3f}" for k, v in results["patterns"][pattern].items())
            + f" ({time.perf_counter() - t0:.0f} s)"
        )
    results["scale"] = scale
    results["pixel_size_m"] = pair.pixel_size_m
    return results


def false_alarms(
    pre: np.ndarray,
    post: np.ndarray,
    transform,
    crs,
    pixel_size_m: float,
    best: LoadedModel,
    work_dir: Path,
    threads: int = 2,
) -> dict[str, Any]:
    """Run the cnn and threshold comparisons on a no-change pair; count detections."""
    work = Path(work_dir)
    write_geotiff(work / "input" / "pre.tif", pre, transform, crs)
    write_geotiff(work / "input" / "post.tif", post, transform, crs)
    pre_path, post_path = work / "input" / "pre.tif", work / "input" / "post.tif"
    lod = compare_dsms(pre_path, post_path, work / "cmp", lod_options(pixel_size_m))
    baseline = compare_dsms(
        pre_path, post_path, work / "cmp-uniform", lod_options(pixel_size_m, "uniform")
    )
    cnn = ComparisonOptions(method="cnn")
    cnn.detection.model = str(best.path.with_suffix(".json"))
    cnn.detection.num_threads = threads
    detect = run_stage("detect", pre_path, post_path, work / "cmp", cnn)
    rows, cols = patch_origins(pre.shape)
    with rasterio.open(work / "cmp" / "pre_aligned.tif") as src:
        found = rasterize_detections(
            work / "cmp" / "detections.geojson", pre.shape, src.transform, src.crs
        )
    labels = label_from_fraction(centre_fractions(found.astype(np.uint8), rows, cols))
    usable = usable_windows(pre, post, rows, cols)
    return {
        "cnn_detections": detect["detections"],
        "cnn_positive_cells": detect["positive_cells"],
        "cnn_positive_patches": int(labels[usable].sum()),
        "patches": int(usable.sum()),
        "lod_detections": lod.results["vectorize"]["detections"],
        "lod_uniform_detections": baseline.results["vectorize"]["detections"],
        "coregister": {
            k: lod.results["coregister"][k] for k in ("shift_east_m", "shift_north_m", "shift_up_m")
        },
    }


def format_table(results: dict[str, Any], title: str) -> str:
    """A plain-text table: method x pattern, P / R / F1, with the paper's figures."""
    lines = [title, ""]
    header = f"{'method':<16}" + "".join(f"| {p:^23}" for p in sorted(results["patterns"]))
    lines.append(header)
    lines.append(f"{'':<16}" + "| P     R     F1        " * len(results["patterns"]))
    methods = [m for m in METHOD_ORDER if any(m in v for v in results["patterns"].values())]
    for method in methods:
        row = f"{method:<16}"
        for pattern in sorted(results["patterns"]):
            m = results["patterns"][pattern].get(method)
            row += (
                f"| {m['precision']:.3f} {m['recall']:.3f} {m['f1']:.3f}     "
                if m
                else "| -" + " " * 22
            )
        lines.append(row)
    if results.get("pixel_size_m", 0) < 0.1:
        for method, table in PAPER_TABLES.items():
            row = f"{'paper ' + method[4:]:<16}"
            for pattern in sorted(results["patterns"]):
                p, r, f = table.get(pattern, (float("nan"),) * 3)
                row += f"| {p:.3f} {r:.3f} {f:.3f}     "
            lines.append(row)
    return "\n".join(lines)


__all__ = [
    "METHOD_ORDER",
    "PAPER_TABLES",
    "evaluate_manifest",
    "evaluate_pattern",
    "false_alarms",
    "format_table",
    "lod_options",
    "patch_labels_from_pixels",
    "rasterize_detections",
    "score",
    "test_patches",
]
