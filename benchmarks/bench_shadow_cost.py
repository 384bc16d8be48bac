"""The cost of the cast-shadow pass per preset at 512 x 512 (docs/TRADEOFFS.md, "Cast shadows"), in ms,
best of 3: decompose, relight, relight with shadows on a fresh decomposition's first key (the relief
and the visibility made), and again under the same key (both kept).

    PYTHONPATH=. .venv/bin/python benchmarks/bench_shadow_cost.py
"""

from __future__ import annotations

import os
import time

from relight.files.photo import read_photo
from relight.imaging.resample import resize_linear
from relight.lighting.lamps import sun_light
from relight.network.quality import PRESETS
from relight.network.runtime import Relighter
from relight.network.shadowing import ShadowCaster


def best_ms(run, repeats: int = 3) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times) * 1e3


def main() -> int:
    photo, _ = read_photo("relight/data/examples/astronaut.jpg")
    photo = resize_linear(photo, 512, 512)  # in linear, as bench_presets.py (the bundled photo is 512 x 512 already)
    light = sun_light(90.0, 10.0, 5.0, 4) * 3.0
    print(f"load average {os.getloadavg()[0]:.1f}")
    print("| preset | decompose | relight | relight --shadows, first | relight --shadows, key seen before |")
    print("|---|---|---|---|---|")
    for q in PRESETS:
        relighter = Relighter(working_size=q.working_size)
        options = q.decompose_options(working_size=False)
        d = relighter.decompose(photo, **options)

        def first():
            d.shadows = ShadowCaster(d.transport, d.alpha, d._matte)  # nothing kept: relief and visibility anew
            d.relight(light, shadows=True)

        decompose = best_ms(lambda: relighter.decompose(photo, **options))
        plain = best_ms(lambda: d.relight(light))
        fresh = best_ms(first)
        seen = best_ms(lambda: d.relight(light, shadows=True))
        print(f"| {q.label} | {decompose:.0f} | {plain:.0f} | {fresh:.0f} | {seen:.0f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
