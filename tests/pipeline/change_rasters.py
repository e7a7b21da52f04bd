"""Change rasters made in memory for the region tests: dh, its LoD, and the significance
mask they give, on a UTM grid."""

import numpy as np
from rasterio.transform import from_origin

from worker.pipeline.change_regions import ChangeRasters
from worker.pipeline.difference import GAIN, LOSS
from worker.pipeline.error_model import LOD_Z, ErrorModel, VariogramModel


def change_rasters(
    dh: np.ndarray,
    lod: np.ndarray,
    model: ErrorModel,
    pixel_size: float,
    pre: np.ndarray | None = None,
    post: np.ndarray | None = None,
) -> ChangeRasters:
    """`dh` centred on stable ground; significant where |dh| exceeds `lod`."""
    significance = np.zeros(dh.shape, np.uint8)
    significance[dh < -lod] = LOSS
    significance[dh > lod] = GAIN
    return ChangeRasters(
        dh=dh,
        lod=lod,
        significance=significance,
        transform=from_origin(500000, 4000000, pixel_size, pixel_size),
        crs="EPSG:32654",
        model=model,
        pre=pre,
        post=post,
    )


def uniform_error_model(pixel_size: float, sigma: float, pixels: int) -> ErrorModel:
    """One sigma everywhere, errors uncorrelated."""
    return ErrorModel(
        pixel_size=pixel_size,
        slope_centres_deg=[0.0],
        curvature_centres=[0.0],
        sigma_table=[[sigma]],
        median_dh_m=0.0,
        nmad_m=sigma,
        stable_pixels=pixels,
        variogram=VariogramModel(nugget=1.0, ranges_m=[], psills=[]),
    )


def uniform_change_rasters(
    pre: np.ndarray, post: np.ndarray, pixel_size: float, sigma: float
) -> ChangeRasters:
    """The change between two DSMs under one sigma everywhere (errors uncorrelated)."""
    model = uniform_error_model(pixel_size, sigma, pre.size)
    lod = np.full(pre.shape, LOD_Z * sigma, np.float32)
    dh = (post - pre).astype(np.float32)
    return change_rasters(
        dh, lod, model, pixel_size, pre.astype(np.float32), post.astype(np.float32)
    )
