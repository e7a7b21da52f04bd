"""The comparison's `cnn` detection stage (`detect_cnn`) over files, memory bounded.

From `pre_aligned.tif` and `post_coregistered.tif` (one metric grid) it writes:

- probability.tif: per-pixel landslide probability (float32 0-1, nodata -9999 where
  either DSM has no data), a Cloud-Optimized GeoTIFF (overviews averaged);
- cells.geojson: the paper's 32-pixel cells on a stride-32 grid from the raster's
  top-left corner (partial cells at the right and bottom edges included), one feature
  per POSITIVE cell: landslide pixels (probability >= the model's pixel threshold) make
  up more than 10 % of the cell's valid pixels (the paper's rule). Properties: row, col
  (of the cell's top-left pixel), fraction, score (mean probability of the cell);
- detections.geojson: the merged landslide polygons: 8-connected landslide pixels that
  reach a positive cell, merged when they reach the same group of 8-connected positive
  cells (depletion and deposit of one slide are one landslide), kept when at least
  `min_area_px` pixels and when their mean probability (score) reaches the model card's
  `min_score` (a MultiPolygon when its parts do not touch). The cells are computed after
  this: pixels of landslides that were not kept are not landslide.
  Properties as the threshold method's (area_m2, volume_loss_m3, volume_gain_m3,
  max_abs_dh_m, score, method) plus model ("name@version"). Volumes sum |dh| x pixel
  area over the polygon's pixels beyond the difference stage's level of detection (loss
  and gain apart); max_abs_dh_m is the largest |dh| in the polygon; score is the
  polygon's mean probability.

Memory: the network works on one tile at a time (a few hundred MB at tile_px 1024);
grouping the landslide pixels holds about 10 bytes per pixel of the whole raster (uint8
classes, int32 labels and a relabelled copy): 250 MB for 1 km2 at 20 cm/pixel.
"""

from __future__ import annotations

import json
import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
import rasterio.features
import shapely
from rasterio.windows import Window
from scipy import ndimage
from shapely.geometry import box as shapely_box
from shapely.geometry import shape as to_shape

from worker.pipeline.atomic import write_text_atomic
from worker.pipeline.cnn.inference import (
    DEFAULT_PIXEL_THRESHOLD,
    MULTIPLE,
    pyramid_halo,
    pyramid_window,
    tiles,
    torch_threads,
    window_size,
)
from worker.pipeline.cnn.models import SlideNet
from worker.pipeline.cnn.options import CnnOptions
from worker.pipeline.cnn.patches import CORE_PX, LABEL_FRACTION, PATCH_PX
from worker.pipeline.cnn.registry import LoadedModel, resolve_model
from worker.pipeline.cog import RasterRole, write_cog
from worker.pipeline.detection_record import DetectionProperties, write_detections
from worker.pipeline.errors import InputError
from worker.pipeline.geo import crs_to_string, is_metric_projected, to_wgs84_geojson
from worker.pipeline.progress import ProgressFn, no_progress
from worker.pipeline.raster_io import NODATA
from worker.pipeline.stages import StageResult

CELL_PX = CORE_PX


@dataclass
class CnnResult(StageResult):
    detections: int
    total_area_m2: float
    total_volume_loss_m3: float
    total_volume_gain_m3: float
    positive_cells: int
    cells: int
    method: str
    model: str
    pixel_threshold: float
    min_score: float
    scales: list[int]
    crs: str
    pixels: int
    seconds: float
    inference_seconds: float


def _read_window(src: rasterio.io.DatasetReader, r0: int, c0: int, h: int, w: int):
    window = Window(c0, r0, w, h)
    data = src.read(1, window=window, boundless=True, masked=True, fill_value=src.nodata)
    array = np.ma.filled(data.astype(np.float32), np.nan)
    array[~np.isfinite(array)] = np.nan
    return array


def detect_cnn(
    pre_path: Path,
    post_path: Path,
    dh_path: Path,
    significance_path: Path,
    probability_out: Path,
    cells_out: Path,
    detections_out: Path,
    options: CnnOptions | None = None,
    progress: ProgressFn = no_progress,
    loaded: LoadedModel | None = None,
) -> CnnResult:
    """The `cnn` detection stage (see the module doc); inputs on one metric grid."""
    options = options or CnnOptions()
    start = time.perf_counter()
    loaded = loaded or resolve_model(options.model)
    model = loaded.model
    if not isinstance(model, SlideNet):
        raise InputError(
            f"model {loaded.version} is a {model.kind}: the cnn method needs a dense model"
        )
    threshold = options.pixel_threshold
    if threshold is None:
        threshold = float(loaded.card.decision.get("pixel_threshold", DEFAULT_PIXEL_THRESHOLD))
    scales = tuple(options.scales or loaded.card.decision.get("scales", [1]))
    torch_threads(options.num_threads)

    with rasterio.open(pre_path) as pre_src, rasterio.open(post_path) as post_src:
        if (pre_src.shape != post_src.shape) or (pre_src.transform != post_src.transform):
            raise InputError("pre and post DSMs must be on the same grid: run the align stage")
        height, width = pre_src.shape
        if height < PATCH_PX or width < PATCH_PX:
            raise InputError(
                f"the DSMs overlap on only {width} x {height} pixels: the CNN needs at least "
                f"one {PATCH_PX} x {PATCH_PX}-pixel patch"
            )
        transform, crs = pre_src.transform, pre_src.crs
        if not is_metric_projected(crs):
            raise InputError("the cnn method needs DSMs in a metric CRS: run the align stage")
        classes, infer_seconds = _write_probability(
            pre_src, post_src, model, threshold, scales, options.tile_px, probability_out, progress
        )
    progress(0.85)

    fraction, total = cell_fractions(classes)
    labels, count = _landslides(classes, _positive(fraction, total))
    min_score = options.min_score
    if min_score is None:
        min_score = float(loaded.card.decision.get("min_score", 0.0))
    detections, kept = _polygons(
        labels,
        count,
        Path(probability_out),
        Path(dh_path),
        Path(significance_path),
        transform,
        crs,
        options,
        loaded.version,
        min_score,
    )
    # The cells follow the landslides kept: pixels of dropped ones are not landslide.
    dropped = (labels > 0) & ~np.isin(labels, np.asarray(kept, dtype=labels.dtype))
    dropped |= (classes == 1) & (labels == 0)
    classes[dropped] = 0
    del labels, dropped
    progress(0.9)
    cells = _cells(classes, Path(probability_out), transform, crs)
    write_text_atomic(
        Path(cells_out),
        json.dumps(
            {
                "type": "FeatureCollection",
                "features": cells["features"],
                "metric_crs": crs_to_string(crs),
                "cell_px": CELL_PX,
                "rule": f"landslide pixels > {LABEL_FRACTION:.0%} of the cell",
            },
            separators=(",", ":"),
        ),
    )
    write_detections(Path(detections_out), detections, crs)
    progress(1.0)
    props = [properties for _, properties in detections]
    return CnnResult(
        detections=len(detections),
        total_area_m2=float(sum(p.area_m2 for p in props)),
        total_volume_loss_m3=float(sum(p.volume_loss_m3 for p in props)),
        total_volume_gain_m3=float(sum(p.volume_gain_m3 for p in props)),
        positive_cells=len(cells["features"]),
        cells=int(cells["count"]),
        method="cnn",
        model=loaded.version,
        pixel_threshold=float(threshold),
        min_score=float(min_score),
        scales=list(scales),
        crs=crs_to_string(crs),
        pixels=int(height * width),
        seconds=time.perf_counter() - start,
        inference_seconds=infer_seconds,
    )


def _write_probability(
    pre_src: rasterio.io.DatasetReader,
    post_src: rasterio.io.DatasetReader,
    model: SlideNet,
    threshold: float,
    scales: tuple[int, ...],
    tile_px: int,
    probability_out: Path,
    progress: ProgressFn,
) -> tuple[np.ndarray, float]:
    """Tile by tile: the probability COG, and the whole raster's classes (uint8: 1
    landslide pixel, 0 not, 255 nodata). Returns (classes, seconds in the network)."""
    height, width = pre_src.shape
    pixel_size = float((abs(pre_src.transform.a) + abs(pre_src.transform.e)) / 2)
    halo = pyramid_halo(scales)
    classes = np.full((height, width), 255, dtype=np.uint8)
    profile = {
        "driver": "GTiff",
        "height": height,
        "width": width,
        "count": 1,
        "dtype": "float32",
        "crs": pre_src.crs,
        "transform": pre_src.transform,
        "nodata": NODATA,
        "tiled": True,
        "blockxsize": 256,
        "blockysize": 256,
        "compress": "deflate",
        "predictor": 3,
    }
    grid = list(tiles((height, width), tile_px, MULTIPLE * max(scales)))
    infer_seconds = 0.0
    with tempfile.TemporaryDirectory(dir=Path(probability_out).parent) as tmp_dir:
        tmp_tif = Path(tmp_dir) / "probability.tif"
        with rasterio.open(tmp_tif, "w", **profile) as dst:
            for i, (r0, c0, h, w) in enumerate(grid):
                size = window_size(h, w, halo, max(scales))
                pre_w = _read_window(pre_src, r0 - halo, c0 - halo, *size)
                post_w = _read_window(post_src, r0 - halo, c0 - halo, *size)
                t0 = time.perf_counter()
                p = pyramid_window(model, pre_w, post_w, pixel_size, scales, halo, (h, w))
                infer_seconds += time.perf_counter() - t0
                core = (slice(halo, halo + h), slice(halo, halo + w))
                valid = np.isfinite(pre_w[core]) & np.isfinite(post_w[core])
                classes[r0 : r0 + h, c0 : c0 + w] = np.where(valid, p >= threshold, 255)
                out = np.where(valid, np.round(p, 3), NODATA).astype(np.float32)
                dst.write(out, 1, window=Window(c0, r0, w, h))
                progress(0.8 * (i + 1) / len(grid))
        # Probabilities are continuous: overviews average them (the elevation role).
        write_cog(tmp_tif, Path(probability_out), RasterRole.elevation)
    return classes, infer_seconds


def cell_fractions(classes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Landslide share and valid-pixel count of each stride-32 cell (partial edge cells
    included). `classes`: uint8 1 landslide, 0 not, 255 nodata."""
    height, width = classes.shape
    nr, nc = math.ceil(height / CELL_PX), math.ceil(width / CELL_PX)
    padded = np.full((nr * CELL_PX, nc * CELL_PX), 255, dtype=np.uint8)
    padded[:height, :width] = classes
    blocks = padded.reshape(nr, CELL_PX, nc, CELL_PX)
    landslide = (blocks == 1).sum(axis=(1, 3))
    total = (blocks != 255).sum(axis=(1, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        fraction = np.where(total > 0, landslide / np.maximum(total, 1), 0.0)
    return fraction, total


def _positive(fraction: np.ndarray, total: np.ndarray) -> np.ndarray:
    """The paper's rule per cell: landslide pixels > 10 % of the cell's valid pixels."""
    return (np.rint(fraction * total) > LABEL_FRACTION * total) & (total > 0)


def _cells(classes: np.ndarray, probability_path: Path, transform, crs) -> dict[str, Any]:
    fraction, total = cell_fractions(classes)
    positive = _positive(fraction, total)
    features = []
    with rasterio.open(probability_path) as prob_src:
        for i, j in zip(*np.nonzero(positive), strict=True):
            r0, c0 = int(i * CELL_PX), int(j * CELL_PX)
            h = min(CELL_PX, classes.shape[0] - r0)
            w = min(CELL_PX, classes.shape[1] - c0)
            p = prob_src.read(1, window=Window(c0, r0, w, h), masked=True)
            left, top = transform * (c0, r0)
            right, bottom = transform * (c0 + w, r0 + h)
            geom = shapely_box(
                min(left, right), min(top, bottom), max(left, right), max(top, bottom)
            )
            features.append(
                {
                    "type": "Feature",
                    "geometry": to_wgs84_geojson(geom, crs),
                    "properties": {
                        "row": r0,
                        "col": c0,
                        "fraction": round(float(fraction[i, j]), 3),
                        "score": round(float(p.mean()) if p.count() else 0.0, 3),
                    },
                }
            )
    return {"features": features, "positive": positive, "count": int((total > 0).sum())}


def _polygons(
    labels: np.ndarray,
    count: int,
    probability_path: Path,
    dh_path: Path,
    significance_path: Path,
    transform,
    crs,
    options: CnnOptions,
    model_version: str,
    min_score: float,
) -> tuple[list[dict[str, Any]], list[int]]:
    """Polygons of the labelled landslides that are large and confident enough; returns
    their detection records (WGS84 geometry, properties) and the labels kept."""
    if count == 0:
        return [], []
    sizes = np.bincount(labels.ravel(), minlength=count + 1)
    pixel_area = abs(transform.a * transform.e)
    min_px = options.min_area_px
    if options.min_area_m2 is not None:
        min_px = math.ceil(options.min_area_m2 / pixel_area)
    lod = _lod(significance_path)
    objects = ndimage.find_objects(labels)
    detections: list[tuple[dict[str, Any], DetectionProperties]] = []
    kept: list[int] = []
    with (
        rasterio.open(probability_path) as prob_src,
        rasterio.open(dh_path) as dh_src,
    ):
        for label in range(1, count + 1):
            if sizes[label] < min_px or objects[label - 1] is None:
                continue
            rows, cols = objects[label - 1]
            window = Window(cols.start, rows.start, cols.stop - cols.start, rows.stop - rows.start)
            inside = labels[rows, cols] == label
            prob = np.ma.filled(
                prob_src.read(1, window=window, masked=True).astype(np.float64), np.nan
            )
            score = float(np.nanmean(prob[inside]))
            if score < min_score:
                continue
            kept.append(label)
            dh = np.ma.filled(dh_src.read(1, window=window, masked=True).astype(np.float64), np.nan)
            win_transform = rasterio.windows.transform(window, transform)
            polys = [
                to_shape(geom)
                for geom, value in rasterio.features.shapes(
                    inside.astype(np.uint8), mask=inside, transform=win_transform, connectivity=8
                )
                if value == 1
            ]
            geometry = shapely.union_all(polys) if len(polys) > 1 else polys[0]
            finite = inside & np.isfinite(dh)
            with np.errstate(invalid="ignore"):
                loss = finite & (dh < -lod)
                gain = finite & (dh > lod)
            properties = DetectionProperties(
                area_m2=round(float(geometry.area), 2),
                volume_loss_m3=round(float(-dh[loss].sum() * pixel_area), 2) + 0.0,
                volume_gain_m3=round(float(dh[gain].sum() * pixel_area), 2) + 0.0,
                max_abs_dh_m=round(float(np.abs(dh[finite]).max()) if finite.any() else 0.0, 3),
                score=round(score, 3),
                method="cnn",
                model_version=model_version,
            )
            detections.append((to_wgs84_geojson(geometry, crs), properties))
    return detections, kept


def _landslides(classes: np.ndarray, positive_cells: np.ndarray) -> tuple[np.ndarray, int]:
    """Label image of the landslides: 8-connected landslide pixels that reach a positive
    cell, merged when they reach the same group of 8-connected positive cells (so the
    depletion and the deposit of one slide, split by a thin unchanged gap, are one)."""
    eight = np.ones((3, 3), dtype=bool)
    labels, count = ndimage.label(classes == 1, structure=eight)
    cell_groups, _ = ndimage.label(positive_cells, structure=eight)
    group_of = np.zeros(count + 1, dtype=np.int32)
    parent: dict[int, int] = {}

    def find(g: int) -> int:
        while parent.setdefault(g, g) != g:
            g = parent[g]
        return g

    for label, window in enumerate(ndimage.find_objects(labels), start=1):
        if window is None:
            continue
        rr, cc = np.nonzero(labels[window] == label)
        groups = np.unique(
            cell_groups[(rr + window[0].start) // CELL_PX, (cc + window[1].start) // CELL_PX]
        )
        groups = groups[groups > 0]
        if groups.size == 0:
            continue
        root = find(int(groups[0]))
        for g in groups[1:]:
            parent[find(int(g))] = root
        group_of[label] = root
    roots = {find(int(g)) for g in group_of[group_of > 0]}
    renumber = {root: i for i, root in enumerate(sorted(roots), start=1)}
    final = np.zeros(count + 1, dtype=np.int32)
    for label in range(1, count + 1):
        if group_of[label]:
            final[label] = renumber[find(int(group_of[label]))]
    return final[labels], len(renumber)


def _lod(significance_path: Path) -> float:
    """The level of detection the difference stage applied (0 when unknown)."""
    try:
        with rasterio.open(significance_path) as src:
            value = src.tags().get("LOD_M")
    except rasterio.errors.RasterioIOError:
        return 0.0
    return float(value) if value else 0.0


__all__ = ["CELL_PX", "CnnResult", "cell_fractions", "detect_cnn"]
