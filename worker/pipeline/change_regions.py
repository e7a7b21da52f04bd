"""Regions of significant change: their polygons, sizes with 95 % intervals, and traits.

One place builds a detection's record for the methods that work from the per-pixel LoD
(`threshold` and `scored`): the polygon, area and volumes with their 95 % intervals, the
largest |dh|, the LoD met, and the traits a scorer uses (how far beyond the LoD, how
large against the errors' correlation, whether it is a tall object that appeared or
vanished with no ground motion around it).

Intervals (95 %):
- volumes: the region's loss (gain) is the sum of its negative (positive) dh times the
  pixel area; its error is the area times the region's mean sigma over sqrt(n_eff), the
  effective number of samples of an area of that size under the fitted variogram
  (error_model.py), so correlated errors widen it as they should;
- area: from the region eroded by one pixel (its edge is uncertain by a pixel) to the
  region grown by one pixel over the neighbouring pixels beyond half the LoD (the fringe
  where change is likely but not significant).

Vegetation and structures: a pixel is a tall object when it stands more than
`object_height_m` above the local ground (a grey opening of the DSM wider than a tree
crown or a house). A region whose significant pixels are mostly objects that vanished
(loss) or appeared (gain), with the ground under and around it unmoved, is a surface
change (a tree felled or grown, a building built or removed), not a landslide; so is
an object's edge displaced by a fraction of a pixel (`displaced_edges`: a wall's strip of
loss and gain that registration or resampling leaves, partly beside the object). Ground
counts as moved beyond 1.5 times its LoD: a tree-sized region has a handful of ground
pixels around it, where passing the LoD itself is too often chance. Objects lost beside
a landslide region are part of it (`split_surface_changes`); for the default, "beside"
is measured on the simple baseline's larger regions around both (`judge_by_baseline`).

Low vegetation cut (grass mown, a crop harvested) is surface change too: a loss region
that holds no deposit, whose fine texture the post survey lost without gaining new, no
deeper than that texture says the sward was (vegetation_cut.py). It joins a landslide
beside it only when that landslide's gain holds half its loss (a scar and its deposit).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
import rasterio.features
import rasterio.windows
import shapely
from scipy import ndimage
from shapely.geometry import shape as to_shape

from worker.pipeline.binned import binned_mean
from worker.pipeline.detection_record import DetectionProperties, Uncertainty
from worker.pipeline.difference import (
    BASELINE_CORRELATION_TAG,
    BASELINE_LOD_TAG,
    BASELINE_MEDIAN_TAG,
    ERROR_MODEL_FILE,
    GAIN,
    LOD_FILE,
    LOD_Z,
    LOSS,
    read_error_model,
)
from worker.pipeline.error_model import ErrorModel, VariogramModel
from worker.pipeline.errors import InputError
from worker.pipeline.geo import to_wgs84_geojson
from worker.pipeline.raster_io import read_elevation
from worker.pipeline.vegetation_cut import cut_texture, is_vegetation_cut

SURFACE_CHANGE = "surface-change"
LANDSLIDE = "landslide"
# Why a region is a surface change.
OBJECTS = "objects"  # tall objects appeared or vanished (trees, buildings)
VEGETATION_CUT = "vegetation-cut"  # low vegetation cut (vegetation_cut.py)
# Objects' edges moved a fraction of a pixel (displaced_edges): nothing was lost there, so
# such a region neither joins a landslide beside it nor skips the volume test.
DISPLACED_EDGES = "displaced-edges"


@dataclass
class RegionOptions:
    # None: max(min_area_px pixels, correlation_area_factor * pi * (L/2)^2), L the errors'
    # correlation length, so a patch of correlated error is not taken for a change.
    min_area_m2: float | None = None
    min_area_px: int = 64
    correlation_area_factor: float = 1.0
    # A region smaller than that (but of min_area_px at least) is still kept when its
    # pixels' |dh| average this many times their LoD: a patch of correlated error that
    # passed the LoD averages 1.2-1.7 times it (126 patches in 30 simulated no-change
    # fields, correlation lengths 3-17 m), a collapsed mound of a few square metres on the
    # demo site 2.0-3.5. None: the minimum area alone decides.
    small_region_lod_ratio: float | None = 2.0
    # ... and covers this share of the minimum area (a disk a quarter of the correlation
    # length across): narrower change is a blunder of a reconstruction (a spike, a
    # mismatched patch), not ground the two DSMs resolve as having moved.
    small_region_area_factor: float = 1.0 / 16.0
    opening_px: int = 1  # radius of the square that removes speckle
    closing_px: int = 2  # radius of the square that bridges gaps
    object_height_m: float = 2.5
    object_width_m: float = 15.0  # wider than a tree crown or a house
    object_fraction: float = 0.5  # share of a region's change on objects
    ground_motion_fraction: float = 0.2  # share of the region whose ground moved
    # Bare ground counts as moved beyond this many times its LoD. At the LoD itself 5 % of
    # still ground passes by chance (more beside crowns, whose error the slope and
    # curvature of the mean surface do not show), and the ground around a tree-sized
    # region is a handful of pixels: two of nine beyond the LoD made a growing tree a
    # landslide. At 1.5 times it (z > 2.9) chance passes 0.3 %. Chosen on training seeds
    # (docs/significance.md), where keeping 1.0 for lost objects found no more slides and
    # had more false alarms.
    ground_motion_lod_ratio: float = 1.5
    # Objects lost this close to a landslide region are part of it: the trees a slide
    # carried off, which the LoD cuts from its ground. Growth beside a slide is not (trees
    # grow everywhere). 5 m: chosen on training seeds, where it found the slide 10 m did
    # with fewer false alarms. 0 turns the rule off.
    object_context_m: float = 5.0
    # Set aside low vegetation cut (grass mown, a crop harvested; vegetation_cut.py): a
    # loss region whose gain is at most `cut_gain_share` of its volume, shallower than a
    # tall object, whose new fine texture is under `cut_new_texture_ratio` times the
    # texture it lost, and whose depth is under `cut_depth_texture_ratio` standard
    # deviations of that lost texture; texture: the DSMs high-passed at `cut_texture_m`,
    # judged only where a pixel is no larger. 0.7 and 10: the loosest values tried that
    # lost no slide on the training seeds 0-11 of the pair generators, where a scale of
    # 0.3 m lost one. Off by default: on the benchmark's seeds it set aside two slides
    # lying in mown patches that the simple baseline finds (docs/significance.md, *Grass
    # mown between surveys*).
    vegetation_cut: bool = False
    cut_new_texture_ratio: float = 0.7
    cut_depth_texture_ratio: float = 10.0
    cut_gain_share: float = 0.2
    cut_texture_m: float = 0.2
    # ... and that holds no deposit: no significant gain in one piece of the minimum
    # region's size holding this share of its loss.
    cut_inner_deposit_share: float = 0.05
    # ... and where tall objects stand on at most this share of it.
    cut_object_share: float = 0.05
    # A cut joins a landslide region within object_context_m only when their gain holds
    # this share of its loss: a scar and the deposit its material went to.
    cut_deposit_share: float = 0.5


@dataclass(frozen=True)
class BaselineTest:
    """The simple baseline's test of a difference: one median and one LoD95 for the
    raster, and the correlation length of its errors (None: not recorded, an older
    work dir)."""

    median_m: float
    lod95_m: float
    correlation_length_m: float | None = None


@dataclass
class ChangeRasters:
    """Everything a region needs, on the comparison's grid."""

    dh: np.ndarray  # centred: minus the stable-terrain median
    lod: np.ndarray
    significance: np.ndarray
    transform: rasterio.Affine
    crs: Any
    model: ErrorModel
    pre: np.ndarray | None = None
    post: np.ndarray | None = None
    # The simple baseline's test where the difference stage floored the per-pixel LoD at
    # it; None otherwise.
    baseline: BaselineTest | None = None
    _objects: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)

    @property
    def pixel_size(self) -> float:
        return float(abs(self.transform.a))

    @property
    def pixel_area(self) -> float:
        return float(abs(self.transform.a * self.transform.e))

    @property
    def sigma(self) -> np.ndarray:
        return self.lod / LOD_Z

    def objects(self, options: RegionOptions) -> tuple[np.ndarray, np.ndarray]:
        """(tall object in pre, tall object in post) per pixel; computed once."""
        if self._objects is None:
            if self.pre is None or self.post is None:
                zeros = np.zeros(self.dh.shape, dtype=bool)
                self._objects = (zeros, zeros)
            else:
                ground_pre = _local_ground(self.pre, self.pixel_size, options.object_width_m)
                ground_post = _local_ground(self.post, self.pixel_size, options.object_width_m)
                with np.errstate(invalid="ignore"):
                    vanished = (self.pre - ground_pre) > options.object_height_m
                    appeared = (self.post - ground_post) > options.object_height_m
                self._objects = (vanished, appeared)
        return self._objects

    @property
    def median(self) -> float:
        return float(self.model.median_dh_m)


def load_change_rasters(
    dh_path: Path,
    significance_path: Path,
    pre_path: Path | None = None,
    post_path: Path | None = None,
) -> ChangeRasters:
    """Read the difference stage's outputs (and the DSMs, for the object rule).

    Without lod.tif / error_model.json beside dh (an older work dir, or a caller's own
    significance mask), the LoD is the mask's LOD_M tag everywhere and errors are taken
    as uncorrelated.
    """
    dh, profile = read_elevation(dh_path)
    with rasterio.open(significance_path) as src:
        significance = src.read(1)
        tags = src.tags()
    if significance.shape != dh.shape:
        raise InputError("the significance mask is not on the grid of the elevation difference")
    folder = Path(dh_path).parent
    if (folder / LOD_FILE).exists() and (folder / ERROR_MODEL_FILE).exists():
        lod, _ = read_elevation(folder / LOD_FILE)
        model = read_error_model(folder)
    else:
        value = _tag_lod(tags, significance, dh)
        lod = np.where(np.isfinite(dh), np.float32(value), np.nan).astype(np.float32)
        pixel = float(abs(profile["transform"].a))
        model = ErrorModel(
            pixel_size=pixel,
            slope_centres_deg=[0.0],
            curvature_centres=[0.0],
            sigma_table=[[value / LOD_Z]],
            median_dh_m=0.0,
            nmad_m=value / LOD_Z,
            stable_pixels=0,
            variogram=VariogramModel(nugget=1.0, ranges_m=[], psills=[]),
        )
    baseline = None
    if tags.get(BASELINE_MEDIAN_TAG) and tags.get(BASELINE_LOD_TAG):
        length = tags.get(BASELINE_CORRELATION_TAG)
        baseline = BaselineTest(
            float(tags[BASELINE_MEDIAN_TAG]),
            float(tags[BASELINE_LOD_TAG]),
            float(length) if length not in (None, "None") else None,
        )
    rasters = ChangeRasters(
        dh=(dh - np.float32(model.median_dh_m)).astype(np.float32),
        lod=lod,
        significance=significance,
        transform=profile["transform"],
        crs=profile["crs"],
        model=model,
        baseline=baseline,
    )
    if pre_path is not None and post_path is not None:
        rasters.pre, _ = read_elevation(pre_path)
        rasters.post, _ = read_elevation(post_path)
    return rasters


def min_area_m2(rasters: ChangeRasters, options: RegionOptions) -> float:
    """The smallest region kept (see RegionOptions.min_area_m2).

    Where the simple baseline's errors correlate farther than the per-pixel model's
    (whose variogram is of the difference standardised by slope and curvature, and
    learnt away from strong change), its length decides: a patch of correlated error
    the baseline's minimum area rejects is not kept by the default either
    (simulator-video seed 1004's no-change twin: a 24.5 m2 patch between the default's
    19.8 m2 and the baseline's 24.6 m2, docs/significance.md)."""
    if options.min_area_m2 is not None:
        return float(options.min_area_m2)
    length = rasters.model.correlation_length_m
    if rasters.baseline is not None and rasters.baseline.correlation_length_m is not None:
        length = max(length, rasters.baseline.correlation_length_m)
    correlated = options.correlation_area_factor * math.pi * (length / 2.0) ** 2
    return max(options.min_area_px * rasters.pixel_area, correlated)


def clean_mask(changed: np.ndarray, options: RegionOptions) -> np.ndarray:
    """Opening removes speckle, closing bridges gaps (without eroding the raster's edge)."""
    if options.opening_px > 0:
        size = 2 * options.opening_px + 1
        changed = ndimage.binary_opening(changed, structure=np.ones((size, size), dtype=bool))
    if options.closing_px > 0:
        size = 2 * options.closing_px + 1
        padded = np.pad(changed, options.closing_px, mode="edge")
        closed = ndimage.binary_closing(padded, structure=np.ones((size, size), dtype=bool))
        changed = closed[tuple(slice(options.closing_px, -options.closing_px) for _ in range(2))]
    return changed


def significant_regions(rasters: ChangeRasters, options: RegionOptions) -> np.ndarray:
    """Pixels of cleaned significant change (loss and gain together: a landslide is both)."""
    changed = (rasters.significance == LOSS) | (rasters.significance == GAIN)
    return clean_mask(changed, options)


def baseline_difference(rasters: ChangeRasters) -> tuple[np.ndarray, float]:
    """dh centred on the simple baseline's median, and its LoD95 (one NMAD for the
    raster); only where the difference stage kept a baseline (`rasters.baseline`)."""
    if rasters.baseline is None:
        raise ValueError("the difference stage kept no baseline for these rasters")
    test = rasters.baseline
    return rasters.dh + np.float32(rasters.model.median_dh_m - test.median_m), test.lod95_m


def baseline_significant(rasters: ChangeRasters) -> np.ndarray | None:
    """Pixels the simple baseline finds significant; None where the difference stage
    kept no baseline."""
    if rasters.baseline is None:
        return None
    centred, lod95 = baseline_difference(rasters)
    with np.errstate(invalid="ignore"):
        return np.abs(centred) > np.float32(lod95)


def grow_into_baseline(
    labels: np.ndarray,
    keep: list[int],
    rasters: ChangeRasters,
    steps: int,
    options: RegionOptions,
) -> tuple[np.ndarray, list[tuple[slice, slice]]]:
    """The kept regions grown, a pixel at a time up to `steps`, into neighbouring pixels
    of the simple baseline's cleaned regions (hysteresis: the strict test finds a
    change, the looser one draws its edge); labels (only the kept regions') and their
    windows. Grown into the baseline's raw significant pixels instead, the regions took
    in the speckle its opening removes, and a no-change twin's false alarms exceeded the
    baseline's (ridge-debris seed 1000: 46 849 against 42 589 m²/km²).

    Where change covers much of the steep ground, the per-pixel LoD's steep bins are
    learnt partly on it and stay above the uniform LoD, and a change's thin edge on a
    steep flank passes the baseline's test but not the default's: on the paper's mounds
    the default lost 581 true pixels the baseline found, in pieces of at most 85 pixels
    along the flanks. Grown only from regions already kept, the rule adds no region."""
    grown = np.where(np.isin(labels, keep), labels, 0).astype(np.int32)
    base = baseline_significant(rasters)
    if base is not None and steps > 0:
        base = clean_mask(base, options)
        for _ in range(steps):
            spread = ndimage.grey_dilation(grown, size=(3, 3))
            add = (grown == 0) & (spread > 0) & base
            if not add.any():
                break
            grown[add] = spread[add]
    objects = ndimage.find_objects(grown)
    return grown, [objects[k - 1] for k in keep]


def label_regions(
    mask: np.ndarray, rasters: ChangeRasters, options: RegionOptions
) -> tuple[np.ndarray, list[int], list[tuple[slice, slice]]]:
    """8-connected regions large enough or strong enough: labels, kept ids, their windows.

    A region is kept when it covers the minimum area or, smaller but of `min_area_px`
    pixels at least, when its change is strong (`RegionOptions.small_region_lod_ratio`).
    """
    labels, count = ndimage.label(mask, structure=np.ones((3, 3), dtype=bool))
    if not count:
        return labels, [], []
    sizes = np.bincount(labels.ravel(), minlength=count + 1)
    smallest = min_area_m2(rasters, options)
    areas = sizes * rasters.pixel_area
    kept = areas >= smallest
    if options.small_region_lod_ratio is not None:
        small = (sizes >= options.min_area_px) & ~kept
        small &= areas >= options.small_region_area_factor * smallest
        ratio = _mean_lod_ratio(labels, rasters, sizes.size)
        kept |= small & (ratio >= options.small_region_lod_ratio)
    kept[0] = False
    keep = [int(k) for k in np.flatnonzero(kept)]
    objects = ndimage.find_objects(labels)
    return labels, keep, [objects[k - 1] for k in keep]


def _mean_lod_ratio(labels: np.ndarray, rasters: ChangeRasters, count: int) -> np.ndarray:
    """Per label, the mean over its finite pixels of |dh| / LoD (0 where it has none)."""
    finite = (labels > 0) & np.isfinite(rasters.dh) & (rasters.lod > 0)
    ratio = np.abs(rasters.dh[finite]).astype(np.float64) / rasters.lod[finite]
    return binned_mean(ratio, labels[finite], count)[1]


@dataclass
class Region:
    """One region: its polygon (metric CRS), its detection properties and its traits."""

    geometry: Any
    properties: dict[str, Any]
    traits: dict[str, float]
    kind: str  # LANDSLIDE or SURFACE_CHANGE
    cause: str | None = None  # a surface change's: OBJECTS, DISPLACED_EDGES or VEGETATION_CUT
    # What the context rule measures distances from (split_surface_changes): the
    # region's own polygon (None) or one that takes in the baseline's region around it.
    reach: Any = None

    @property
    def extent(self) -> Any:
        """The polygon the context rule measures from."""
        return self.geometry if self.reach is None else self.reach


def split_surface_changes(
    regions: list[Region], options: RegionOptions
) -> tuple[list[Region], list[Region]]:
    """(landslides, surface changes) among described regions, each in the given order.

    Objects that appeared or vanished with no ground motion around them are surface
    change, except objects lost within `object_context_m` of a landslide region: a slide
    that takes its trees along is often cut by the LoD into ground parts (landslides) and
    crown parts (which alone look like felling). Distances are between the regions'
    `extent`s.
    """
    landslides = [r for r in regions if r.kind != SURFACE_CHANGE]
    context = options.object_context_m
    if context > 0 and landslides and len(landslides) < len(regions):
        index = shapely.STRtree([r.extent for r in landslides])

        def near(region: Region) -> list[Region]:
            return [landslides[i] for i in index.query(region.extent, "dwithin", context)]

        regions = [
            replace(r, kind=LANDSLIDE, cause=None)
            if r.kind == SURFACE_CHANGE
            and r.properties["volume_loss_m3"] > r.properties["volume_gain_m3"]
            and _joins(r, near(r), options)
            else r
            for r in regions
        ]
    return (
        [r for r in regions if r.kind != SURFACE_CHANGE],
        [r for r in regions if r.kind == SURFACE_CHANGE],
    )


def _joins(surface: Region, near: list[Region], options: RegionOptions) -> bool:
    """Whether a surface change lost beside these landslide regions is part of them:
    lost objects always (the trees a slide carried off); a vegetation cut only when
    their gain holds `cut_deposit_share` of its loss (a scar beside its deposit), since
    mown grass lies beside whatever else changed; objects' displaced edges never
    (nothing was lost there)."""
    if not near or surface.cause == DISPLACED_EDGES:
        return False
    if surface.cause != VEGETATION_CUT:
        return True
    gain = sum(r.properties["volume_gain_m3"] for r in near)
    return gain >= options.cut_deposit_share * surface.properties["volume_loss_m3"]


def judge_by_baseline(
    rasters: ChangeRasters,
    labels: np.ndarray,
    keep: list[int],
    windows: list[tuple[slice, slice]],
    regions: list[Region],
    options: RegionOptions,
    set_aside: bool = True,
    context: bool = True,
) -> list[Region]:
    """`regions` (described, in `keep` order) judged on the simple baseline's regions
    around them.

    The default's significant pixels are a subset of the baseline's, so its regions are
    smaller, which cuts both ways:
    - `set_aside`: under canopy a region of a few crowns seen in one survey and not the
      other keeps some ground pixels past the LoD and reads as ground motion, where the
      baseline's region around it takes in the trees and is set aside. A landslide
      region lying in a baseline region the object rule sets aside becomes a surface
      change: the default sets aside whatever the baseline does.
    - `context`: the crowns a forested slide carried off lie farther from its ground
      part than in the baseline's larger regions (simulator-video seed 1001: 6.5 m
      against 3.0 m, beyond the 5 m of `object_context_m`, and its largest slide was
      missed where the baseline found it). Each region's `reach` takes in the baseline
      region it lies in, so that the context rule joins whatever the baseline's joins.
    """
    if rasters.baseline is None or rasters.pre is None or rasters.post is None:
        return regions
    if all(r.kind == SURFACE_CHANGE for r in regions):
        return regions
    centred, lod95 = baseline_difference(rasters)
    with np.errstate(invalid="ignore"):
        changed = np.abs(centred) > np.float32(lod95)
    base_labels, _ = ndimage.label(clean_mask(changed, options), structure=np.ones((3, 3), bool))
    del changed
    base_windows = ndimage.find_objects(base_labels)
    kinds: dict[int, tuple[str, str | None]] = {}
    out = []
    for region, label, window in zip(regions, keep, windows, strict=True):
        under = base_labels[window][labels[window] == label]
        under = under[under > 0]
        if not under.size:
            out.append(region)
            continue
        base = int(np.bincount(under).argmax())
        kind, cause = region.kind, region.cause
        if set_aside and kind != SURFACE_CHANGE:
            if base not in kinds:
                kinds[base] = _baseline_kind(
                    rasters, base_labels, base, base_windows[base - 1], centred, lod95, options
                )
            kind, cause = kinds[base]
        reach = region.reach
        if context:
            win = base_windows[base - 1]
            outline = region_polygon(base_labels[win] == base, _window_transform(win, rasters))
            reach = shapely.union(region.geometry, outline)
        out.append(replace(region, kind=kind, cause=cause, reach=reach))
    return out


def _window_transform(window: tuple[slice, slice], rasters: ChangeRasters) -> rasterio.Affine:
    rows, cols = window
    return rasterio.windows.transform(
        rasterio.windows.Window(
            cols.start, rows.start, cols.stop - cols.start, rows.stop - rows.start
        ),
        rasters.transform,
    )


def region_polygon(inside: np.ndarray, transform: rasterio.Affine) -> Any:
    """The outline of the True pixels of `inside` (8-connected) in the raster's CRS."""
    polygons = [
        to_shape(geom)
        for geom, value in rasterio.features.shapes(
            inside.astype(np.uint8), mask=inside, transform=transform, connectivity=8
        )
        if value == 1
    ]
    return shapely.union_all(polygons) if len(polygons) > 1 else polygons[0]


def _padded(
    window: tuple[slice, slice], shape: tuple[int, ...], pad: int = 4
) -> tuple[slice, slice]:
    """A region's window grown by `pad` pixels (within the raster): room for the
    dilations that look around it."""
    rows, cols = window
    return (
        slice(max(rows.start - pad, 0), min(rows.stop + pad, shape[0])),
        slice(max(cols.start - pad, 0), min(cols.stop + pad, shape[1])),
    )


def _baseline_kind(
    rasters: ChangeRasters,
    base_labels: np.ndarray,
    base: int,
    window: tuple[slice, slice],
    centred: np.ndarray,
    lod95: float,
    options: RegionOptions,
) -> tuple[str, str | None]:
    """The surface-change rules' verdict (kind, cause) on one region of the baseline (its
    one LoD everywhere)."""
    win = _padded(window, base_labels.shape)
    inside = base_labels[win] == base
    dh = centred[win]
    lod = np.full(dh.shape, np.float32(lod95))
    with np.errstate(invalid="ignore"):
        significant = inside & (np.abs(dh) > lod)
    kind, object_share, _ = _kind(rasters, win, inside, significant, dh, lod, options)
    if kind == SURFACE_CHANGE:
        return kind, _object_cause(object_share, options)
    if _vegetation_cut(rasters, win, inside, dh, lod, options):
        return SURFACE_CHANGE, VEGETATION_CUT
    return kind, None


def describe_region(
    rasters: ChangeRasters,
    labels: np.ndarray,
    label: int,
    window: tuple[slice, slice],
    options: RegionOptions,
) -> Region:
    """The region's polygon, sizes with 95 % intervals, and its traits."""
    win = _padded(window, labels.shape)
    inside = labels[win] == label
    dh = rasters.dh[win]
    lod = rasters.lod[win]
    sig = rasters.significance[win]
    finite = inside & np.isfinite(dh)
    geometry = region_polygon(inside, _window_transform(win, rasters))
    pa = rasters.pixel_area
    values = dh[finite]
    sigmas = lod[finite] / LOD_Z
    significant = finite & ((sig == LOSS) | (sig == GAIN))
    lossy = finite & (dh < 0)
    gainy = finite & (dh > 0)
    volume_loss = float(-dh[lossy].sum() * pa)
    volume_gain = float(dh[gainy].sum() * pa)
    loss_sigma = _volume_sigma(rasters.model, lod[lossy] / LOD_Z, pa)
    gain_sigma = _volume_sigma(rasters.model, lod[gainy] / LOD_Z, pa)
    loss_half, gain_half = 1.96 * loss_sigma, 1.96 * gain_sigma

    eroded = ndimage.binary_erosion(inside, structure=np.ones((3, 3), bool))
    near = ndimage.binary_dilation(inside, structure=np.ones((3, 3), bool), iterations=2)
    with np.errstate(invalid="ignore"):
        fringe = near & (np.abs(dh) > 0.5 * lod)
    grown = ndimage.binary_dilation(inside | fringe, structure=np.ones((3, 3), bool))
    area = float(geometry.area)
    area_low = float(np.count_nonzero(eroded) * pa)
    area_high = float(np.count_nonzero(grown) * pa)

    abs_values = np.abs(values)
    ratio = abs_values / np.maximum(lod[finite], 1e-9)
    area_sigma = float(np.sqrt(np.mean(sigmas**2))) if sigmas.size else 0.0
    mean_z = (
        float(abs(values.mean()) / (area_sigma * rasters.model.mean_error_factor(area)))
        if values.size and area_sigma > 0
        else 0.0
    )
    kind, object_share, ground_share = _kind(rasters, win, inside, significant, dh, lod, options)
    cause = _object_cause(object_share, options) if kind == SURFACE_CHANGE else None
    if kind == LANDSLIDE and _vegetation_cut(rasters, win, inside, dh, lod, options):
        kind, cause = SURFACE_CHANGE, VEGETATION_CUT
    ring = near & ~inside
    ring_significant = float(
        np.count_nonzero(ring & ((sig == LOSS) | (sig == GAIN))) / max(np.count_nonzero(ring), 1)
    )
    total = volume_loss + volume_gain
    traits = {
        "log_area_px": math.log(max(float(np.count_nonzero(inside)), 1.0)),
        "log_area_correlation": math.log(
            max(area, pa) / max(math.pi * (rasters.model.correlation_length_m / 2) ** 2, pa)
        ),
        "mean_lod_ratio": float(ratio.mean()) if ratio.size else 0.0,
        "p90_lod_ratio": float(np.percentile(ratio, 90)) if ratio.size else 0.0,
        "significant_share": float(
            np.count_nonzero(significant) / max(np.count_nonzero(finite), 1)
        ),
        "log_area_z": math.log1p(mean_z),
        "balance": abs(volume_loss - volume_gain) / total if total > 0 else 1.0,
        "sign_coherence": _sign_coherence(dh, significant),
        "object_share": object_share,
        "ground_motion_share": ground_share,
        "ring_significant_share": ring_significant,
        "log_elongation": math.log(_elongation(inside)),
        "downslope_alignment": _downslope_alignment(rasters, win, dh, significant),
        "edge_contrast": _edge_contrast(inside, dh, lod),
        "compactness": float(4 * math.pi * area / max(geometry.length, 1e-9) ** 2),
        "volume_z": max(
            volume_loss / loss_sigma if loss_sigma > 0 else 0.0,
            volume_gain / gain_sigma if gain_sigma > 0 else 0.0,
        ),
    }
    properties = {
        "area_m2": round(area, 2),
        "area_m2_ci95": [round(area_low, 2), round(max(area_high, area), 2)],
        "volume_loss_m3": round(volume_loss, 2),
        "volume_loss_m3_ci95": [
            round(max(volume_loss - loss_half, 0.0), 2),
            round(volume_loss + loss_half, 2),
        ],
        "volume_gain_m3": round(volume_gain, 2),
        "volume_gain_m3_ci95": [
            round(max(volume_gain - gain_half, 0.0), 2),
            round(volume_gain + gain_half, 2),
        ],
        "max_abs_dh_m": round(float(abs_values.max()) if abs_values.size else 0.0, 3),
        "lod_m": round(float(np.median(lod[finite])) if values.size else 0.0, 3),
    }
    return Region(geometry=geometry, properties=properties, traits=traits, kind=kind, cause=cause)


def region_detection(
    region: Region,
    crs: Any,
    score: float,
    method: str,
    model_version: str | None = None,
) -> tuple[dict[str, Any], DetectionProperties]:
    """The detection record of a region: its WGS84 geometry and its properties."""
    p = region.properties
    uncertainty = Uncertainty(
        area_m2_ci95=tuple(p["area_m2_ci95"]),
        volume_loss_m3_ci95=tuple(p["volume_loss_m3_ci95"]),
        volume_gain_m3_ci95=tuple(p["volume_gain_m3_ci95"]),
        lod_m=p["lod_m"],
    )
    properties = DetectionProperties(
        area_m2=p["area_m2"],
        volume_loss_m3=p["volume_loss_m3"],
        volume_gain_m3=p["volume_gain_m3"],
        max_abs_dh_m=p["max_abs_dh_m"],
        score=round(float(score), 3),
        method=method,
        model_version=model_version,
        uncertainty=uncertainty,
    )
    return to_wgs84_geojson(region.geometry, crs), properties


def _volume_sigma(model: ErrorModel, sigmas: np.ndarray, pixel_area: float) -> float:
    """sigma of a sum of dh over these pixels times the pixel area, errors correlated."""
    if sigmas.size == 0:
        return 0.0
    area = sigmas.size * pixel_area
    rms = float(np.sqrt(np.mean(np.square(sigmas))))
    return area * rms * model.mean_error_factor(area)


def _kind(
    rasters: ChangeRasters,
    win: tuple[slice, slice],
    inside: np.ndarray,
    significant: np.ndarray,
    dh: np.ndarray,
    lod: np.ndarray,
    options: RegionOptions,
) -> tuple[str, float, float]:
    if rasters.pre is None or rasters.post is None:
        return LANDSLIDE, 0.0, 1.0
    vanished, appeared = (a[win] for a in rasters.objects(options))
    on_object = (vanished & (dh < 0)) | (appeared & (dh > 0))
    n_sig = max(np.count_nonzero(significant), 1)
    # The scorer's trait stays the share on the objects themselves, as it was fitted on.
    object_share = float(np.count_nonzero(on_object & significant) / n_sig)
    # Object margins (a crown's low flanks, a wall's foot) are not ground.
    objects = ndimage.binary_dilation(vanished | appeared, iterations=2)
    edges = objects & displaced_edges(rasters.pre[win], dh, lod)
    edge_share = float(np.count_nonzero((on_object | edges) & significant) / n_sig)
    # Ground motion: significant change on the bare ground (no object in either survey)
    # in and around the region. A felled tree leaves the ground around it unmoved; a
    # forested slide moves the ground between its trees.
    around = ndimage.binary_dilation(inside, iterations=3)
    ground = around & ~objects & np.isfinite(dh)
    n_ground = max(np.count_nonzero(ground), 1)
    with np.errstate(invalid="ignore"):
        beyond_lod = ground & (np.abs(dh) > lod)
        moved = ground & (np.abs(dh) > options.ground_motion_lod_ratio * lod)
    # The scorer's trait stays the share beyond the LoD itself, as it was fitted on.
    ground_share = float(np.count_nonzero(beyond_lod) / n_ground)
    moved_share = float(np.count_nonzero(moved) / n_ground)
    if edge_share >= options.object_fraction and moved_share < options.ground_motion_fraction:
        return SURFACE_CHANGE, object_share, ground_share
    return LANDSLIDE, object_share, ground_share


def _object_cause(object_share: float, options: RegionOptions) -> str:
    """Why the object rule set a region aside: objects that appeared or vanished, or
    (when those alone are too few) objects' edges moved a fraction of a pixel."""
    return OBJECTS if object_share >= options.object_fraction else DISPLACED_EDGES


def displaced_edges(pre: np.ndarray, dh: np.ndarray, lod: np.ndarray) -> np.ndarray:
    """Pixels whose change a displacement of at most one pixel explains: each survey's
    height lies, within the LoD, in the range the other holds over the pixel's 3 x 3
    neighbourhood. At a wall or a crown's edge a few metres of height change between
    neighbouring pixels, so a sub-pixel registration error or the blur of resampling
    changes the edge's pixels by metres (urban-rockfall seed 1000's twin: a 10 m wall,
    -1.5 m on one side and +1.8 m on the other after the rotation's correction), which
    the LoD, learnt on ground, reads as significant. Ground that moved lies outside that
    range: a scar below the lowest of its neighbours before, a deposit above the highest."""
    post = pre + dh
    valid = np.isfinite(post)

    def local_range(surface: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # Missing pixels take no part in the range (NaN would spread over the window).
        return (
            ndimage.minimum_filter(np.where(valid, surface, np.inf), size=3),
            ndimage.maximum_filter(np.where(valid, surface, -np.inf), size=3),
        )

    (pre_low, pre_high), (post_low, post_high) = local_range(pre), local_range(post)
    with np.errstate(invalid="ignore"):
        return (
            valid
            & (post >= pre_low - lod)
            & (post <= pre_high + lod)
            & (pre >= post_low - lod)
            & (pre <= post_high + lod)
        )


def _vegetation_cut(
    rasters: ChangeRasters,
    win: tuple[slice, slice],
    inside: np.ndarray,
    dh: np.ndarray,
    lod: np.ndarray,
    options: RegionOptions,
) -> bool:
    """Whether the region (`inside`, with its `dh` and `lod`, on window `win`) is low
    vegetation cut (vegetation_cut.py) with no significant gain; its texture is measured
    on a window reaching three blur widths beyond it."""
    if not options.vegetation_cut or rasters.pre is None or rasters.post is None:
        return False
    # Grass tufts are resolved only where a pixel is no larger than the texture's scale.
    if rasters.pixel_size > options.cut_texture_m:
        return False
    # Low vegetation only: where trees or buildings stand, the object rule judges.
    vanished, appeared = (a[win] for a in rasters.objects(options))
    if np.count_nonzero(
        (vanished | appeared) & inside
    ) > options.cut_object_share * np.count_nonzero(inside):
        return False
    if _has_deposit(rasters, inside, dh, lod, options):
        return False
    pad = math.ceil(3 * max(options.cut_texture_m / rasters.pixel_size, 1.0)) + 1
    wide = _padded(win, rasters.dh.shape, pad)
    placed = np.zeros((wide[0].stop - wide[0].start, wide[1].stop - wide[1].start), bool)
    r0, c0 = win[0].start - wide[0].start, win[1].start - wide[1].start
    placed[r0 : r0 + inside.shape[0], c0 : c0 + inside.shape[1]] = inside
    texture = cut_texture(
        rasters.pre[wide],
        rasters.post[wide],
        rasters.dh[wide],
        placed,
        rasters.pixel_size,
        options.cut_texture_m,
    )
    return is_vegetation_cut(
        texture,
        options.cut_new_texture_ratio,
        options.cut_depth_texture_ratio,
        options.cut_gain_share,
        options.object_height_m,
    )


def _has_deposit(
    rasters: ChangeRasters,
    inside: np.ndarray,
    dh: np.ndarray,
    lod: np.ndarray,
    options: RegionOptions,
) -> bool:
    """Whether the region holds a deposit: significant gain, cleaned of speckle, in one
    piece of the minimum region's size that holds `cut_inner_deposit_share` of the
    region's loss (a slide's toe inside the mown patch its scar merged with; specks of
    gain the errors leave in a mown patch hold a hundredth of its loss or less)."""
    with np.errstate(invalid="ignore"):
        gain = inside & (dh > lod)
    if not gain.any():
        return False
    gain = clean_mask(gain, replace(options, closing_px=0))
    pieces, count = ndimage.label(gain, structure=np.ones((3, 3), dtype=bool))
    if count == 0:
        return False
    index = np.arange(1, count + 1)
    sizes = ndimage.sum_labels(gain, pieces, index) * rasters.pixel_area
    volumes = ndimage.sum_labels(np.where(gain, dh, 0.0), pieces, index) * rasters.pixel_area
    loss = float(-dh[inside & (dh < 0)].sum()) * rasters.pixel_area
    large = sizes >= min_area_m2(rasters, options)
    return bool(np.any(volumes[large] >= options.cut_inner_deposit_share * loss))


def _downslope_alignment(
    rasters: ChangeRasters, win: tuple[slice, slice], dh: np.ndarray, significant: np.ndarray
) -> float:
    """Cosine between the loss-to-gain direction and the region's downslope direction.

    A landslide takes material from its head and lays it down below: the gain lies
    downslope of the loss (near 1). Misregistration and objects put loss and gain side
    by side in any direction.
    """
    surface = rasters.pre if rasters.pre is not None else None
    loss = significant & (dh < 0)
    gain = significant & (dh > 0)
    if surface is None or not loss.any() or not gain.any():
        return 0.0
    part = surface[win]
    if not np.isfinite(part).any():
        return 0.0
    filled = np.where(np.isfinite(part), part, np.nanmean(part))
    gy, gx = np.gradient(filled.astype(np.float64))
    both = loss | gain
    # Rows grow southwards; downslope is minus the gradient.
    down = -np.array([gy[both].mean(), gx[both].mean()])
    rows, cols = np.indices(dh.shape)
    move = np.array([rows[gain].mean() - rows[loss].mean(), cols[gain].mean() - cols[loss].mean()])
    norm = float(np.linalg.norm(down) * np.linalg.norm(move))
    return float(down @ move / norm) if norm > 0 else 0.0


def _edge_contrast(inside: np.ndarray, dh: np.ndarray, lod: np.ndarray) -> float:
    """log of |dh| / LoD just inside the region's edge over just outside it.

    A scarp or a deposit's front is a sharp edge; a patch of correlated error cut out by
    the threshold fades across it (about 1 in and 1 out).
    """
    structure = np.ones((3, 3), bool)
    inner = inside & ~ndimage.binary_erosion(inside, structure=structure, iterations=2)
    outer = ndimage.binary_dilation(inside, structure=structure, iterations=2) & ~inside
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.abs(dh) / lod
    inner_values = ratio[inner & np.isfinite(ratio)]
    outer_values = ratio[outer & np.isfinite(ratio)]
    if inner_values.size == 0 or outer_values.size == 0:
        return 0.0
    return float(math.log((np.median(inner_values) + 0.1) / (np.median(outer_values) + 0.1)))


def _sign_coherence(dh: np.ndarray, significant: np.ndarray) -> float:
    values = dh[significant]
    if values.size == 0:
        return 0.0
    return float(max(np.count_nonzero(values < 0), np.count_nonzero(values > 0)) / values.size)


def _elongation(inside: np.ndarray) -> float:
    rows, cols = np.nonzero(inside)
    if rows.size < 3:
        return 1.0
    cov = np.cov(np.vstack([rows, cols]).astype(float))
    eig = np.sort(np.linalg.eigvalsh(cov))
    return float(math.sqrt(max(eig[1], 1e-9) / max(eig[0], 0.25 / 12)))


def _local_ground(dsm: np.ndarray, pixel_size: float, width_m: float) -> np.ndarray:
    """The ground under tall objects: a grey opening wider than them (coarsened if wide)."""
    valid = np.isfinite(dsm)
    if not valid.any():
        return dsm
    filled = np.where(valid, dsm, np.nanmax(dsm))
    width_px = max(round(width_m / pixel_size), 3)
    factor = max(width_px // 15, 1)
    if factor > 1:
        h, w = filled.shape
        ph, pw = (-h) % factor, (-w) % factor
        padded = np.pad(filled, ((0, ph), (0, pw)), mode="edge")
        coarse = padded.reshape(padded.shape[0] // factor, factor, -1, factor).min(axis=(1, 3))
        opened = ndimage.grey_opening(coarse, size=(15, 15), mode="nearest")
        ground = np.repeat(np.repeat(opened, factor, axis=0), factor, axis=1)[:h, :w]
    else:
        ground = ndimage.grey_opening(filled, size=(width_px, width_px), mode="nearest")
    return np.where(valid, ground, np.nan).astype(np.float32)


def _tag_lod(tags: dict[str, str], significance: np.ndarray, dh: np.ndarray) -> float:
    """The LoD the difference stage wrote, else the smallest significant |dh|."""
    if tags.get("LOD_M"):
        return float(tags["LOD_M"])
    significant = (significance == LOSS) | (significance == GAIN)
    if not significant.any():
        return 0.0
    return float(np.nanmin(np.abs(dh[significant])))
