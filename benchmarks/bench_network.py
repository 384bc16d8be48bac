"""Cost of RelightNet layouts: params, fp32 ONNX size, GFLOP, onnxruntime latency, training speed.

    .venv/bin/python benchmarks/bench_network.py [--configs paper default small ...]
        [--sizes 256 512] [--repeats 3] [--train-size 128] [--no-train]

Each config (a PRESETS name or one of the ablation layouts below) gets seeded
random weights (latency does not depend on the values), is exported to fp32
ONNX with export.onnx_export, and is timed with onnxruntime (CPU provider,
batch 1, median of --repeats runs after one warm-up) at every size with 1 and
2 intra-op threads, all in one run so the ratios share the machine's load.
GFLOP are counted by torch.utils.flop_counter (2 per multiply-add). Prints a
Markdown table for docs/benchmarks/model.md.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]

from model.networks.network import PAPER_CONFIG, PRESETS, RelightNet  # noqa: E402

# Steps from the paper layout to the default one, one change at a time.
LAYOUTS = {
    "paper": PAPER_CONFIG,
    "paper + shared parts": {**PAPER_CONFIG, "shared_parts": True},
    "paper + shared parts + 1 full-res conv": {**PAPER_CONFIG, "shared_parts": True, "full_res_convs": 1},
    "width 16, decoder 8, shared, 1 full-res conv": {**PRESETS["default"], "width": 16, "decoder_width": 8},
    "default": PRESETS["default"],
    "default, separable convs": {**PRESETS["default"], "separable": True},
    "default, decoder 4": {**PRESETS["default"], "decoder_width": 4},
    "small": PRESETS["small"],
}


def gflop(net: RelightNet, size: int) -> float:
    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as counter, torch.no_grad():
        net.eval()(torch.zeros(1, 3, size, size))
    return counter.get_total_flops() / 1e9


def ort_ms(path: Path, size: int, threads: int, repeats: int) -> float:
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    sess = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    x = np.random.default_rng(0).uniform(-1, 1, (1, 3, size, size)).astype(np.float32)
    sess.run(None, {"image": x})  # first run at a shape plans the memory
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        sess.run(None, {"image": x})
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--configs", nargs="*", default=list(LAYOUTS), help=f"from {list(LAYOUTS)}")
    p.add_argument("--sizes", type=int, nargs="*", default=[256, 512])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--train-size", type=int, default=128)
    p.add_argument("--no-train", action="store_true")
    args = p.parse_args()
    unknown = [c for c in args.configs if c not in LAYOUTS]
    if unknown:
        p.error(f"unknown configs {unknown}; choose from {list(LAYOUTS)}")
    import onnxruntime as ort

    from export.random_model import export_random_model

    print(f"torch {torch.__version__}, onnxruntime {ort.__version__}, {platform.machine()}, "
          f"batch 1, median of {args.repeats}\n")
    cols = [f"GFLOP {s}" for s in args.sizes]
    cols += [f"ORT ms {s}, {t} thr" for s in args.sizes for t in (1, 2)]
    if not args.no_train:
        cols.append(f"train img/s {args.train_size} (1 thr)")
    print("| config | params (M) | ONNX MB | " + " | ".join(cols) + " |")
    print("|---" * (len(cols) + 3) + "|")
    with tempfile.TemporaryDirectory() as tmp:
        for i, name in enumerate(args.configs):
            config = LAYOUTS[name]
            path, _, net = export_random_model(Path(tmp) / f"m{i}.onnx", seed=0, **config)
            params = sum(q.numel() for q in net.parameters()) / 1e6
            cells = [f"{gflop(net, s):.1f}" for s in args.sizes]
            cells += [f"{ort_ms(path, s, t, args.repeats):.0f}" for s in args.sizes for t in (1, 2)]
            if not args.no_train:
                from bench_train import time_training

                torch.set_num_threads(1)
                ips, _, _, _ = time_training(config, 2, args.train_size, 2)
                cells.append(f"{ips:.2f}")
            mb = path.stat().st_size / 2 ** 20
            print(f"| {name} | {params:.2f} | {mb:.1f} | " + " | ".join(cells) + " |", flush=True)
            path.unlink()


if __name__ == "__main__":
    main()
