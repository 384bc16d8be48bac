"""The sun-response loss (issue 45): the relit person's pattern of light under a hard sun, in log
luminance, against the truth's.

The light's response (model.scoring.metrics.light_response) is measured in log luminance with
each image's mean removed; the relight term of the geometry losses is linear L1 under the scene's
other light, which weighs the lit side and hardly sees the shadow side or the terminator. Here
each sample is relit to a hard white sun drawn by the data (model.samples.data_augment.
random_sun_light) and compared with the truth under that sun by PRT, albedo x (T . L_sun), which
the baked transport makes exact for any light (its self-shadowing included):

    d = log max(lum relit, f_r) - log max(lum truth, f_t),   f_x = FLOOR x mean_w lum x (per image)
    loss = sum w |d - mean_w d| / sum w

Removing d's mean, and each image's floor following its own level, make the term blind to the
relit level (the level prior's job, relight.network.level), as the slope and correlation are.
The floor keeps the log finite where a sun leaves the truth black (a cast shadow); below it no
gradient flows (max passes none).
L1, not L2: the pixels where a cast shadow falls, which a cosine lobe cannot darken, do not
dominate.
"""

from __future__ import annotations

import torch

from relight.imaging.colour import LUMINANCE_WEIGHTS

FLOOR = 0.01  # of an image's mean luminance over the person: below it, black to the eye
MIN_FLOOR = 1e-12  # an image black all over still has a finite log


def _luminance(image: torch.Tensor) -> torch.Tensor:
    r, g, b = (float(v) for v in LUMINANCE_WEIGHTS)
    return image[:, 0:1] * r + image[:, 1:2] * g + image[:, 2:3] * b


def _masked_mean(x: torch.Tensor, w: torch.Tensor, total: torch.Tensor) -> torch.Tensor:
    return (x * w).sum(dim=(1, 2, 3), keepdim=True) / total


def sun_response_loss(relit: torch.Tensor, truth: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """The module docstring's loss of relit and truth [B, 3, H, W] (linear) over weight [B, 1, H, W];
    images with no weight count for nothing."""
    total = weight.sum(dim=(1, 2, 3), keepdim=True)
    safe = total.clamp_min(1e-6)
    lum_relit, lum_truth = _luminance(relit), _luminance(truth)

    def floored_log(lum):
        floor = (FLOOR * _masked_mean(lum, weight, safe)).detach().clamp_min(MIN_FLOOR)
        return torch.log(torch.maximum(lum, floor))

    d = floored_log(lum_relit) - floored_log(lum_truth)
    d = d - _masked_mean(d, weight, safe)
    return (d.abs() * weight).sum() / total.sum().clamp_min(1.0)
