"""Torch twins of the core's rendering layer (relight.network.prt) and the SH ops the model uses.

Channel-first layout: maps are [B, C, H, W], lights [B, n, 3]. Each function
equals its numpy counterpart in relight (tested in tests/model/test_model_sh_torch.py).
"""

from __future__ import annotations

import numpy as np
import torch

from relight.lighting import sh_rotation
from relight.imaging.colour import LUMINANCE_WEIGHTS, SRGB_GAMMA, SRGB_LINEAR_KNEE, SRGB_OFFSET, SRGB_SCALE, SRGB_SLOPE


def shading(transport: torch.Tensor, light: torch.Tensor) -> torch.Tensor:
    """T . L per pixel: transport [B,n,H,W], light [B,n,3] -> [B,3,H,W]."""
    if transport.shape[1] != light.shape[1]:
        raise ValueError(f"shading: transport has {transport.shape[1]} coefficients, "
                         f"light has {light.shape[1]}")
    return torch.einsum("bnhw,bnc->bchw", transport, light)


def render(albedo: torch.Tensor, transport: torch.Tensor, residual: torch.Tensor | None,
           light: torch.Tensor) -> torch.Tensor:
    """albedo * (T . L) + E . L  -> [B,3,H,W] (residual may be None)."""
    image = albedo * shading(transport, light)
    if residual is not None:
        image = image + shading(residual, light)
    return image


def shading_tstar(tstar: torch.Tensor, light: torch.Tensor) -> torch.Tensor:
    """Per-channel T*.L for the "T* = albedo*T + E" ablation; tstar [B,3n,H,W] (index c*n+k)."""
    b, c3n, h, w = tstar.shape
    n = light.shape[1]
    if c3n != 3 * n:
        raise ValueError(f"shading_tstar: T* has {c3n} channels, expected 3*{n}")
    return torch.einsum("bcnhw,bnc->bchw", tstar.reshape(b, 3, n, h, w), light)


def rotation_matrix(R: np.ndarray, order: int, dtype=torch.float32,
                    device: torch.device | str = "cpu") -> torch.Tensor:
    """relight.lighting.sh_rotation.rotation_matrix as a tensor [n, n]; rotate with rotate_light."""
    return torch.as_tensor(sh_rotation.rotation_matrix(R, order), dtype=dtype, device=device)


def rotate_light(light: torch.Tensor, matrix: torch.Tensor) -> torch.Tensor:
    """M @ L for light [B,n,3] (or [n,3]) and M [B,n,n] (or [n,n])."""
    return torch.matmul(matrix, light)


def srgb_encode(linear: torch.Tensor) -> torch.Tensor:
    """Linear -> sRGB-encoded, clipped to [0, 1] first (as relight.imaging.colour.srgb_encode)."""
    x = linear.clamp(0.0, 1.0)
    high = SRGB_SCALE * torch.pow(x.clamp(min=SRGB_LINEAR_KNEE), 1.0 / SRGB_GAMMA) - SRGB_OFFSET
    return torch.where(x <= SRGB_LINEAR_KNEE, x * SRGB_SLOPE, high)


def to_network_input(linear: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Linear photo [B,3,H,W] -> sRGB-encoded, mapped to [-1, 1], times mask [B,1,H,W]."""
    x = srgb_encode(linear) * 2.0 - 1.0
    if mask is not None:
        x = x * mask
    return x


def mean_luminance(light: torch.Tensor) -> torch.Tensor:
    """Solid-angle mean luminance of lights [B,n,3] -> [B] (relight.lighting.sh.mean_luminance)."""
    weights = torch.tensor(LUMINANCE_WEIGHTS.tolist(), dtype=light.dtype, device=light.device)
    return (light[:, 0, :] / (2.0 * np.sqrt(np.pi))) @ weights
