"""Surface appearance: multi-scale noise, material albedo, sun shading and cast shadows.

The orthoimage a survey renders from is `albedo x shading`, computed once per survey
at DSM resolution. Ground albedo is static between steps (so unchanged ground looks
the same in every survey, apart from sun and exposure); landslide scars and deposits
get a disturbed-soil texture; tree crowns get per-tree tones and a leaf texture.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum

import cv2
import numpy as np

# Tree kinds (see vegetation.py) drawn by `compose_albedo`.
CONIFER, BROADLEAF, SHRUB, LOG, MODEL_TREE = 0, 1, 2, 3, 4


class Material(IntEnum):
    """Ground materials; values are stored in uint8 material maps."""

    SAND = 0
    GRASS = 1
    SOIL = 2
    ROCK = 3
    WATER = 4
    GRAVEL = 5
    FOREST_FLOOR = 6
    TARGET_BLACK = 7
    TARGET_WHITE = 8


# Base colours (sRGB, 0..255) and the strength of their texture.
_MATERIAL_RGB = {
    Material.SAND: (196, 178, 140),
    Material.GRASS: (96, 122, 58),
    Material.SOIL: (122, 98, 72),
    Material.ROCK: (132, 129, 121),
    Material.WATER: (64, 80, 78),
    Material.GRAVEL: (150, 144, 132),
    Material.FOREST_FLOOR: (88, 80, 56),
    Material.TARGET_BLACK: (28, 28, 28),
    Material.TARGET_WHITE: (236, 236, 232),
}
_MATERIAL_CONTRAST = {
    Material.SAND: 0.10,
    Material.GRASS: 0.22,
    Material.SOIL: 0.16,
    Material.ROCK: 0.20,
    Material.WATER: 0.05,
    Material.GRAVEL: 0.22,
    Material.FOREST_FLOOR: 0.25,
    Material.TARGET_BLACK: 0.02,
    Material.TARGET_WHITE: 0.02,
}
_TREE_RGB = {
    CONIFER: (44, 70, 40),
    BROADLEAF: (72, 104, 46),
    SHRUB: (88, 110, 52),
    LOG: (98, 88, 60),
    MODEL_TREE: (52, 92, 44),
}


def fbm(
    shape: tuple[int, int],
    rng: np.random.Generator,
    scales: Sequence[float],
    weights: Sequence[float] | None = None,
) -> np.ndarray:
    """Sum of smooth random fields with feature sizes `scales` (in cells), each of unit
    standard deviation times its weight. float32, deterministic for a given rng state."""
    h, w = shape
    out = np.zeros(shape, np.float32)
    weights = weights if weights is not None else [1.0] * len(scales)
    for s, wt in zip(scales, weights, strict=True):
        if s <= 1.0:
            layer = rng.standard_normal(shape, dtype=np.float32)
        else:
            gh = int(np.ceil(h / s)) + 3
            gw = int(np.ceil(w / s)) + 3
            coarse = rng.standard_normal((gh, gw), dtype=np.float32)
            big = cv2.resize(coarse, (round(gw * s), round(gh * s)), interpolation=cv2.INTER_CUBIC)
            oy = int(s)
            ox = int(s)
            layer = big[oy : oy + h, ox : ox + w]
            sd = float(layer.std())
            layer = layer / (sd if sd > 0 else 1.0)
        out += np.float32(wt) * layer
    return out


@dataclass(frozen=True)
class Sun:
    """Sun position for a survey: azimuth clockwise from north, elevation above horizon."""

    azimuth_deg: float
    elevation_deg: float

    @property
    def vector(self) -> np.ndarray:
        az, el = np.radians(self.azimuth_deg), np.radians(self.elevation_deg)
        return np.array([np.sin(az) * np.cos(el), np.cos(az) * np.cos(el), np.sin(el)])


def cast_shadows(dsm: np.ndarray, res: float, sun: Sun) -> np.ndarray:
    """Fraction of direct sunlight blocked at each cell (0 lit .. 1 shadowed).

    The DSM is rotated so that light comes from the top rows; a cell is in shadow when
    any cell before it along the light direction rises above the sun ray through it,
    which is a running maximum of h + distance * tan(elevation)."""
    h, w = dsm.shape
    centre = (w / 2.0, h / 2.0)
    m = cv2.getRotationMatrix2D(centre, sun.azimuth_deg, 1.0)
    cos, sin = abs(m[0, 0]), abs(m[0, 1])
    nw, nh = int(np.ceil(h * sin + w * cos)) + 2, int(np.ceil(h * cos + w * sin)) + 2
    m[0, 2] += nw / 2.0 - centre[0]
    m[1, 2] += nh / 2.0 - centre[1]
    low = float(dsm.min()) - 1e4
    rot = cv2.warpAffine(
        dsm.astype(np.float32),
        m,
        (nw, nh),
        flags=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=low,
    ).astype(np.float64)
    k = res * np.tan(np.radians(sun.elevation_deg))
    g = rot + (np.arange(nh, dtype=np.float64) * k)[:, None]
    # Running maximum down the rows, one whole row per step: the values of
    # np.maximum.accumulate(g, axis=0), which took 3x as long on these arrays.
    run = np.empty_like(g)
    run[0] = g[0]
    for i in range(1, nh):
        np.maximum(run[i - 1], g[i], out=run[i])
    shadow_rot = (run > g + 0.5 * k + 1e-4).astype(np.float32)
    inv = cv2.invertAffineTransform(m)
    shadow = cv2.warpAffine(
        shadow_rot,
        inv,
        (w, h),
        flags=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0.0,
    )
    return cv2.GaussianBlur(shadow, (0, 0), 0.8)


def shading(dsm: np.ndarray, res: float, sun: Sun, ambient: float = 0.38) -> np.ndarray:
    """Lambertian sun shading with cast shadows and sky light; flat sunlit ground is 1."""
    gy, gx = np.gradient(dsm.astype(np.float32), np.float32(res))
    # Rows run south: dz/dnorth = -gy.
    nx, ny, nz = -gx, gy, np.ones_like(gx)
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    s = sun.vector.astype(np.float32)
    lambert = np.clip((nx * s[0] + ny * s[1] + nz * s[2]) / norm, 0, 1)
    direct = lambert * (1.0 - cast_shadows(dsm, res, sun))
    sky = 0.55 + 0.45 * (nz / norm)
    return (ambient * sky + (1 - ambient) * direct / np.float32(s[2])).astype(np.float32)


@dataclass
class TextureBank:
    """Static noise fields of a scene (one per texture role), made once per scenario."""

    coarse: np.ndarray
    medium: np.ndarray
    fine: np.ndarray
    grain: np.ndarray
    leaf: np.ndarray
    disturbed: np.ndarray

    @classmethod
    def make(cls, shape: tuple[int, int], res: float, rng: np.random.Generator) -> TextureBank:
        """Noise at fixed physical sizes: coarse ~ 4 m, medium ~ 0.6 m, fine ~ 8 cm,
        grain = one cell; `leaf` for crowns; `disturbed` for landslide material."""

        def cells(metres: float) -> float:
            return max(1.0, metres / res)

        coarse = fbm(shape, rng, [cells(12.0), cells(4.0)], [0.6, 0.4])
        medium = fbm(shape, rng, [cells(1.5), cells(0.6)], [0.5, 0.5])
        fine = fbm(shape, rng, [cells(0.2), cells(0.08)], [0.6, 0.4])
        grain = rng.standard_normal(shape, dtype=np.float32)
        leaf = fbm(shape, rng, [cells(0.9), cells(0.3), 1.0], [0.4, 0.4, 0.2])
        disturbed = fbm(shape, rng, [cells(2.0), cells(0.4), cells(0.1)], [0.4, 0.35, 0.25])
        return cls(coarse, medium, fine, grain, leaf, disturbed)


def ground_albedo(
    material: np.ndarray, bank: TextureBank, res: float, contrast: float = 1.0
) -> np.ndarray:
    """Albedo (0..1, float32, HxWx3) of the bare ground and low vegetation. `contrast`
    scales every variation of the ground around its material's colour (texture, grass
    patches, pebbles): below 1 a texture-poor field such as freshly mown grass, whose
    local contrast in the images falls by about that factor."""
    h, w = material.shape
    out = np.zeros((h, w, 3), np.float32)
    # Grain matters only where cells are a few centimetres; at coarse resolution it
    # would be pixel noise, so it fades out.
    grain_w = float(np.clip(0.05 / max(res, 1e-3), 0.15, 1.0))
    for mat, rgb in _MATERIAL_RGB.items():
        sel = material == mat
        if not sel.any():
            continue
        c = _MATERIAL_CONTRAST[mat] * contrast
        tex = (
            0.35 * bank.coarse[sel]
            + 0.3 * bank.medium[sel]
            + 0.25 * bank.fine[sel]
            + 0.25 * grain_w * bank.grain[sel]
        )
        base = np.asarray(rgb, np.float32) / 255.0
        val = base[None, :] * (1.0 + c * tex)[:, None]
        if mat == Material.GRASS:
            # Yellowish and dark patches.
            yell = np.clip(bank.medium[sel] * 0.5 + bank.coarse[sel] * 0.5, -1, 1)[:, None]
            val = val + 0.05 * contrast * yell * np.array([0.9, 0.5, -0.1], np.float32)[None, :]
        if mat == Material.SAND:
            # Sparse darker pebbles and lighter dry grains.
            peb = bank.grain[sel] > 2.3
            val[peb] *= 1.0 - 0.28 * contrast
        out[sel] = val
    return np.clip(out, 0.0, 1.0)


def disturbed_albedo(
    base: np.ndarray, bank: TextureBank, depth: np.ndarray, sand_like: np.ndarray
) -> np.ndarray:
    """Albedo of freshly moved material where `depth` (m of change, >0) is non-zero:
    moist darker sand on the sandy parts, brown soil with lumps elsewhere."""
    sel = depth > 0
    if not sel.any():
        return base
    out = base.copy()
    t = bank.disturbed[sel]
    sand = sand_like[sel]
    sand_rgb = np.array([172, 150, 112], np.float32) / 255.0
    soil_rgb = np.array([112, 88, 64], np.float32) / 255.0
    rgb = np.where(sand[:, None], sand_rgb[None, :], soil_rgb[None, :])
    contrast = np.where(sand, 0.2, 0.26)[:, None]
    lumps = np.clip(bank.grain[sel] * 0.5 + bank.fine[sel] * 0.5, -2.5, 2.5)[:, None]
    val = rgb * (1.0 + contrast * (0.4 * t[:, None] + 0.6 * lumps))
    # Thin changes blend with what was there.
    a = np.clip(depth[sel] / 0.03, 0.0, 1.0)[:, None]
    out[sel] = (1 - a) * out[sel] + a * val
    return np.clip(out, 0.0, 1.0)


def tree_albedo(
    base: np.ndarray,
    bank: TextureBank,
    tree_index: np.ndarray,
    kinds: np.ndarray,
    tones: np.ndarray,
    radial: np.ndarray,
) -> np.ndarray:
    """Draw crowns over `base` where `tree_index` >= 0. `radial` is the normalised
    distance from the crown centre (0 centre .. 1 edge) for a darker rim."""
    sel = tree_index >= 0
    if not sel.any():
        return base
    out = base.copy()
    ti = tree_index[sel]
    kind = kinds[ti]
    rgb = np.zeros((ti.size, 3), np.float32)
    for k, c in _TREE_RGB.items():
        rgb[kind == k] = np.asarray(c, np.float32) / 255.0
    tone = tones[ti][:, None]
    leaf = bank.leaf[sel][:, None]
    rim = 1.0 - 0.25 * np.clip(radial[sel], 0, 1)[:, None] ** 2
    val = rgb * (1.0 + tone) * (1.0 + 0.28 * leaf) * rim
    out[sel] = val
    return np.clip(out, 0.0, 1.0)


@dataclass(frozen=True)
class Exposure:
    """Camera exposure differences between surveys: gain and white balance."""

    gain: float = 1.0
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def to_dict(self) -> dict:
        return {
            "gain": round(self.gain, 4),
            "white_balance": [round(x, 4) for x in self.white_balance],
        }


def orthoimage(albedo: np.ndarray, shade: np.ndarray, exposure: Exposure) -> np.ndarray:
    """The uint8 RGB orthoimage a survey is rendered from."""
    wb = np.asarray(exposure.white_balance, np.float32) * np.float32(exposure.gain * 255.0)
    img = albedo * shade[..., None] * wb[None, None, :]
    # Gentle highlight roll-off instead of hard clipping.
    img = np.where(img > 220, 220 + (img - 220) * 0.4, img)
    return np.clip(img + 0.5, 0, 255).astype(np.uint8)
