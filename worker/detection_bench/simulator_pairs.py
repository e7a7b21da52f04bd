"""The survey simulator's analytic DSM pairs as one more generator of the benchmark.

`worker/simulator/dsm_pair.py` makes the pairs of slidewatch's own tests: an analytic
surface (a regional slope, sinusoids, gaussian hills), one pit-and-lobe slide, white
noise, a shift and a tilt of the post survey. Drawn here with other settings per seed
(pixel size, noise, shift, tilt, slide size and depth), they are a generator no scorer
was fitted to. The twin is the same seed without the slide: the simulator draws the
terrain and the noise alike with or without it, so the slide's change is exactly the
difference of the two post DSMs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from worker.pairgen.pair import DsmPair, SlideTruth
from worker.simulator.dsm_pair import SlideSpec, make_dsm_pair

NAME = "simulator-analytic"


@dataclass(frozen=True)
class SimulatorPairs:
    name: str = NAME
    summary: str = (
        "The survey simulator's analytic pairs: sinusoid-and-hill slopes of 10-40 degrees, "
        "one pit-and-lobe slide 1-6 m deep, white noise 3-30 cm, a post shift up to 2 px "
        "and 0.5 m, a tilt up to 1 m/km, 0.2-1 m pixels."
    )

    def make(self, seed: int, no_change: bool = False) -> DsmPair:
        rng = np.random.default_rng([seed, 0x51A1])
        rows, cols = (int(v) for v in rng.integers(384, 641, size=2))
        pixel = float(rng.uniform(0.2, 1.0))
        shift = (
            float(rng.uniform(-2, 2) * pixel),
            float(rng.uniform(-2, 2) * pixel),
            float(rng.uniform(-0.5, 0.5)),
        )
        tilt = (float(rng.uniform(-1, 1)), float(rng.uniform(-1, 1)))
        noise = float(rng.uniform(0.03, 0.3))
        spec = SlideSpec(
            centre_frac=(float(rng.uniform(0.3, 0.7)), float(rng.uniform(0.3, 0.7))),
            depletion_semi_axes_frac=(
                float(rng.uniform(0.05, 0.12)),
                float(rng.uniform(0.04, 0.1)),
            ),
            deposit_semi_axes_frac=(float(rng.uniform(0.06, 0.14)), float(rng.uniform(0.05, 0.11))),
            depth_m=float(rng.uniform(1.0, 6.0)),
        )
        common = {
            "shape": (rows, cols),
            "pixel_size_m": pixel,
            "shift_m": shift,
            "noise_m": noise,
            "seed": seed,
            "tilt_m_per_km": tilt,
        }
        without = make_dsm_pair(slide=False, **common)
        pre, post = without.pre, without.post
        true_dh = np.zeros(pre.shape, np.float32)
        labels = np.zeros(pre.shape, np.int16)
        slides: list[SlideTruth] = []
        if not no_change:
            with_slide = make_dsm_pair(slide=spec, **common)
            post = with_slide.post
            true_dh = (with_slide.post - without.post).astype(np.float32)
            footprint = np.abs(true_dh) > 0.01
            labels[footprint] = 1
            area = pixel * pixel
            rr, cc = np.nonzero(footprint)
            slides.append(
                SlideTruth(
                    id=1,
                    kind="pit-and-lobe",
                    area_m2=float(footprint.sum() * area),
                    area_px=int(footprint.sum()),
                    volume_loss_m3=float(-true_dh[true_dh < 0].sum() * area),
                    volume_gain_m3=float(true_dh[true_dh > 0].sum() * area),
                    max_depth_m=float(np.abs(true_dh).max()),
                    length_m=float(max(np.ptp(rr), np.ptp(cc)) * pixel) if rr.size else 0.0,
                )
            )
        return DsmPair(
            generator=self.name,
            seed=seed,
            pixel_size=pixel,
            pre=pre,
            post=post,
            true_dh=true_dh,
            slide_labels=labels,
            slides=slides,
            surface_change=np.zeros(pre.shape, bool),
            observation_error=(post - pre - true_dh).astype(np.float32),
            no_change=no_change,
            description={
                "summary": self.summary,
                "noise_m": noise,
                "shift_m": shift,
                "tilt_m_per_km": tilt,
                "depth_m": spec.depth_m,
            },
        )
