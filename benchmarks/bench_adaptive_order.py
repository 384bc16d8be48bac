"""Adaptive SH order: which order each bundled light needs, the shading error of
that order and of always N=4 against order 8, and the relight cost per order.
Prints markdown tables (docs/TRADEOFFS.md, "Adaptive SH order").

    PYTHONPATH=. .venv/bin/python benchmarks/bench_adaptive_order.py [--fraction 0.99] [--repeat 7]

Error: a white, unoccluded Lambertian sphere (relight.network.prt.lambert_transport at
order 8, truncated) under each preset (normalized to mean luminance 0.8), at
20,000 Fibonacci normals; per normal and channel |s_N - s_8| / mean(s_8)
(relative to the mean reference shading, so dark normals do not divide by ~0).
Time: albedo * (T . L) + E . L on a 512x512 decomposition-sized float32 array
(T, E [262144, n]), median of --repeat runs.
"""

from __future__ import annotations

import argparse
import os
import platform

import numpy as np

from farm.rendering.bake import fibonacci_directions
from relight.lighting import presets, sh, sh_adaptive
from relight.lighting.light import sh_light
from relight.network.prt import lambert_transport
from timing import median_ms  # benchmarks/timing.py

REF_ORDER = 8
FIXED_ORDER = 4


def shading_errors(coeffs8: np.ndarray, T8: np.ndarray, order: int) -> tuple[float, float]:
    """(mean, max) of |s_order - s_8| / mean(s_8) over normals and channels."""
    ref = T8 @ coeffs8
    n = sh.num_coeffs(order)
    approx = T8[:, :n] @ coeffs8[:n]
    rel = np.abs(approx - ref) / ref.mean(axis=0)
    return float(rel.mean()), float(rel.max())


def relight_ms(order: int, repeat: int, pixels: int = 512 * 512) -> float:
    rng = np.random.default_rng(order)
    n = sh.num_coeffs(order)
    albedo = rng.uniform(0, 1, (pixels, 3)).astype(np.float32)
    T = rng.normal(0, 0.3, (pixels, n)).astype(np.float32)
    E = rng.normal(0, 0.05, (pixels, n)).astype(np.float32)
    L = rng.normal(0, 0.3, (n, 3)).astype(np.float32)

    def once():
        out = albedo * (T @ L)
        out += E @ L
        return out

    return median_ms(once, repeat)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fraction", type=float, default=0.99)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()

    normals = fibonacci_directions(20_000)
    T8 = lambert_transport(normals, REF_ORDER)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"numpy {np.__version__}; fraction {args.fraction}\n")
    print(f"| preset | required order | mean err (required) | max err (required) "
          f"| mean err (N={FIXED_ORDER}) | max err (N={FIXED_ORDER}) |")
    print("|---|---|---|---|---|---|")
    orders = []
    for name in presets.list_presets():
        c8 = sh_light(name, REF_ORDER)
        need = sh_adaptive.required_order(c8, args.fraction)
        orders.append(need)
        m_req, x_req = shading_errors(c8, T8, need)
        m_fix, x_fix = shading_errors(c8, T8, FIXED_ORDER)
        print(f"| {name} | {need} | {m_req:.2e} | {x_req:.2e} | {m_fix:.2e} | {x_fix:.2e} |")
    print(f"\nrequired orders: min {min(orders)}, median {int(np.median(orders))}, max {max(orders)}\n")

    print("| order | coefficients | relight 512x512 (ms) | ratio to N=4 |")
    print("|---|---|---|---|")
    times = {o: relight_ms(o, args.repeat) for o in range(REF_ORDER + 1)}
    for o, ms in times.items():
        print(f"| {o} | {sh.num_coeffs(o)} | {ms:.1f} | {ms / times[FIXED_ORDER]:.2f} |")


if __name__ == "__main__":
    main()
