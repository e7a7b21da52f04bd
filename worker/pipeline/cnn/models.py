"""The detection models: the paper's PatchNet and our dense SlideNet.

PatchNet (the paper's Fig. 3, "inspired by AlexNet"). The figure's filter counts did not
survive, so they are ours: AlexNet's layer pattern (five convolutions, max-pooling after
the 1st, 2nd and 5th, three fully connected layers) with widths scaled down to a
32 x 32 x 2 input:

    input 2 x 32 x 32 (pre, post; see normalize.py)
    Conv(16) BN ReLU   -> 16 x 30 x 30     Conv: 3 x 3, stride 1, no padding
    MP                 -> 16 x 29 x 29     MP: 2 x 2, stride 1
    Conv(32) BN ReLU   -> 32 x 27 x 27
    MP                 -> 32 x 26 x 26
    Conv(48) BN ReLU   -> 48 x 24 x 24
    Conv(48) BN ReLU   -> 48 x 22 x 22
    Conv(16) BN ReLU   -> 16 x 20 x 20
    MP                 -> 16 x 19 x 19
    FC(64) BN ReLU, FC(64) BN ReLU, FC(1)  -> one logit (sigmoid: landslide probability)

Batch norm follows every convolution and the first two FC layers, as the paper says.
Weights: He (Kaiming normal, fan-in, ReLU gain); biases zero; BN scale 1, shift 0.
421 k parameters (1.7 MB in float32).

SlideNet (ours): a small fully convolutional encoder-decoder with dense output. Input: the
four channels of normalize.dense_inputs (rel_pre, rel_post, dh, valid); encoder at 1/2,
1/4 and 1/8 resolution (dilated 3 x 3 convolutions at 1/8 for a receptive field of about
130 pixels), one skip connection at 1/4, logits at 1/4 resolution upsampled bilinearly
to full resolution. About 5 k multiply-adds per pixel; 137 k parameters.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from torch import nn
from torch.nn import functional

PATCH_FILTERS = (16, 32, 48, 48, 16)
PATCH_FC = (64, 64)
SLIDENET_WIDTHS = (16, 32, 64)
MODEL_KINDS = ("patchnet", "slidenet")


def _conv_bn(cin: int, cout: int, stride: int = 1, dilation: int = 1, padding: int = 1):
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, stride=stride, padding=padding, dilation=dilation),
        nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True),
    )


def he_init(module: nn.Module) -> None:
    """He (Kaiming normal, fan-in) weights and zero biases for conv and linear layers."""
    for m in module.modules():
        if isinstance(m, nn.Conv2d | nn.Linear):
            nn.init.kaiming_normal_(m.weight, mode="fan_in", nonlinearity="relu")
            if m.bias is not None:
                nn.init.zeros_(m.bias)
        elif isinstance(m, nn.BatchNorm2d | nn.BatchNorm1d):
            nn.init.ones_(m.weight)
            nn.init.zeros_(m.bias)


class PatchNet(nn.Module):
    """The paper's patch classifier: (N, 2, 32, 32) -> (N,) logits."""

    kind = "patchnet"
    input_px = 32

    def __init__(
        self, filters: Sequence[int] = PATCH_FILTERS, fc: Sequence[int] = PATCH_FC
    ) -> None:
        super().__init__()
        f1, f2, f3, f4, f5 = filters
        self.config = {"filters": list(filters), "fc": list(fc)}
        pool = nn.MaxPool2d(2, stride=1)
        self.features = nn.Sequential(
            _conv_bn(2, f1, padding=0),
            pool,
            _conv_bn(f1, f2, padding=0),
            pool,
            _conv_bn(f2, f3, padding=0),
            _conv_bn(f3, f4, padding=0),
            _conv_bn(f4, f5, padding=0),
            pool,
        )
        side = self.input_px - 2 - 1 - 2 - 1 - 2 - 2 - 2 - 1  # 19
        self.flat = f5 * side * side
        self.classifier = nn.Sequential(
            nn.Linear(self.flat, fc[0]),
            nn.BatchNorm1d(fc[0]),
            nn.ReLU(inplace=True),
            nn.Linear(fc[0], fc[1]),
            nn.BatchNorm1d(fc[1]),
            nn.ReLU(inplace=True),
            nn.Linear(fc[1], 1),
        )
        he_init(self)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.features(x)
        return self.classifier(torch.flatten(x, 1)).squeeze(1)


class SlideNet(nn.Module):
    """Dense landslide segmentation: (N, 4, H, W) -> (N, H, W) logits; H, W multiples of 8."""

    kind = "slidenet"
    in_channels = 4
    multiple = 8

    def __init__(self, widths: Sequence[int] = SLIDENET_WIDTHS) -> None:
        super().__init__()
        w1, w2, w3 = widths
        self.config = {"widths": list(widths)}
        self.enc1 = nn.Sequential(_conv_bn(self.in_channels, w1, stride=2), _conv_bn(w1, w1))
        self.enc2 = nn.Sequential(_conv_bn(w1, w2, stride=2), _conv_bn(w2, w2))
        self.enc3 = nn.Sequential(
            _conv_bn(w2, w3, stride=2),
            _conv_bn(w3, w3, dilation=2, padding=2),
            _conv_bn(w3, w3, dilation=4, padding=4),
        )
        self.dec = _conv_bn(w3 + w2, w2)
        self.head = nn.Conv2d(w2, 1, 1)
        he_init(self)

    def forward_quarter(self, x: torch.Tensor) -> torch.Tensor:
        """Logits at 1/4 resolution, (N, 1, H/4, W/4)."""
        e2 = self.enc2(self.enc1(x))
        e3 = self.enc3(e2)
        up = functional.interpolate(e3, size=e2.shape[-2:], mode="bilinear", align_corners=False)
        return self.head(self.dec(torch.cat([up, e2], dim=1)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        quarter = self.forward_quarter(x)
        full = functional.interpolate(
            quarter, size=x.shape[-2:], mode="bilinear", align_corners=False
        )
        return full.squeeze(1)


def build_model(kind: str, config: dict[str, Any] | None = None) -> nn.Module:
    """A fresh model of `kind` ("patchnet" or "slidenet") with its config."""
    config = dict(config or {})
    if kind == "patchnet":
        return PatchNet(**config)
    if kind == "slidenet":
        return SlideNet(**config)
    raise ValueError(f"unknown model kind {kind!r}; kinds are {', '.join(MODEL_KINDS)}")


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
