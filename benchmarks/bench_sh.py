"""Benchmark relight.lighting.sh: equirect projection and rotation. Prints markdown tables.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_sh.py [--repeat 15]

Times are the median of --repeat runs (after one warm-up run that builds the
cached per-resolution tables, reported separately as "first call").
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from relight.lighting import sh, sh_projection, sh_rotation
import timing  # benchmarks/timing.py


def median_ms(fn, repeat: int) -> float:
    return timing.median_ms(fn, repeat, warmup=0)


def bench_projection(repeat: int) -> None:
    H, W = 1024, 2048
    rng = np.random.default_rng(0)
    # a map with HDR range: smooth sky plus a small, very bright sun
    img = (rng.random((H, W, 3)) * 2.0).astype(np.float32)
    img[100:110, 500:510] = 5.0e4
    print(f"### Projection of a {W}x{H} float32 RGB map\n")
    print("| order | coeffs | first call (ms) | float32 (ms) | float64 (ms) | max rel. error float32 |")
    print("|---|---|---|---|---|---|")
    for order in (2, 4, 8):
        sh_projection._projection_tables.cache_clear()
        t = time.perf_counter()
        sh_projection.project_equirect(img, order)
        first = 1e3 * (time.perf_counter() - t)
        t32 = median_ms(lambda: sh_projection.project_equirect(img, order), repeat)
        t64 = median_ms(lambda: sh_projection.project_equirect(img, order, precision="float64"), repeat)
        c32 = sh_projection.project_equirect(img, order)
        c64 = sh_projection.project_equirect(img, order, precision="float64")
        err = np.abs(c32 - c64).max() / np.abs(c64).max()
        print(f"| {order} | {sh.num_coeffs(order)} | {first:.1f} | {t32:.1f} | {t64:.1f} | {err:.1e} |")
    print()


def bench_naive_baseline(repeat: int) -> None:
    """The textbook way (basis at every texel, weighted sum) against the
    separable path, on a map small enough for the full basis table."""
    H, W, order = 512, 1024, 4
    img = np.random.default_rng(2).random((H, W, 3)).astype(np.float32)

    def naive():
        dirs, omega = sh_projection.equirect_directions(H, W)
        basis = sh.sh_basis(dirs, order)  # [H, W, n] float64
        return np.einsum("hwk,hwc,h->kc", basis, np.maximum(img, 0), omega, optimize=True)

    def batched_matmul():
        # separable too, but channel-major copy + numpy's batched 3D matmul
        # (a loop of H small GEMMs): the previous implementation
        azimuth, rows = sh_projection._projection_tables(H, W, order)
        rgb = np.ascontiguousarray(np.maximum(img, 0).transpose(0, 2, 1))
        per_row = np.matmul(rgb, azimuth.astype(np.float32))
        return np.einsum("hka,hca->kc", rows, per_row.astype(np.float64))

    t_naive = median_ms(naive, max(3, repeat // 3))
    t_batched = median_ms(batched_matmul, repeat)
    t_fast = median_ms(lambda: sh_projection.project_equirect(img, order), repeat)
    reference = naive()
    err = np.abs(reference - sh_projection.project_equirect(img, order)).max() / np.abs(reference).max()
    err_b = np.abs(reference - batched_matmul()).max() / np.abs(reference).max()
    print(f"### Projection methods compared ({W}x{H}, order {order}, one run)\n")
    print("| method | time (ms) | speed-up | max rel. difference to per-texel |")
    print("|---|---|---|---|")
    print(f"| per-texel basis, float64 | {t_naive:.1f} | 1 | 0 |")
    print(f"| separable, transpose + batched 3D matmul | {t_batched:.1f} | {t_naive / t_batched:.0f}x | {err_b:.1e} |")
    print(f"| project_equirect: separable, one 2D GEMM | {t_fast:.1f} | {t_naive / t_fast:.0f}x | {err:.1e} |")
    print()


def bench_rotation(repeat: int) -> None:
    rng = np.random.default_rng(1)
    q = rng.normal(size=(10_000, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    Rs = np.stack(
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
         2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
         2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=-1
    ).reshape(-1, 3, 3)
    print("### Rotation matrices (Ivanic-Ruedenberg recurrence)\n")
    print("| order | one rotation (ms) | rotate [n,3] coeffs (ms) | 10,000 rotations batched (ms) "
          "| per rotation in batch (us) |")
    print("|---|---|---|---|---|")
    for order in (2, 4, 8):
        c = rng.normal(size=(sh.num_coeffs(order), 3))
        one = median_ms(lambda: sh_rotation.rotation_matrix(Rs[0], order), repeat * 10)
        rot = median_ms(lambda: sh_rotation.rotate(c, Rs[0]), repeat * 10)
        batch = median_ms(lambda: sh_rotation.rotation_matrix(Rs, order), max(3, repeat // 5))
        print(f"| {order} | {one:.3f} | {rot:.3f} | {batch:.0f} | {1e3 * batch / len(Rs):.1f} |")
    print()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15)
    args = parser.parse_args()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"numpy {np.__version__}, {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} CPUs, load average {load:.1f} at start\n")
    bench_projection(args.repeat)
    bench_naive_baseline(args.repeat)
    bench_rotation(args.repeat)


if __name__ == "__main__":
    main()
