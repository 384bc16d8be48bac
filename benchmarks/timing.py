"""The benchmarks' one timer: median wall milliseconds of a call."""

from __future__ import annotations

import statistics
import time


def median_ms(fn, repeats: int, warmup: int = 1) -> float:
    """Median wall milliseconds of fn() over `repeats` runs, after `warmup` untimed runs."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)
