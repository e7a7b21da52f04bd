"""Random landslides on the hillslope: training data that is not the scenario's own.

The hillslope scenario's two slides (the deep-seated slide at x = 25 m and the bank
slump at x = -95 m) are test data. `random_hillslope_slides` draws slides of random
place, size, depth and runout elsewhere on the slope: toes in HILLSLOPE_TRAINING_X,
40-200 m above the stream, moving downslope. Each candidate is tried on the ground as
the earlier ones left it (as `evolution.advance` applies them), and dropped when it
does not fit.
"""

from __future__ import annotations

import numpy as np

from worker.simulator.landslide import SlideSpec, apply_slide
from worker.simulator.terrain import Scene, stream_y

# Where random slides may be placed (local x, metres): away from the scenario's own.
HILLSLOPE_TRAINING_X = ((-195.0, -150.0), (85.0, 190.0))
MAX_TRIES = 200


def random_hillslope_slides(
    scene: Scene, rng: np.random.Generator, n_slides: int
) -> list[SlideSpec]:
    """Up to `n_slides` random slides that fit on `scene` one after the other."""
    ground = scene.ground.copy()
    slides: list[SlideSpec] = []
    tries = 0
    while len(slides) < n_slides and tries < MAX_TRIES:
        tries += 1
        lo, hi = HILLSLOPE_TRAINING_X[int(rng.integers(len(HILLSLOPE_TRAINING_X)))]
        x = float(rng.uniform(lo, hi))
        length = float(rng.uniform(12.0, 55.0))
        candidate = SlideSpec(
            name=f"train-{len(slides) + 1}",
            label="random training slide",
            toe_xy=(x, float(stream_y(x)) + float(rng.uniform(40.0, 200.0))),
            azimuth_deg=float(rng.uniform(165.0, 195.0)),
            length_m=length,
            width_m=float(rng.uniform(0.5, 1.0)) * length,
            failure_angle_deg=float(rng.uniform(18.0, 27.0)),
            head_angle_deg=float(rng.uniform(45.0, 55.0)),
            flank_angle_deg=float(rng.uniform(38.0, 45.0)),
            runout_m=float(rng.uniform(0.3, 1.2)) * length,
            deposit_angle_deg=float(rng.uniform(5.0, 14.0)),
            deposit_spread=float(rng.uniform(0.6, 0.8)),
            roughness=0.05,
        )
        try:
            result = apply_slide(
                ground, scene.grid, candidate, np.random.default_rng(0), scene.floor
            )
        except ValueError:
            continue
        ground[result.rows, result.cols] += result.delta
        slides.append(candidate)
    return slides
