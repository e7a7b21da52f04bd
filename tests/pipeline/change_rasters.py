"""Change rasters made in memory for the region tests: dh, its LoD, and the significance
mask they give, on a UTM grid."""

import numpy as np
from rasterio.transform import from_origin

from worker.pipeline.change_regions import ChangeRasters
from worker.pipeline.difference import GAIN, LOSS
from worker.pipeline.error_model import ErrorModel


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
