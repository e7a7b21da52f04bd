"""Low vegetation cut between surveys (grass mown, a crop harvested): change, not landslide.

A mown patch lowers the surface by the height of the sward, often past the LoD over tens
of square metres, and nothing in its size or depth tells it from a shallow soil slip. What
does: the fine texture of the surface. Grass is rough at the scale of its tufts; the
stubble left after mowing is not. Over a mown patch the difference's fine texture is the
*pre* survey's (the tufts it lost) and owes nothing to the post survey's, while ground
that moved (a slump, a slip, a flow) carries its texture along or makes new relief, so
the difference takes texture from both surveys. With the DSMs high-passed at the scale of
tufts (`texture_m`), over a region's pixels:

- lost texture: -cov(dh, pre), the variance of what the pre surface had and the post lost;
- new texture: cov(dh, post), the variance of what the post surface has and the pre had not.

Relief the two surveys share (furrows, clods, the slope's own roughness) cancels in both,
whatever its size. A region is a vegetation cut when it is a loss (its gain a small share
of its volume), shallower than a tall object, its new texture well under its lost texture
(`new_texture_ratio`), and its depth within a few standard deviations of the texture it
lost (`depth_texture_ratio`): the sward's height, not a scar cut into the ground. A cut
within the context distance of a landslide region still joins it
(change_regions.split_surface_changes): a scar whose deposit lies beside it is a slide.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage


@dataclass(frozen=True)
class CutTexture:
    """A region's texture figures (m, m^2)."""

    depth_m: float  # median lowering over the region
    lost_var: float  # -cov(dh, pre) of the high-passed surfaces
    new_var: float  # cov(dh, post)
    gain_share: float  # gain volume over loss plus gain

    @property
    def new_texture_ratio(self) -> float:
        return self.new_var / self.lost_var if self.lost_var > 0 else math.inf

    @property
    def depth_texture_ratio(self) -> float:
        return self.depth_m / math.sqrt(self.lost_var) if self.lost_var > 0 else math.inf


def high_pass(surface: np.ndarray, pixel_size: float, texture_m: float) -> np.ndarray:
    """The surface minus its Gaussian blur at `texture_m` (at least one pixel); holes are
    filled with the window's median first and stay NaN."""
    valid = np.isfinite(surface)
    if not valid.any():
        return np.full(surface.shape, np.nan, dtype=np.float32)
    filled = np.where(valid, surface, np.median(surface[valid])).astype(np.float64)
    sigma = max(texture_m / pixel_size, 1.0)
    out = filled - ndimage.gaussian_filter(filled, sigma, mode="nearest")
    return np.where(valid, out, np.nan).astype(np.float32)


def cut_texture(
    pre: np.ndarray,
    post: np.ndarray,
    dh: np.ndarray,
    inside: np.ndarray,
    pixel_size: float,
    texture_m: float,
) -> CutTexture | None:
    """The texture figures of the region `inside` (all arrays on one window, which should
    reach a few `texture_m` beyond the region); None where it has too few pixels."""
    pre_hp = high_pass(pre, pixel_size, texture_m)
    post_hp = high_pass(post, pixel_size, texture_m)
    use = inside & np.isfinite(dh) & np.isfinite(pre_hp) & np.isfinite(post_hp)
    if np.count_nonzero(use) < 16:
        return None
    values = dh[use].astype(np.float64)
    loss = float(-values[values < 0].sum())
    gain = float(values[values > 0].sum())
    p = pre_hp[use].astype(np.float64)
    q = post_hp[use].astype(np.float64)
    d = q - p
    d -= d.mean()
    return CutTexture(
        depth_m=float(np.median(-values)),
        lost_var=float(-np.mean(d * (p - p.mean()))),
        new_var=float(np.mean(d * (q - q.mean()))),
        gain_share=gain / (loss + gain) if loss + gain > 0 else 0.0,
    )


def is_vegetation_cut(
    texture: CutTexture | None,
    new_texture_ratio: float,
    depth_texture_ratio: float,
    max_gain_share: float,
    max_depth_m: float,
) -> bool:
    """The rule of the module's doc on a region's figures."""
    if texture is None or texture.lost_var <= 0:
        return False
    return (
        texture.gain_share <= max_gain_share
        and 0.0 < texture.depth_m < max_depth_m
        and texture.new_texture_ratio < new_texture_ratio
        and texture.depth_texture_ratio < depth_texture_ratio
    )
