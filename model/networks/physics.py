"""The physics the geometry-first network derives its transport and light from (torch).

Every function here is differentiable and exports to ONNX opset 17 (only
elementwise ops, MatMul, ReduceSum and slices: no linalg ops), so the fitted
light and the photo-consistent albedo live inside the exported graph and the
runtime stays `albedo * (T . L') + E . L'`.

* `sh_basis`: real orthonormal SH of unit directions (relight.lighting.sh.sh_basis, torch).
* `lobe_transport`: T_lm = v * A_l / pi * Y_lm(n), the unoccluded white-Lambert
  transport of relight.network.prt.lambert_transport scaled by a visibility v in [0, 1]
  (ambient occlusion).
* `visibility_from_transport`: v = T_00 / T_00(unoccluded), its supervision.
* `fit_light`: ridge least squares for the photo's own SH light given T and an
  albedo prior, solved by Gauss-Jordan elimination without pivoting (the
  ridge makes the normal equations symmetric positive definite).
* `photo_consistent_albedo`: photo / (T . L_a), the shading floored in deep
  shadow: relight.network.prt.photo_consistent_albedo on torch tensors, the one rule (and
  constants) the runtime shares, so the albedo follows from the light the same way there.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from relight.network import prt
from relight.lighting import sh as sh_np
from relight.imaging.colour import SRGB_ENCODED_KNEE, SRGB_GAMMA, SRGB_OFFSET, SRGB_SCALE, SRGB_SLOPE
from relight.network.prt import ALBEDO_MIN_MEAN, ALBEDO_RELIABLE


def sh_basis(dirs: torch.Tensor, order: int, dim: int = 1, scale=None) -> torch.Tensor:
    """Real orthonormal SH of unit vectors along `dim` (size 3): [.., 3, ..] -> [.., n, ..].

    The same recurrences as relight.lighting.sh.sh_basis (polynomials in x, y, z; no
    Condon-Shortley phase); `dirs` must already be unit length. `scale` (n
    numbers) multiplies each coefficient, as plain floats so that a traced
    graph holds them as constants.
    """
    x, y, z = (dirs.select(dim, i) for i in range(3))
    diag, a, b = sh_np._legendre_factors(order)
    q = []
    for m in range(order + 1):
        col = [torch.full_like(z, float(diag[m]))]
        if m + 1 <= order:
            col.append(math.sqrt(2 * m + 3) * z * col[0])
        for l in range(m + 2, order + 1):
            col.append(float(a[l, m]) * z * col[-1] - float(b[l, m]) * col[-2])
        q.append(col)
    cos_m, sin_m = [torch.ones_like(x)], [torch.zeros_like(x)]
    for _ in range(order):
        c, s = cos_m[-1], sin_m[-1]
        cos_m.append(x * c - y * s)
        sin_m.append(x * s + y * c)
    out: list[torch.Tensor | None] = [None] * ((order + 1) ** 2)
    sqrt2 = math.sqrt(2.0)
    for l in range(order + 1):
        centre = l * l + l
        out[centre] = q[0][l]
        for m in range(1, l + 1):
            p = sqrt2 * q[m][l - m]
            out[centre + m] = p * cos_m[m]
            out[centre - m] = p * sin_m[m]
    if scale is not None:
        out = [o * float(k) for o, k in zip(out, scale)]
    return torch.stack(out, dim=dim)


def lobe_scale(order: int) -> np.ndarray:
    """A_l / pi per coefficient, [n]: T_lm = v * lobe_scale * Y_lm(n)."""
    A = sh_np.clamped_cosine_coeffs(order)
    return np.repeat(A / np.pi, 2 * np.arange(order + 1) + 1)


def lobe_transport(normal: torch.Tensor, visibility: torch.Tensor, order: int) -> torch.Tensor:
    """Transport [B, n, H, W] of a white Lambertian point with unit `normal` [B,3,H,W]
    and ambient visibility [B,1,H,W]: v * A_l / pi * Y_lm(n)."""
    return sh_basis(normal, order, dim=1, scale=lobe_scale(order)) * visibility


# T_00 of an unoccluded white Lambertian point: (A_0 / pi) * Y_00 = 1 / (2 sqrt(pi))
UNOCCLUDED_DC = 1.0 / (2.0 * math.sqrt(math.pi))


def visibility_from_transport(transport: torch.Tensor) -> torch.Tensor:
    """Ambient visibility [B,1,H,W] of a transport map [B,n,H,W]: T_00 relative to an
    unoccluded point, clamped to [0, 1] (a glossy bake can exceed 1 slightly)."""
    return (transport[:, :1] / UNOCCLUDED_DC).clamp(0.0, 1.0)


def srgb_decode(encoded: torch.Tensor) -> torch.Tensor:
    """sRGB-encoded [0, 1] -> linear (relight.imaging.colour.srgb_decode), clipped to [0, 1] first."""
    x = encoded.clamp(0.0, 1.0)
    high = torch.pow((x.clamp(min=SRGB_ENCODED_KNEE) + SRGB_OFFSET) / SRGB_SCALE, SRGB_GAMMA)
    return torch.where(x <= SRGB_ENCODED_KNEE, x / SRGB_SLOPE, high)


def linear_from_network_input(image: torch.Tensor) -> torch.Tensor:
    """The linear photo the network input encodes (relight.network.prt.to_network_input inverted
    where the mask is 1)."""
    return srgb_decode((image + 1.0) * 0.5)


def solve_spd(matrix: torch.Tensor, rhs: torch.Tensor) -> torch.Tensor:
    """x with matrix @ x = rhs for symmetric positive definite [.., n, n] and rhs [.., n, k].

    Gauss-Jordan elimination without pivoting (stable for SPD matrices), unrolled
    over n: elementwise ops only, so it differentiates and exports to ONNX.
    """
    n = matrix.shape[-1]
    aug = torch.cat([matrix, rhs], dim=-1)
    eye = torch.eye(n, dtype=matrix.dtype, device=matrix.device)
    for k in range(n):
        row = aug[..., k:k + 1, :]
        pivot = row / row[..., :, k:k + 1]
        col = aug[..., :, k:k + 1]
        # eliminate column k from every row (row k becomes 0), then put the pivot row back
        aug = aug - col * pivot + eye[:, k:k + 1] * pivot
    return aug[..., :, n:]


def fit_light(transport: torch.Tensor, albedo: torch.Tensor, photo: torch.Tensor, weight: torch.Tensor,
              prior: torch.Tensor, ridge: float | torch.Tensor, precision: torch.dtype = torch.float64) -> torch.Tensor:
    """The SH light [B, n, 3] that best explains `photo` as albedo * (T . L), per channel:

        argmin_L  sum_x w(x) (albedo_c(x) T(x) . L_c - photo_c(x))^2 + lam_c |L_c - prior_c|^2

    with lam_c = ridge * trace(normal matrix_c) / n, relative to the data's own
    scale: combinations of coefficients the pixels hardly see (light from behind
    the person, the bands a Lambertian lobe filters out) stay at the prior. The
    system is solved after Jacobi scaling (unit diagonal), so that its condition
    number does not depend on the bands' very different scales and a float32
    graph agrees with float64.
    transport [B,n,H,W], albedo/photo [B,3,H,W], weight [B,1,H,W], prior [B,n,3].
    `precision`: float64 (the default, and what the exported graph runs) or float32, which
    training may use: there the answer moves by ~3e-7 of the light (measured) for half the
    time of a double fit and its backward.
    """
    b, n = transport.shape[:2]
    # float64 in the graph: the normal matrix sums up to a million float32 products, whose
    # rounding depends on the summation order (torch and onnxruntime differ) and which
    # the solve would amplify; the system is tiny, so double costs little at inference
    dtype = transport.dtype
    t = transport.reshape(b, 1, n, -1).to(precision)          # [B,1,n,P]
    a = albedo.reshape(b, 3, 1, -1).to(precision)             # [B,3,1,P]
    w = weight.reshape(b, 1, 1, -1).to(precision)
    photo, prior = photo.to(precision), prior.to(precision)
    design = t * a                                            # [B,3,n,P]: rows of albedo_c * T
    weighted = design * w
    normal = torch.matmul(weighted, design.transpose(-1, -2))  # [B,3,n,n]
    rhs = torch.matmul(weighted, photo.reshape(b, 3, -1, 1))  # [B,3,n,1]
    eye = torch.eye(n, dtype=precision, device=transport.device)
    diag = (normal * eye).sum(dim=-1)                         # [B,3,n]
    lam = ridge * diag.mean(dim=-1, keepdim=True) + 1e-20     # [B,3,1]
    scale = torch.rsqrt(diag + lam)                           # Jacobi: unit diagonal
    system = (normal + lam.unsqueeze(-1) * eye) * scale.unsqueeze(-1) * scale.unsqueeze(-2)
    prior_c = prior.permute(0, 2, 1)                          # [B,3,n]
    target = ((rhs.squeeze(-1) + lam * prior_c) * scale).unsqueeze(-1)
    light = solve_spd(system, target).squeeze(-1) * scale
    return light.permute(0, 2, 1).to(dtype)                   # [B,n,3]


def photo_consistent_albedo(photo: torch.Tensor, shading: torch.Tensor, weight: torch.Tensor,
                            reliable: float = ALBEDO_RELIABLE, min_mean: float = ALBEDO_MIN_MEAN) -> torch.Tensor:
    """photo / max(shading, reliable * mean shading), in [0, 1], for [B, 3, H, W] tensors
    (weight [B, 1, H, W]): relight.network.prt.photo_consistent_albedo, the one rule and constants
    the runtime uses too, run on torch (what it means and why: there)."""
    return prt.photo_consistent_albedo(photo, shading, weight, reliable, min_mean, xp=torch, channels=1, pixels=(2, 3))
