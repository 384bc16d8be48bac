"""The depth head's loss (issue 45): scale-and-shift-invariant, over the person's pixels.

One photo fixes a person's depth only up to scale and shift (how far away, how large), so the
network's depth p is compared with the farm's depth pass t after both are standardized over the
pixels of weight w (per image):

    x_n = (x - mean_w x) / sqrt(var_w x + EPS)        loss = sum w |p_n - t_n| / sum w

Standardizing removes any shift b and any positive scale a, so loss(a p + b, t) = loss(p, t) and
loss(a t + b, t) = 0 for every a > 0 (up to EPS against the variance); a depth turned inside out
(a < 0) costs 2 mean_w |t_n| > 0, and so does any depth that is not an affine copy of the truth.
Least-squares alignment (min over a, b of |a p + b - t|, the MiDaS form) was not used: it lets a
be negative, so an inverted depth would score 0 and the shadows over it would fall on the wrong
side. L1 rather than L2 of the standardized values: the silhouette's edge pixels, where the crop's
resampling mixes depths, do not dominate.
"""

from __future__ import annotations

import torch

EPS = 1e-10   # added to each image's depth variance: a flat prediction has a finite gradient


def _standardized(x: torch.Tensor, w: torch.Tensor, total: torch.Tensor) -> torch.Tensor:
    mean = (x * w).sum(dim=(1, 2, 3), keepdim=True) / total
    var = (((x - mean) ** 2) * w).sum(dim=(1, 2, 3), keepdim=True) / total
    return (x - mean) / torch.sqrt(var + EPS)


def ssi_depth_loss(pred: torch.Tensor, truth: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """The module docstring's loss of depths pred, truth [B, 1, H, W] over weight [B, 1, H, W] >= 0,
    averaged over the images that have weight (0 when none has)."""
    if pred.shape != truth.shape or pred.shape != weight.shape or pred.ndim != 4 or pred.shape[1] != 1:
        raise ValueError(f"depth, truth and weight must be [B, 1, H, W] alike, got {tuple(pred.shape)}, "
                         f"{tuple(truth.shape)}, {tuple(weight.shape)}")
    w = weight.to(pred.dtype)
    total = w.sum(dim=(1, 2, 3), keepdim=True)
    has = (total > 0).to(pred.dtype).reshape(-1)
    total = total.clamp_min(1e-8)
    t = truth.to(pred.dtype)
    per_image = (torch.abs(_standardized(pred, w, total) - _standardized(t, w, total)) * w).sum(dim=(1, 2, 3))
    per_image = per_image / total.reshape(-1)
    return (per_image * has).sum() / has.sum().clamp_min(1.0)
