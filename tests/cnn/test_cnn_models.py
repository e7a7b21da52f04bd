"""The models' shapes and initialisation."""

import math

import torch
from torch import nn

from worker.pipeline.cnn.models import PatchNet, SlideNet, build_model, count_parameters


def test_patchnet_layers_follow_the_paper():
    model = PatchNet()
    convs = [m for m in model.features if isinstance(m, nn.Sequential)]
    pools = [m for m in model.features if isinstance(m, nn.MaxPool2d)]
    assert [c[0].out_channels for c in convs] == [16, 32, 48, 48, 16]
    for block in convs:
        conv, bn, relu = block
        assert conv.kernel_size == (3, 3) and conv.stride == (1, 1)
        assert isinstance(bn, nn.BatchNorm2d) and isinstance(relu, nn.ReLU)
    assert len(pools) == 3
    for pool in model.features:
        if isinstance(pool, nn.MaxPool2d):
            assert pool.kernel_size == 2 and pool.stride == 1
    layers = list(model.classifier)
    linear = [m for m in layers if isinstance(m, nn.Linear)]
    assert [m.out_features for m in linear] == [64, 64, 1]
    assert isinstance(layers[1], nn.BatchNorm1d) and isinstance(layers[4], nn.BatchNorm1d)
    assert not any(isinstance(m, nn.BatchNorm1d) for m in layers[6:])


def test_patchnet_shapes():
    model = PatchNet().eval()
    x = torch.randn(5, 2, 32, 32)
    assert model.features(x).shape == (5, 16, 19, 19)
    assert model(x).shape == (5,)
    assert count_parameters(model) == 421_057
    assert count_parameters(model) * 4 < 2_000_000


def test_he_initialisation_and_zero_biases():
    torch.manual_seed(0)
    model = PatchNet()
    for m in model.modules():
        if isinstance(m, nn.Conv2d | nn.Linear):
            fan_in = m.weight[0].numel()
            expected = math.sqrt(2.0 / fan_in)
            assert abs(m.weight.std().item() / expected - 1) < 0.2
            assert torch.count_nonzero(m.bias) == 0
        if isinstance(m, nn.BatchNorm2d | nn.BatchNorm1d):
            assert torch.all(m.weight == 1) and torch.all(m.bias == 0)


def test_slidenet_dense_output():
    model = SlideNet().eval()
    with torch.no_grad():
        out = model(torch.randn(2, 4, 64, 96))
    assert out.shape == (2, 64, 96)
    assert build_model("slidenet", model.config).config == model.config
    assert count_parameters(model) * 4 < 2_000_000
