"""Dataset creation exactly as the paper: 42-pixel patches, stride 10, the 10 % rule.

Layout of one patch (pixel rows and columns of the DSM grid; the same for both axes):

    patch origin (r, c)        top-left pixel of the 42 x 42 window
    window                     rows r .. r+41, cols c .. c+41
    margin                     5 pixels on each side: rows r .. r+4 and r+37 .. r+41
    centre (the 32-pixel cell) rows r+5 .. r+36, cols c+5 .. c+36

Origins run r = 0, 10, 20, ... while r + 42 <= height (likewise for columns), so every
window lies wholly inside the raster; the last rows/columns that do not fill a stride are
not covered by a centre. The margin is what the loose training crops into: shifting the
32-pixel crop of the pre patch by up to 5 pixels either way stays inside the window.

Label: 1 when MORE than 10 % of the 32 x 32 centre is landslide in the truth mask
(strictly: count > 0.10 * 1024, i.e. at least 103 pixels), else 0.

A patch is usable only when its whole 42 x 42 window has elevations in both DSMs and a
defined mask (mask nodata is 255): nodata is never labelled, and never a landslide.

Classes are balanced as in the paper (1561 patches per class there): every patch of the
minority class is kept and the majority class is subsampled at random (seeded) to the
same count.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

PATCH_PX = 42
CORE_PX = 32
MARGIN_PX = (PATCH_PX - CORE_PX) // 2  # 5 on each side
STRIDE_PX = 10
LABEL_FRACTION = 0.10
MASK_NODATA = 255


@dataclass
class PatchSet:
    """Patches of one or more DSM pairs. Arrays share their first dimension."""

    pre: np.ndarray  # (N, 42, 42) float32 metres
    post: np.ndarray  # (N, 42, 42) float32 metres
    labels: np.ndarray  # (N,) uint8
    fraction: np.ndarray  # (N,) float32, landslide share of the centre
    rows: np.ndarray  # (N,) int32 patch origins
    cols: np.ndarray  # (N,) int32
    pixel_size_m: np.ndarray  # (N,) float32
    group: np.ndarray  # (N,) int16: index into `groups`
    groups: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return int(self.labels.shape[0])

    def subset(self, index: np.ndarray) -> PatchSet:
        return PatchSet(
            pre=self.pre[index],
            post=self.post[index],
            labels=self.labels[index],
            fraction=self.fraction[index],
            rows=self.rows[index],
            cols=self.cols[index],
            pixel_size_m=self.pixel_size_m[index],
            group=self.group[index],
            groups=list(self.groups),
        )

    @staticmethod
    def concat(sets: list[PatchSet]) -> PatchSet:
        groups: list[str] = []
        remapped = []
        for s in sets:
            mapping = []
            for name in s.groups:
                if name not in groups:
                    groups.append(name)
                mapping.append(groups.index(name))
            lookup = np.asarray(mapping or [0], dtype=np.int16)
            remapped.append(lookup[s.group] if len(s) else s.group)
        return PatchSet(
            pre=np.concatenate([s.pre for s in sets]),
            post=np.concatenate([s.post for s in sets]),
            labels=np.concatenate([s.labels for s in sets]),
            fraction=np.concatenate([s.fraction for s in sets]),
            rows=np.concatenate([s.rows for s in sets]),
            cols=np.concatenate([s.cols for s in sets]),
            pixel_size_m=np.concatenate([s.pixel_size_m for s in sets]),
            group=np.concatenate(remapped).astype(np.int16),
            groups=groups,
        )


def patch_origins(
    shape: tuple[int, int], stride: int = STRIDE_PX, patch: int = PATCH_PX
) -> tuple[np.ndarray, np.ndarray]:
    """Row and column origins of the patch grid (1-D arrays): 0, stride, ... <= size - patch."""
    height, width = shape
    if height < patch or width < patch:
        return np.zeros(0, dtype=np.int32), np.zeros(0, dtype=np.int32)
    rows = np.arange(0, height - patch + 1, stride, dtype=np.int32)
    cols = np.arange(0, width - patch + 1, stride, dtype=np.int32)
    return rows, cols


def centre_crop(patches: np.ndarray) -> np.ndarray:
    """(..., 42, 42) -> (..., 32, 32): rows/cols 5..36, the centre the model sees."""
    return patches[..., MARGIN_PX : MARGIN_PX + CORE_PX, MARGIN_PX : MARGIN_PX + CORE_PX]


def window_sums(values: np.ndarray, rows: np.ndarray, cols: np.ndarray, size: int) -> np.ndarray:
    """Sum of `values` over the size x size windows with top-left corners rows x cols.

    Returns an array of shape (len(rows), len(cols)); uses an integral image (exact in
    float64 for counts).
    """
    integral = np.zeros((values.shape[0] + 1, values.shape[1] + 1), dtype=np.float64)
    integral[1:, 1:] = np.cumsum(np.cumsum(values, axis=0, dtype=np.float64), axis=1)
    r0, c0 = rows[:, None], cols[None, :]
    r1, c1 = r0 + size, c0 + size
    return integral[r1, c1] - integral[r0, c1] - integral[r1, c0] + integral[r0, c0]


def centre_fractions(
    mask: np.ndarray, rows: np.ndarray, cols: np.ndarray, margin: int = MARGIN_PX
) -> np.ndarray:
    """Share of landslide (mask == 1) in the 32 x 32 centre of each patch of the grid."""
    landslide = (mask == 1).astype(np.float64)
    sums = window_sums(landslide, rows + margin, cols + margin, CORE_PX)
    return (sums / float(CORE_PX * CORE_PX)).astype(np.float32)


def label_from_fraction(fraction: np.ndarray, threshold: float = LABEL_FRACTION) -> np.ndarray:
    """1 where the landslide share is strictly more than `threshold` (the paper's 10 %)."""
    count = np.rint(np.asarray(fraction, dtype=np.float64) * CORE_PX * CORE_PX)
    return (count > threshold * CORE_PX * CORE_PX).astype(np.uint8)


def centres_inside(region: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """(len(rows), len(cols)) bool: the patch's 32-pixel centre lies wholly in `region`."""
    outside = (np.asarray(region) == 0).astype(np.float64)
    return window_sums(outside, rows + MARGIN_PX, cols + MARGIN_PX, CORE_PX) == 0


def usable_windows(
    pre: np.ndarray,
    post: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    mask: np.ndarray | None = None,
    patch: int = PATCH_PX,
) -> np.ndarray:
    """(len(rows), len(cols)) bool: the whole window is valid in pre, post (and the mask)."""
    invalid = ~(np.isfinite(pre) & np.isfinite(post))
    if mask is not None:
        invalid |= mask == MASK_NODATA
    return window_sums(invalid.astype(np.float64), rows, cols, patch) == 0


def extract_patches(
    pre: np.ndarray,
    post: np.ndarray,
    mask: np.ndarray,
    pixel_size_m: float,
    stride: int = STRIDE_PX,
    region: np.ndarray | None = None,
    group: str = "",
) -> PatchSet:
    """Every usable patch of one pre/post/mask triple on the paper's grid.

    `region` (bool or 0/1 array on the grid) keeps only patches whose 32-pixel centre lies
    wholly inside it (how one mound is taken out as the test set). Patches are in
    row-major order of their origins.
    """
    if pre.shape != post.shape or pre.shape != mask.shape:
        raise ValueError("pre, post and mask must have the same shape")
    rows, cols = patch_origins(pre.shape, stride)
    if rows.size == 0 or cols.size == 0:
        return _empty(pixel_size_m, group)
    fraction = centre_fractions(mask, rows, cols)
    usable = usable_windows(pre, post, rows, cols, mask)
    if region is not None:
        usable &= centres_inside(region, rows, cols)
    ri, ci = np.nonzero(usable)
    origin_r, origin_c = rows[ri], cols[ci]
    offsets = np.arange(PATCH_PX)
    index_r = origin_r[:, None, None] + offsets[None, :, None]
    index_c = origin_c[:, None, None] + offsets[None, None, :]
    fractions = fraction[ri, ci]
    n = origin_r.size
    return PatchSet(
        pre=pre[index_r, index_c].astype(np.float32),
        post=post[index_r, index_c].astype(np.float32),
        labels=label_from_fraction(fractions),
        fraction=fractions.astype(np.float32),
        rows=origin_r.astype(np.int32),
        cols=origin_c.astype(np.int32),
        pixel_size_m=np.full(n, pixel_size_m, dtype=np.float32),
        group=np.zeros(n, dtype=np.int16),
        groups=[group],
    )


def balance_classes(labels: np.ndarray, seed: int = 0) -> np.ndarray:
    """Indices of a class-balanced subset: all of the minority class, an equal random
    (seeded) sample of the majority class; sorted."""
    labels = np.asarray(labels)
    positive = np.flatnonzero(labels == 1)
    negative = np.flatnonzero(labels == 0)
    count = min(positive.size, negative.size)
    rng = np.random.default_rng(seed)
    keep_pos = positive if positive.size == count else rng.choice(positive, count, replace=False)
    keep_neg = negative if negative.size == count else rng.choice(negative, count, replace=False)
    return np.sort(np.concatenate([keep_pos, keep_neg]))


def _empty(pixel_size_m: float, group: str) -> PatchSet:
    return PatchSet(
        pre=np.zeros((0, PATCH_PX, PATCH_PX), np.float32),
        post=np.zeros((0, PATCH_PX, PATCH_PX), np.float32),
        labels=np.zeros(0, np.uint8),
        fraction=np.zeros(0, np.float32),
        rows=np.zeros(0, np.int32),
        cols=np.zeros(0, np.int32),
        pixel_size_m=np.zeros(0, np.float32),
        group=np.zeros(0, np.int16),
        groups=[group],
    )
