"""Synthetic DSM pairs and comparison runs shared by the pipeline tests.

Runs are session-scoped: each compare_dsms call costs about a second, and the tests only
read their outputs.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from worker.pipeline.comparison import ComparisonResult, compare_dsms
from worker.simulator.dsm_pair import DsmPair, DsmPairPaths, make_dsm_pair, write_dsm_pair

SLIDE_SHIFT_M = (2.4, -1.3, 0.5)
NOISE_SHIFT_M = (1.7, 0.6, -0.3)


@dataclass
class Run:
    pair: DsmPair
    paths: DsmPairPaths
    result: ComparisonResult


def _run(base: Path, pair: DsmPair) -> Run:
    paths = write_dsm_pair(pair, base / "input")
    return Run(pair, paths, compare_dsms(paths.pre, paths.post, base / "work"))


@pytest.fixture(scope="session")
def slide_run(tmp_path_factory: pytest.TempPathFactory) -> Run:
    """400 x 400 at 1 m, projected, planted slide, multi-pixel shift, 5 cm noise."""
    pair = make_dsm_pair((400, 400), 1.0, SLIDE_SHIFT_M, slide=True, noise_m=0.05, seed=11)
    return _run(tmp_path_factory.mktemp("slide"), pair)


@pytest.fixture(scope="session")
def noise_run(tmp_path_factory: pytest.TempPathFactory) -> Run:
    """Same size, no slide: the two DSMs differ only by noise and a shift."""
    pair = make_dsm_pair((400, 400), 1.0, NOISE_SHIFT_M, slide=False, noise_m=0.05, seed=12)
    return _run(tmp_path_factory.mktemp("noise"), pair)


@pytest.fixture(scope="session")
def hole_run(tmp_path_factory: pytest.TempPathFactory) -> Run:
    """No slide, shift, and a round nodata hole in the pre DSM."""
    pair = make_dsm_pair((300, 300), 1.0, NOISE_SHIFT_M, slide=False, noise_m=0.05, seed=13)
    rows, cols = np.mgrid[0:300, 0:300]
    pair.pre[(rows - 120) ** 2 + (cols - 170) ** 2 < 30**2] = np.nan
    pair.post[200:230, 40:90] = np.nan
    return _run(tmp_path_factory.mktemp("hole"), pair)


@pytest.fixture(scope="session")
def geographic_run(tmp_path_factory: pytest.TempPathFactory) -> Run:
    """EPSG:4326 input with a slide: exercises the UTM path."""
    pair = make_dsm_pair(
        (400, 400),
        1.0,
        (1.2, 0.8, 0.3),
        slide=True,
        noise_m=0.05,
        seed=14,
        crs="EPSG:4326",
        origin=(9.5, 46.2),
    )
    return _run(tmp_path_factory.mktemp("geographic"), pair)
