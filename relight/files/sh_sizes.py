"""How many coefficients spherical harmonics of an order have, and the check of an order: the one
definition, below both relight/lighting/ (relight.lighting.sh re-exports it) and the scene files
(relight/files/dataset.py, whose transport has one channel per coefficient)."""

from __future__ import annotations

import math

import numpy as np

MAX_ORDER = 64  # recurrences are stable far beyond this; the cap catches typos


def check_order(order) -> int:
    """`order` as an int; ValueError unless it is an integer in [0, MAX_ORDER]."""
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)):
        raise ValueError(f"SH order must be an integer, got {order!r}")
    if not 0 <= order <= MAX_ORDER:
        raise ValueError(f"SH order must be in [0, {MAX_ORDER}], got {order}")
    return int(order)


def num_coeffs(order: int) -> int:
    """Number of SH coefficients up to and including band `order`."""
    order = check_order(order)
    return (order + 1) ** 2


def order_from_num_coeffs(n: int) -> int:
    """Inverse of num_coeffs; ValueError unless n is a perfect square."""
    root = math.isqrt(int(n)) if n >= 1 else 0
    if n < 1 or root * root != n:
        raise ValueError(f"{n} SH coefficients is not (order+1)^2 for any order")
    return root - 1
