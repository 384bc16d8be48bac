"""What each quality preset costs on a photo: decomposition (the preset's working size,
network runs, refinement and person segmenter; with a mask and with the segmenter finding
the person) and one relight.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_presets.py [--size 512] [--threads 2] [--repeats 7]

Uses the shipped models (relight/network/quality.py names them) on the bundled photo
relight/data/examples/astronaut.jpg resized to --size x --size. Times are medians
of --repeats after a warm-up, the presets timed in alternation so that a load
drifting on a shared machine shifts them alike (compare ratios).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from relight.files import photo as photo_io  # noqa: E402
from relight.network import quality  # noqa: E402
from relight.lighting.light import sh_light  # noqa: E402
from relight.imaging.resample import resize_linear  # noqa: E402
from relight.network.runtime import Relighter  # noqa: E402


def _row(preset, ms: list[float]) -> str:
    """The table's row of `preset`: its settings, then the median milliseconds of decompose with the
    mask given, decompose with the person segmenter and relight, and the last two together."""
    return (f"| {preset.label} | {preset.model} | {preset.working_size} | {len(preset.augment) + 1} | "
            f"{preset.refine} | {preset.matte_method} | {ms[0]:.0f} | {ms[1]:.0f} | {ms[2]:.0f} | "
            f"{ms[1] + ms[2]:.0f} |")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--repeats", type=int, default=7)
    args = p.parse_args(argv)
    image = photo_io.read_photo(ROOT / "relight" / "data" / "examples" / "astronaut.jpg")[0]
    image = resize_linear(image, args.size, args.size)
    mask = np.zeros(image.shape[:2], np.float32)
    mask[args.size // 8: -args.size // 16, args.size // 8: -args.size // 8] = 1.0
    runs = {}
    for preset in quality.PRESETS:
        r = Relighter(quality.model_path(preset.key), threads=args.threads, working_size=preset.working_size)
        options = preset.decompose_options()
        d = r.decompose(image, mask, **options)
        runs[(preset.label, "decompose, mask given")] = lambda r=r, o=options: r.decompose(image, mask, **o)
        runs[(preset.label, "decompose, person segmenter")] = \
            lambda r=r, o=options: r.decompose(image, matte="person", **o)
        light = sh_light("sunset", d.sh_order)
        runs[(preset.label, "relight (full size)")] = lambda d=d, light=light: d.relight(light)
    for fn in runs.values():
        fn()
    times = {k: [] for k in runs}
    for _ in range(args.repeats):
        for k, fn in runs.items():
            t0 = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t0)
    print(f"# presets on a {args.size}x{args.size} photo, {args.threads} onnxruntime threads, "
          f"median of {args.repeats} (load average {os.getloadavg()[0]:.1f})\n")
    print("| preset | model | working size | runs | refine | segmenter | decompose, mask given (ms) "
          "| decompose, person segmenter (ms) | relight (ms) | segmenter to relit photo (ms) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for preset in quality.PRESETS:
        print(_row(preset, [statistics.median(times[(preset.label, k)]) * 1e3 for k in
                            ("decompose, mask given", "decompose, person segmenter", "relight (full size)")]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
