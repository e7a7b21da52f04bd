"""sorted_sample: the subsample numpy's choice over the values draws, faster."""

import numpy as np
import pytest

from worker.pipeline.sampling import sorted_sample


@pytest.mark.parametrize("seed", range(5))
def test_the_sample_is_the_one_choice_draws_over_the_values(seed):
    mask = np.random.default_rng(100 + seed).random(200_000) < 0.7
    values = np.flatnonzero(mask)
    size = 1_000 * (seed + 1)
    expected = np.sort(np.random.default_rng(seed).choice(values, size, replace=False))
    sample = sorted_sample(np.random.default_rng(seed), values, size)
    np.testing.assert_array_equal(sample, expected)
    assert np.unique(sample).size == size and np.all(mask[sample])
