"""PRT rendering layer: R = albedo * (T . L) + E . L, the network's input encoding, and the
photo-consistent albedo rule (the one function the exported graph, model.networks.physics, and the
runtime, relight.network.refine.consistent_albedo, both use: the albedo follows from the light)."""

from __future__ import annotations

import numpy as np

from relight.imaging.colour import srgb_encode
from relight.lighting.sh import order_from_num_coeffs

__all__ = ["shading", "render", "to_network_input", "lambert_transport", "photo_consistent_albedo",
           "ALBEDO_RELIABLE", "ALBEDO_MIN_MEAN"]

# The photo-consistent albedo rule's constants (photo_consistent_albedo), the one set: the
# geometry network's graph (model.networks.physics, model.networks.geometry's `reliable` default) and the runtime
ALBEDO_RELIABLE = 0.25  # the shading floor, a fraction of the person's weighted mean shading
ALBEDO_MIN_MEAN = 0.08  # the least that mean is taken as: a near-black fit does not floor every pixel at ~0


def _check_light(L) -> np.ndarray:
    L = np.asarray(L)
    if L.ndim != 2 or L.shape[1] != 3:
        raise ValueError(f"light must have shape [(order+1)^2, 3], got {L.shape}")
    order_from_num_coeffs(L.shape[0])
    if not np.all(np.isfinite(L)):
        raise ValueError("light coefficients contain NaN or Inf")
    return L


def _check_transport(T, n: int, name: str) -> np.ndarray:
    T = np.asarray(T)
    if T.ndim < 1 or T.shape[-1] != n:
        raise ValueError(f"{name} must have shape [..., {n}] to match the light, got {T.shape}")
    return T


def _pixel_dtype(*arrays) -> np.dtype:
    # the per-pixel arrays decide: float32 images stay float32 (the light,
    # [n, 3], is cast to them), anything else computes in float64
    if all(np.asarray(a).dtype == np.float32 for a in arrays):
        return np.dtype(np.float32)
    return np.dtype(np.float64)


def shading(T, L) -> np.ndarray:
    """Per-pixel shading T . L: T [..., n], L [n, 3] -> [..., 3] (float32 if T is)."""
    L = _check_light(L)
    T = _check_transport(T, L.shape[0], "transport")
    dtype = _pixel_dtype(T)
    return np.matmul(T.astype(dtype, copy=False), L.astype(dtype, copy=False))


def render(albedo, T, E, L) -> np.ndarray:
    """Linear radiance albedo * (T . L) + E . L; E (residual transport) may be None.

    float32 when albedo, T (and E) are float32, whatever the light's dtype.
    """
    L = _check_light(L)
    albedo = np.asarray(albedo)
    T = _check_transport(T, L.shape[0], "transport")
    if albedo.shape[-1:] != (3,) or albedo.shape[:-1] != T.shape[:-1]:
        raise ValueError(
            f"albedo must have shape {T.shape[:-1] + (3,)} to match transport, got {albedo.shape}"
        )
    out = albedo * shading(T, L)
    if E is not None:
        E = _check_transport(E, L.shape[0], "residual transport")
        if E.shape != T.shape:
            raise ValueError(f"residual transport shape {E.shape} != transport shape {T.shape}")
        out = out + shading(E, L)
    return out.astype(_pixel_dtype(albedo, T, *(() if E is None else (E,))), copy=False)


def lambert_transport(normals, order: int) -> np.ndarray:
    """Unoccluded white-Lambert transport T_lm(n) = A_l / pi * Y_lm(n), [..., n].

    With f_r = 1/pi, an unoccluded white point under constant radiance 1 gets
    T . L = 1 (docs/conventions.md).
    """
    from relight.lighting.sh import clamped_cosine_coeffs, sh_basis

    basis = sh_basis(normals, order)
    A = clamped_cosine_coeffs(order)
    per_coeff = np.repeat(A / np.pi, 2 * np.arange(order + 1) + 1)
    return basis * per_coeff


def to_network_input(image, mask=None) -> np.ndarray:
    """Linear photo [..., 3] -> network input in [-1, 1] (same layout, float32).

    clip to [0, 1] -> sRGB encode -> x * 2 - 1, then multiplied by `mask`
    ([...] or [..., 1], in [0, 1]) when one is given. The caller transposes
    to the network's [B, 3, H, W].
    """
    img = np.asarray(image)
    if img.ndim < 1 or img.shape[-1] != 3:
        raise ValueError(f"image must have shape [..., 3], got {img.shape}")
    if not np.all(np.isfinite(img)):
        raise ValueError("image contains NaN or Inf")
    out = srgb_encode(img.astype(np.float32, copy=False)) * 2.0 - 1.0
    if mask is not None:
        m = np.asarray(mask, dtype=np.float32)
        if m.shape == img.shape[:-1]:
            m = m[..., None]
        if m.shape != img.shape[:-1] + (1,):
            raise ValueError(f"mask must have shape {img.shape[:-1]}, got {np.shape(mask)}")
        if not np.all(np.isfinite(m)) or m.min(initial=0.0) < 0 or m.max(initial=0.0) > 1:
            raise ValueError("mask values must be finite and in [0, 1]")
        out = out * m
    return out.astype(np.float32, copy=False)


def photo_consistent_albedo(photo, shading, weight, reliable: float = ALBEDO_RELIABLE,
                            min_mean: float = ALBEDO_MIN_MEAN, *, xp=np, channels: int = -1,
                            pixels: tuple = (-3, -2)):
    """photo / max(shading, reliable * mean shading), in [0, 1]: the albedo that follows
    from a light (shading = T . L), the one rule of the graph and the runtime.

    Where the photo and the fitted shading agree this makes the relit image the photo times
    shading' / shading (quotient relighting). In deep shadow the shading is floored at
    `reliable` of its mean luminance over the person weighted by `weight` (the mean taken as
    at least `min_mean`), so a small shading error cannot blow up and neighbouring pixels
    keep one albedo source (switching to another albedo there left patches on dark clothing).

    Written once for both array libraries: numpy by default (photo, shading [h, w, 3],
    weight [h, w, 1]); model.networks.physics passes xp=torch, channels=1, pixels=(2, 3) for its
    [B, 3, H, W] tensors (the same ops trace into the exported graph).
    """
    lum = xp.mean(shading, axis=channels, keepdims=True)
    mean = xp.sum(lum * weight, axis=pixels, keepdims=True) / (xp.sum(weight, axis=pixels, keepdims=True) + 1e-4)
    mean = xp.clip(mean, min_mean, None)
    return xp.clip(photo / xp.maximum(shading, reliable * mean), 0.0, 1.0)
