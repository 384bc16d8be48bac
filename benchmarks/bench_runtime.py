"""Runtime benchmark: decomposition time, relighting cost per megapixel, peak memory.

    .venv/bin/python benchmarks/bench_runtime.py [--repeats 3] [--sizes 256 512 1024] [--quick]
                                                 [--skip ...] [--baseline REV]

Uses the default RelightNet config (model.networks.network.PRESETS["default"]) with seeded
random weights (timings do not depend on the weight values), exported to fp32
and fp16 ONNX in a temporary folder. Prints Markdown tables (medians).
"""

from __future__ import annotations

import argparse
import inspect
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _median_time(fn, repeats: int, warmup: bool = True) -> float:
    if warmup:
        fn()  # first run at a shape allocates and plans
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _photo(h: int, w: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(0.05, 0.9, (h, w, 3)).astype(np.float32)


def bench_decompose(models: dict, sizes, repeats: int) -> list[str]:
    """Decomposition of a size x size photo (working size = photo size). Above 512 px
    one cold run per cell (a warm-up would double a minute-long measurement)."""
    from relight.network.runtime import Relighter

    rows = ["| photo (px) | precision | threads | decompose, mask given (ms) | decompose, no mask: + matte pass at 256 (ms) |",
            "|---|---|---|---|---|"]
    for size in sizes:
        photo = _photo(size, size)
        mask = np.ones((size, size), np.float32)
        warm = size <= 512
        for precision, path in models.items():
            for threads in (1, 2):
                r = Relighter(path, threads=threads, working_size=size)
                with_mask = _median_time(lambda: r.decompose(photo, mask), repeats if warm else 1, warm)
                without = "-"
                if precision == "fp32" and threads == 2:
                    without = f"{_median_time(lambda: r.decompose(photo), repeats if warm else 1, warm) * 1e3:.0f}"
                rows.append(f"| {size} | {precision} | {threads} | {with_mask * 1e3:.0f} | {without} |")
                print(rows[-1], flush=True)
    return rows


def _gmac(net, size: int) -> float:
    """Multiply-accumulates of one forward pass at size x size (convolutions and linear layers)."""
    import torch

    total = 0

    def hook(module, _inputs, output):
        nonlocal total
        if isinstance(module, torch.nn.Conv2d):
            k = module.kernel_size[0] * module.kernel_size[1]
            total += output.numel() * module.in_channels * k // module.groups
        elif isinstance(module, torch.nn.Linear):
            total += module.in_features * module.out_features

    handles = [m.register_forward_hook(hook) for m in net.modules()]
    with torch.no_grad():
        net(torch.zeros(1, 3, size, size))
    for h in handles:
        h.remove()
    return total / 1e9


def bench_widths(tmp: Path, widths, size: int, repeats: int) -> list[str]:
    from export.random_model import export_random_model
    from relight.network.runtime import Relighter

    rows = [f"| width | params (M) | GMAC at {size}x{size} | decompose {size}x{size}, mask given, 2 threads (ms) |",
            "|---|---|---|---|"]
    photo = _photo(size, size)
    mask = np.ones((size, size), np.float32)
    for width in widths:
        path, _, net = export_random_model(tmp / f"w{width}.onnx", seed=0, width=width)
        r = Relighter(path, threads=2, working_size=size)
        t = _median_time(lambda: r.decompose(photo, mask), repeats)
        params = sum(p.numel() for p in net.parameters()) / 1e6
        rows.append(f"| {width} | {params:.2f} | {_gmac(net, size):.1f} | {t * 1e3:.0f} |")
        print(rows[-1], flush=True)
    return rows


def _paired_median_times(fns: dict, repeats: int) -> dict:
    """Median seconds of each callable, timed in alternation (a noisy machine's load
    drifts; alternating keeps the ratios between them honest)."""
    for fn in fns.values():
        fn()  # warm-up: first run at a shape allocates and plans
    times = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    return {name: statistics.median(ts) for name, ts in times.items()}


def _baseline_runtime(rev: str):
    """The Decomposition of git revision `rev`, imported as a separate module: relight/network/decomposition.py
    (relight/network/runtime.py before the two were split; today's runtime.py only re-exports it)."""
    import importlib.util

    for rel in ("relight/network/decomposition.py", "relight/network/runtime.py"):
        shown = subprocess.run(["git", "show", f"{rev}:{rel}"], cwd=ROOT, capture_output=True, text=True)
        if shown.returncode == 0:
            break
    else:
        raise SystemExit(f"--baseline {rev}: {shown.stderr.strip()}")
    path = Path(tempfile.mkdtemp()) / "runtime_baseline.py"
    path.write_text(shown.stdout)
    spec = importlib.util.spec_from_file_location("runtime_baseline", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def _as_baseline(module, d):
    """The same decomposition as an object of the baseline runtime (the fields both have)."""
    import dataclasses

    names = {f.name for f in dataclasses.fields(module.Decomposition) if f.init}
    names &= {f.name for f in dataclasses.fields(d) if f.init}
    names.discard("choices")
    return module.Decomposition(**{k: getattr(d, k) for k in names})


def _float16_dot(d, L, block: int = 4096):
    """albedo (T.L') + E.L' with T, E, albedo stored float16, cast to float32 per block of
    rows: the storage idea of issue 5, timed here because numpy 1.26 casts float16 in
    scalar code."""
    n = d._transport_m.shape[1]
    packed = np.concatenate([d._transport_m, d._residual_m, d._albedo_m], axis=1).astype(np.float16)
    L = np.asarray(L, np.float32)
    buf = np.empty((block, packed.shape[1]), np.float32)
    out = np.empty((packed.shape[0], 3), np.float32)

    def run():
        for i in range(0, packed.shape[0], block):
            m = min(block, packed.shape[0] - i)
            b = buf[:m]
            b[...] = packed[i:i + m]
            o = out[i:i + m]
            np.matmul(b[:, :n], L, out=o)
            o *= b[:, 2 * n:]
            o += b[:, n:2 * n] @ L
        return out

    return run, packed.nbytes


def bench_relight(model: Path, repeats: int, big: tuple[int, int], baseline: str | None) -> list[str]:
    from dataclasses import replace

    from relight.network.runtime import Relighter

    old = _baseline_runtime(baseline) if baseline else None
    old_turns = old is not None and "rotation_deg" in inspect.signature(old.Decomposition.relight_working).parameters

    def working(x, *args, **kwargs):
        """The relit person at working resolution (relit_at_working_size; relight_working in a baseline tree)."""
        method = getattr(x, "relit_at_working_size", None) or x.relight_working
        return method(*args, **kwargs)

    head = "| what | pixels | time (ms) | ms per megapixel |"
    rows = [head + (f" {baseline} (ms) | time / {baseline} |" if old else ""),
            "|---|---|---|---|" + ("---|---|" if old else "")]

    def row(what, px, fns, digits=1, times=repeats * 5):
        t = _paired_median_times(fns, times)
        line = f"| {what} | {px} | {t['new'] * 1e3:.{digits}f} | {t['new'] * 1e3 / (px / 1e6):.1f} |"
        if "old" in t:
            line += f" {t['old'] * 1e3:.{digits}f} | {t['new'] / t['old']:.2f} |"
        elif old:
            line += " - | - |"
        rows.append(line)
        print(line, flush=True)

    def pair(d, fn, old_fn=None):
        """{"new": fn(d), "old": old_fn (default fn) on the baseline's copy of d}."""
        fns = {"new": lambda: fn(d)}
        if old:
            d_old = _as_baseline(old, d)
            fns["old"] = lambda: (old_fn or fn)(d_old)
        return fns

    from relight.lighting.light import LightCache, sh_light

    cache = LightCache()
    r = Relighter(model, threads=2, working_size=512)
    ORDER = r.sh_order
    d = r.decompose(_photo(512, 512), np.ones((512, 512), np.float32))
    L = np.random.default_rng(1).normal(0, 0.3, (25, 3))
    L[0] = 3.0  # a light with a positive mean, like a normalized map
    px = 512 * 512
    row("dot product rho(T.L')+E.L' at working res (all pixels in matte)", px,
        pair(d, lambda x: working(x, L)))
    # reference for a memory-bound loop: copying the arrays the dot product reads
    src = np.concatenate([d._transport_m, d._residual_m, d._albedo_m], axis=1)
    dst = np.empty_like(src)
    row(f"reference: memcpy of T, E, albedo ({src.nbytes / 2**20:.0f} MiB float32)", px,
        {"new": lambda: np.copyto(dst, src)})
    half, nbytes = _float16_dot(d, L.astype(np.float32))
    row(f"the dot product with T, E, albedo stored float16 ({nbytes / 2**20:.0f} MiB), cast per 4096 rows",
        px, {"new": half})
    row("dot product, new rotation each call (cached matrix)", px,
        # this tree turns the light in relight.lighting.light (a cached matrix); a baseline from before
        # issue 19 inside relight_working (rotation_deg), a later one as this tree does
        pair(d, lambda x: working(x, sh_light(L, ORDER, rotation_deg=37.0, cache=cache)),
             (lambda x: x.relight_working(L, rotation_deg=37.0)) if old_turns else None))
    row("relight() full frame, crop == working size", px, pair(d, lambda x: x.relight(L)))
    H, W = big
    photo = _photo(H, W, seed=2)
    mask = np.ones((H, W), np.float32)
    d = r.decompose(photo, mask)
    del mask
    size = f"{W}x{H} photo, working {d.working_size[1]}x{d.working_size[0]}"
    for detail in (True, False):
        row(f"relight() {size}, mask given, detail={detail}", H * W,
            pair(d, lambda x, detail=detail: x.relight(L, detail=detail)), digits=0, times=repeats)
    # the network's matte instead of a user mask: alpha is upsampled too
    matte = replace(d, mask=None)
    row(f"relight() {size}, predicted matte, detail=True", H * W,
        pair(matte, lambda x: x.relight(L)), digits=0, times=repeats)
    return rows


CHILD = r"""
import resource, sys, time
from relight.cli import main
t0 = time.perf_counter()
code = main(sys.argv[1:])
print("SECONDS", time.perf_counter() - t0)
# VmHWM: this process image's own peak (ru_maxrss keeps the parent's RSS at fork across exec)
print("PEAK_RSS_KIB", next(l for l in open("/proc/self/status") if l.startswith("VmHWM")).split()[1])
sys.exit(code)
"""


def bench_memory(model: Path, tmp: Path, big: tuple[int, int]) -> list[str]:
    from PIL import Image

    H, W = big
    rgb = (_photo(H, W, seed=3) * 255).astype(np.uint8)
    Image.fromarray(rgb).save(tmp / "big.jpg", quality=90)
    del rgb
    rows = ["| command | wall (s) | peak RSS (MiB) |", "|---|---|---|"]
    for extra in ([], ["--quality", "best"]):
        argv = ["image", str(tmp / "big.jpg"), "--light", "studio", "--model", str(model),
                "--out", str(tmp / "big_relit.png"), "--matte", "network", *extra]  # noise shows no person
        res = subprocess.run([sys.executable, "-c", CHILD, *argv], capture_output=True, text=True,
                             cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
        if res.returncode != 0:
            raise SystemExit(res.stderr)
        secs = float(res.stdout.split("SECONDS")[1].split()[0])
        peak = int(res.stdout.split("PEAK_RSS_KIB")[1].split()[0]) / 1024
        rows.append(f"| relight image {W}x{H} JPEG -> PNG {' '.join(extra)} | {secs:.1f} | {peak:.0f} |")
        print(rows[-1], flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sizes", type=int, nargs="+", default=[256, 512, 1024])
    parser.add_argument("--quick", action="store_true", help="smaller big photo (2000x1500)")
    parser.add_argument("--widths", type=int, nargs="*", default=[8, 16, 32],
                        help="RelightNet widths for the network-cost table at 512 px")
    parser.add_argument("--skip", nargs="*", default=[], choices=["decompose", "widths", "relight", "memory"])
    parser.add_argument("--baseline", metavar="REV", default=None,
                        help="also time relight/network/decomposition.py (relight/network/runtime.py before their split) "
                             "of this git revision (e.g. HEAD), alternating with the working tree's, "
                             "and print the ratio")
    args = parser.parse_args()
    from export.fp16 import export_fp16
    from export.random_model import export_random_model

    big = (2000, 1500) if args.quick else (6000, 4000)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        fp32, _, _ = export_random_model(tmp / "default.onnx", seed=0)  # default config
        fp16, _ = export_fp16(fp32, tmp / "default.fp16.onnx")
        print(f"# runtime benchmark: {platform.processor() or platform.machine()}, "
              f"{os.cpu_count()} CPUs, onnxruntime {__import__('onnxruntime').__version__}, "
              f"model {fp32.stat().st_size / 2**20:.1f} MiB fp32 / {fp16.stat().st_size / 2**20:.1f} MiB fp16; "
              f"load average at start {os.getloadavg()[0]:.1f}\n")
        tables = []
        if "decompose" not in args.skip:
            tables.append(bench_decompose({"fp32": fp32, "fp16": fp16}, args.sizes, args.repeats))
        if "widths" not in args.skip and args.widths:
            tables.append(bench_widths(tmp, args.widths, 512, args.repeats))
        if "relight" not in args.skip:
            tables.append(bench_relight(fp32, args.repeats, big, args.baseline))
        if "memory" not in args.skip:
            tables.append(bench_memory(fp32, tmp, big))
        print(f"(load average at end {os.getloadavg()[0]:.1f})")
        print()
        for t in tables:
            print("\n".join(t) + "\n")
        print(f"(this process: peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB)")


if __name__ == "__main__":
    main()
