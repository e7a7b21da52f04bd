"""How close is the interim reconstruction-noise model to slidewatch's reconstruction?

Usage: .venv/bin/python benchmarks/recon_noise_check.py TRUTH.tif RECONSTRUCTED.tif WORK_DIR

TRUTH.tif is a simulator truth DSM (e.g. step1/truth/dsm.tif of `slidewatch simulate`),
RECONSTRUCTED.tif the DSM that `slidewatch reconstruct` (or `slidewatch bench
reconstruction`) made from the same survey's video. Both are compared with the threshold
comparison (align + co-registration, as the detector sees them), and so is the truth DSM
degraded by worker/training/recon_noise.py: NMAD and tails of Δh for each.
"""

import sys
from pathlib import Path

import numpy as np

from worker.pipeline.comparison import ComparisonOptions, compare_dsms
from worker.pipeline.raster_io import read_elevation, write_geotiff
from worker.training.recon_noise import degrade


def error_stats(truth: Path, post: Path, work: Path, label: str) -> None:
    result = compare_dsms(truth, post, work, ComparisonOptions(method="threshold"))
    dh, _ = read_elevation(work / "dh.tif")
    e = dh[np.isfinite(dh)]
    e = e - np.median(e)
    c = result.results["coregister"]
    print(
        f"{label}: {e.size} pixels, co-registration shift "
        f"{c['shift_east_m']:.2f} / {c['shift_north_m']:.2f} / {c['shift_up_m']:.2f} m, "
        f"NMAD {1.4826 * np.median(np.abs(e)) * 100:.1f} cm, "
        f"|dh| > 20 cm {np.mean(np.abs(e) > 0.2) * 100:.2f} %, "
        f"> 30 cm {np.mean(np.abs(e) > 0.3) * 100:.2f} %, "
        f"p99 {np.percentile(np.abs(e), 99) * 100:.1f} cm"
    )


def main(argv: list[str]) -> None:
    truth, reconstructed, work = Path(argv[0]), Path(argv[1]), Path(argv[2])
    error_stats(truth, reconstructed, work / "reconstruction", "reconstruction")
    z, profile = read_elevation(truth)
    degraded = degrade(z, abs(profile["transform"].a), np.random.default_rng(0))
    write_geotiff(work / "degraded.tif", degraded, profile["transform"], profile["crs"])
    error_stats(truth, work / "degraded.tif", work / "recon_noise", "recon_noise")


if __name__ == "__main__":
    main(sys.argv[1:])
