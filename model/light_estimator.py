"""The photo's light read off the person alone (issue 25): a small network that sees the
masked person crop at 64 px and answers what the geometry-first network's light fit takes
from its albedo prior, the light's colour and level as the person's pixels see them.

    LightEstimator(order=4, width=32)
    forward(x [B, 4, 64, 64]: the masked crop, sRGB-encoded in [-1, 1], and the matte in [-1, 1])
        -> {"light": [B, n, 3], "albedo_mean": [B, 3]}

Five stride-2 convolutions (GroupNorm, SiLU), global average pooling, one linear layer to
the SH light and the person's mean albedo per channel (over its fully covered pixels).
The light is scale-equivariant by construction: the head predicts the log of the DC term
per channel and the other coefficients relative to the DC's luminance. The mean albedo is
what the runtime uses (relight.light_estimate.with_albedo_level): the fitted light scaled
per channel so that the photo-consistent albedo has that mean, which measured far better
than giving the light the estimated DC (docs/EVALUATION.md). Measured against estimators
that also see the background (benchmarks/study_light_context.py): the person alone is the
best input.
"""

from __future__ import annotations

import torch
from torch import nn

from relight.colour import LUMINANCE_WEIGHTS

ARCH = "light-estimator"
INPUT_SIZE = 64
LOG_DC_FLOOR = 1e-3  # the log loss's floor on a DC term: a black channel stays finite


class LightEstimator(nn.Module):
    """See the module docstring. `order`: SH order of the answer; `width`: first conv's channels."""

    arch = ARCH

    def __init__(self, order: int = 4, width: int = 32):
        super().__init__()
        if order < 1 or width < 8 or width % 8:
            raise ValueError(f"LightEstimator: need order >= 1 and a width that is a multiple of 8, "
                             f"got {order}, {width}")
        self.order, self.width = int(order), int(width)
        self.n = (self.order + 1) ** 2
        layers, c = [], 4
        for k in range(5):
            out = self.width * min(2 ** k, 4)
            layers += [nn.Conv2d(c, out, 3, stride=2, padding=1), nn.GroupNorm(8, out), nn.SiLU()]
            c = out
        self.features = nn.Sequential(*layers, nn.AdaptiveAvgPool2d(1), nn.Flatten())
        self.head = nn.Linear(c, self.n * 3 + 3)
        self.register_buffer("luminance", torch.tensor([float(w) for w in LUMINANCE_WEIGHTS]))

    def config(self) -> dict:
        return {"arch": ARCH, "order": self.order, "width": self.width}

    def forward(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        out = self.head(self.features(x))
        raw = out[:, :self.n * 3].view(-1, self.n, 3)
        dc = torch.exp(raw[:, :1].clamp(max=20.0))                    # [B,1,3] > 0
        level = (dc * self.luminance).sum(dim=-1, keepdim=True)       # [B,1,1] its luminance
        # the mean albedo in (0, 1): a sigmoid of the head's last three values
        return {"light": torch.cat([dc, raw[:, 1:] * level], dim=1), "albedo_mean": torch.sigmoid(out[:, self.n * 3:])}


def light_losses(pred: torch.Tensor, true: torch.Tensor, albedo_mean: torch.Tensor | None = None,
                 true_albedo_mean: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """L1 of the log DC per channel (colour and level, in stops / ln 2) plus L1 of the other
    coefficients relative to the true DC's luminance (the light's shape, scale-free); with
    the albedo means [B, 3], L1 of their logs too."""
    luminance = torch.tensor([float(w) for w in LUMINANCE_WEIGHTS], dtype=true.dtype, device=true.device)
    log_dc = torch.log(pred[:, 0].clamp(min=LOG_DC_FLOOR)) - torch.log(true[:, 0].clamp(min=LOG_DC_FLOOR))
    level = (true[:, :1] * luminance).sum(dim=-1, keepdim=True).clamp(min=LOG_DC_FLOOR)
    shape = (pred[:, 1:] - true[:, 1:]).abs() / level
    terms = {"log_dc": log_dc.abs().mean(), "shape": shape.mean()}
    if albedo_mean is not None:
        terms["albedo_mean"] = (torch.log(albedo_mean.clamp(min=LOG_DC_FLOOR))
                                - torch.log(true_albedo_mean.clamp(min=LOG_DC_FLOOR))).abs().mean()
    terms["total"] = sum(terms.values())
    return terms


def albedo_colour_error_deg(est: torch.Tensor, true: torch.Tensor) -> torch.Tensor:
    """[B] degrees between estimated and true mean albedo colours [B, 3]."""
    cos = (est * true).sum(-1) / (est.norm(dim=-1) * true.norm(dim=-1)).clamp(min=1e-12)
    return torch.rad2deg(torch.arccos(cos.clamp(-1.0, 1.0)))


def colour_error_deg(est: torch.Tensor, true: torch.Tensor) -> torch.Tensor:
    """[B] degrees between the estimated and true DC RGB."""
    a, b = est[:, 0], true[:, 0]
    cos = (a * b).sum(-1) / (a.norm(dim=-1) * b.norm(dim=-1)).clamp(min=1e-12)
    return torch.rad2deg(torch.arccos(cos.clamp(-1.0, 1.0)))


def level_error_stops(est: torch.Tensor, true: torch.Tensor) -> torch.Tensor:
    """[B] |log2| of the ratio of the DC luminances."""
    luminance = torch.tensor([float(w) for w in LUMINANCE_WEIGHTS], dtype=true.dtype, device=true.device)
    ratio = (est[:, 0] * luminance).sum(-1).clamp(min=1e-9) / (true[:, 0] * luminance).sum(-1).clamp(min=1e-9)
    return torch.log2(ratio).abs()
