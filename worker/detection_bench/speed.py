"""Detection speed of the `scored` and `threshold` methods: km2 per minute at 20 cm.

The pair is the survey simulator's analytic DSM pair (worker/simulator/dsm_pair.py) of
`size` x `size` pixels at 20 cm (5000: 1 km2) with one slide, already on one grid, so
the figure is that of the detection itself: the difference stage (error model, per-pixel
LoD) plus the method's last stage (score or vectorize). Alignment and co-registration
are the same for every method and are timed by the comparison benchmark.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

PIXEL_M = 0.2


def detection_speed(work_dir: Path, size: int = 5000) -> dict[str, Any]:
    """Seconds and km2/min of difference + score and of difference + vectorize."""
    import rasterio

    from worker.pipeline.difference import difference
    from worker.pipeline.raster_io import write_geotiff
    from worker.pipeline.scoring import score_candidates
    from worker.pipeline.vectorize import vectorize
    from worker.simulator.dsm_pair import make_dsm_pair

    work = Path(work_dir) / "speed"
    work.mkdir(parents=True, exist_ok=True)
    pair = make_dsm_pair((size, size), PIXEL_M, (0.0, 0.0, 0.0), True, 0.05, seed=5)
    crs = rasterio.crs.CRS.from_user_input(pair.crs)
    pre, post = work / "pre_aligned.tif", work / "post_coregistered.tif"
    write_geotiff(pre, pair.pre, pair.transform, crs)
    write_geotiff(post, pair.post, pair.transform, crs)
    del pair
    area_km2 = size * size * PIXEL_M**2 / 1e6
    t0 = time.perf_counter()
    difference(pre, post, work / "dh.tif", work / "significance.tif")
    difference_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    scored = score_candidates(
        work / "dh.tif", work / "significance.tif", pre, post, work / "scored.geojson"
    )
    score_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    vectorize(
        work / "dh.tif",
        work / "significance.tif",
        work / "threshold.geojson",
        pre_path=pre,
        post_path=post,
    )
    vectorize_s = time.perf_counter() - t0
    return {
        "pixel_m": PIXEL_M,
        "size_px": size,
        "area_km2": area_km2,
        "difference_s": round(difference_s, 2),
        "score_s": round(score_s, 2),
        "vectorize_s": round(vectorize_s, 2),
        "scored_km2_per_min": round(area_km2 / ((difference_s + score_s) / 60), 2),
        "threshold_km2_per_min": round(area_km2 / ((difference_s + vectorize_s) / 60), 2),
        "scored_detections": scored.detections,
    }
