"""A tiny hand-made pair generator for the detection benchmark's tests.

256 x 256 pixels at 0.2 m: a tilted slope with gentle bumps (co-registration needs
relief), one elliptic slide 3 m deep with steep walls, 5 cm of noise in each DSM. The
no-change twin has the same terrain and noise and no slide.
"""

from __future__ import annotations

import numpy as np

from worker.pairgen.pair import DsmPair, SlideTruth

SIZE, PIXEL = 256, 0.2
SLIDE_CENTRE, SLIDE_AXES = (128, 120), (40, 30)  # rows, cols; semi-axes in pixels


def tiny_pair(seed: int, no_change: bool = False) -> DsmPair:
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:SIZE, 0:SIZE].astype(np.float32) * PIXEL
    ground = 100 + 0.25 * rows + 0.1 * cols + 0.4 * np.sin(cols / 3) * np.cos(rows / 4)
    err_pre = rng.normal(0, 0.05, ground.shape)
    err_post = rng.normal(0, 0.05, ground.shape)
    r, c = np.mgrid[0:SIZE, 0:SIZE]
    q = ((r - SLIDE_CENTRE[0]) / SLIDE_AXES[0]) ** 2 + ((c - SLIDE_CENTRE[1]) / SLIDE_AXES[1]) ** 2
    true_dh = np.zeros(ground.shape, dtype=np.float32)
    slides: list[SlideTruth] = []
    if not no_change:
        true_dh = (-3.0 * np.clip(3 * (1 - q), 0, 1)).astype(np.float32)
        inside = true_dh < 0
        slides.append(
            SlideTruth(
                id=1,
                kind="rotational",
                area_m2=float(inside.sum()) * PIXEL**2,
                area_px=int(inside.sum()),
                volume_loss_m3=float(-true_dh.sum()) * PIXEL**2,
                volume_gain_m3=0.0,
                max_depth_m=float(-true_dh.min()),
                length_m=2 * SLIDE_AXES[0] * PIXEL,
            )
        )
    return DsmPair(
        generator="tiny",
        seed=seed,
        pixel_size=PIXEL,
        pre=(ground + err_pre).astype(np.float32),
        post=(ground + true_dh + err_post).astype(np.float32),
        true_dh=true_dh,
        slide_labels=(true_dh < 0).astype(np.int16),
        slides=slides,
        surface_change=np.zeros(ground.shape, dtype=bool),
        observation_error=(err_post - err_pre).astype(np.float32),
        no_change=no_change,
    )


class TinyGenerator:
    name = "tiny"
    summary = "a tilted slope with one elliptic slide, 3 m deep, 5 cm noise"

    def make(self, seed: int, no_change: bool = False) -> DsmPair:
        return tiny_pair(seed, no_change)
