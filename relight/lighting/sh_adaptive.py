"""Adaptive SH order: how many bands a light needs for a diffuse surface.

The clamped cosine filters the light (E_lm = A_l L_lm, relight.lighting.sh.clamped_cosine_coeffs);
the order a request needs is the smallest that holds a share of that filtered
energy (docs/TRADEOFFS.md). numpy only.
"""

from __future__ import annotations

import numpy as np

from relight.lighting.sh import clamped_cosine_coeffs, order_from_num_coeffs, validate_coeffs

__all__ = ["band_irradiance_energy", "required_order"]


def band_irradiance_energy(coeffs) -> np.ndarray:
    """Energy per band l of the clamped-cosine-convolved light: A_l^2 sum_m,rgb L_lm^2."""
    c = validate_coeffs(coeffs)
    order = order_from_num_coeffs(c.shape[0])
    A = clamped_cosine_coeffs(order)
    band = np.repeat(np.arange(order + 1), 2 * np.arange(order + 1) + 1)
    per_coeff = (c.astype(np.float64) ** 2).sum(axis=1)
    return A**2 * np.bincount(band, weights=per_coeff, minlength=order + 1)


def required_order(coeffs, fraction: float = 0.99) -> int:
    """Smallest order whose convolved energy holds `fraction` of the total of `coeffs`.

    A diffuse surface sees the light through the clamped cosine, whose A_l falls
    as l^-2.5 (and is 0 for odd l > 1): bands beyond this order change a
    Lambertian image by at most sqrt(1 - fraction) of its energy. Pass order-8
    coefficients to compare against the order-8 total.
    """
    if not (isinstance(fraction, (int, float)) and 0.0 < fraction <= 1.0):
        raise ValueError(f"fraction must be in (0, 1], got {fraction!r}")
    energy = band_irradiance_energy(coeffs)
    total = energy.sum()
    if not total > 0:
        return 0  # a black light needs nothing
    captured = np.cumsum(energy) / total
    # Tolerance: cumsum rounding may leave the full sum a few ulps below 1.
    return int(np.argmax(captured >= fraction - 1e-12))
