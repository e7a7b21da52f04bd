"""Tiled dense inference: seamless tiles, the pyramid, nodata never a landslide."""

import numpy as np
import pytest
import torch

from worker.pipeline.cnn.detect_stage import cell_fractions
from worker.pipeline.cnn.inference import block_mean, predict_dense
from worker.pipeline.cnn.models import SlideNet


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(5)
    net = SlideNet()
    with torch.no_grad():  # non-trivial batch-norm statistics
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.uniform_(-0.2, 0.2)
                m.running_var.uniform_(0.5, 2.0)
    return net.eval()


def _pair():
    rng = np.random.default_rng(0)
    pre = (np.cumsum(rng.normal(0, 0.02, (260, 300)), axis=1) + 10).astype(np.float32)
    post = pre + rng.normal(0, 0.01, pre.shape).astype(np.float32)
    post[100:150, 120:180] -= 0.5
    post[20:40, 250:280] = np.nan
    return pre, post


@pytest.mark.parametrize("scales", [(1,), (1, 2, 4)])
def test_tiles_join_without_seams(model, scales):
    pre, post = _pair()
    whole = predict_dense(model, pre, post, 0.02, tile_px=1024, num_threads=1, scales=scales)
    tiled = predict_dense(model, pre, post, 0.02, tile_px=96, num_threads=1, scales=scales)
    np.testing.assert_allclose(tiled, whole, atol=2e-5)


def test_nodata_has_zero_probability(model):
    pre, post = _pair()
    prob = predict_dense(model, pre, post, 0.02, num_threads=1, scales=(1, 2, 4))
    assert np.all(prob[20:40, 250:280] == 0)
    assert prob.shape == pre.shape and prob.min() >= 0 and prob.max() <= 1


def test_block_mean_and_cells():
    a = np.arange(36, dtype=np.float32).reshape(6, 6)
    a[0, 0] = np.nan
    m = block_mean(a, 2)
    assert np.isnan(m[0, 0]) and m[2, 2] == pytest.approx(a[4:6, 4:6].mean())
    classes = np.zeros((40, 70), np.uint8)
    classes[:32, :32][:10, :11] = 1  # 110 of 1024 pixels
    classes[32:, :] = 255
    fraction, total = cell_fractions(classes)
    assert fraction.shape == (2, 3) and total[0, 0] == 1024 and total[1, 0] == 0
    assert total[0, 2] == 32 * 6  # the partial cell at the right edge
    assert fraction[0, 0] == pytest.approx(110 / 1024)
