"""Training throughput (images/s): forward + all losses + backward + AdamW step.

    .venv/bin/python benchmarks/bench_train.py [--size 256] [--batch 4] [--steps 3] [--variants]
        [--preset default|small|paper] [--width W]
    .venv/bin/python benchmarks/bench_train.py --geometry geo-default --size 128 --batch 8 --steps 6 \
        [--data data/train128 --pack runs/pack128.npz] [--compile] [--bf16]

--geometry times the geometry-first GeometryNet (the shipped model) with its
training losses under the CPU settings that matter: torch threads (1 = how the
comparison trainings ran, two at a time; 2 = both cores in one run), the light
fit's precision in training (float64 before issue 25, float32 now) and its pixel
stride (--fit-stride), channels-last memory format, torch.compile and bf16.

Random inputs with the shapes of real samples, or with --pack the batches of
model.train's own data module (the data pipeline inside the timed step). Prints a
markdown table; copy it with the command into docs/benchmarks/model.md.
"""

from __future__ import annotations

import argparse
import platform
import time

import torch

from model.training.losses import LossWeights, relight_losses
from model.networks.network import PRESETS, RelightNet


def fake_batch(batch: int, size: int, n: int) -> dict:
    g = torch.Generator().manual_seed(0)
    r = lambda *s: torch.rand(*s, generator=g)
    alpha = (r(batch, 1, size, size) > 0.3).float()
    return {"input": r(batch, 3, size, size) * 2 - 1, "albedo": r(batch, 3, size, size),
            "transport": r(batch, n, size, size) - 0.5, "light": r(batch, n, 3), "alpha": alpha,
            "image": r(batch, 3, size, size), "target_light": r(batch, n, 3), "target_image": r(batch, 3, size, size)}


def forward_gflop(model: RelightNet, size: int) -> float:
    """Forward-pass GFLOP (2 per multiply-add) of one size x size image: load-independent."""
    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as counter, torch.no_grad():
        model.eval()(torch.zeros(1, 3, size, size))
    return counter.get_total_flops() / 1e9


def time_training(config: dict, batch: int, size: int, steps: int, warmup: int = 1):
    torch.manual_seed(0)
    model = RelightNet(**config)
    gflop = forward_gflop(model, size)
    model.train()
    opt = torch.optim.AdamW(model.parameters(), lr=5e-5)
    data = fake_batch(batch, size, model.n)
    weights = LossWeights()
    times = []
    for i in range(warmup + steps):
        t0 = time.perf_counter()
        terms = relight_losses(model(data["input"]), data, weights, decomposition=model.decomposition,
                               tstar=model.tstar)
        opt.zero_grad()
        terms["total"].backward()
        opt.step()
        if i >= warmup:
            times.append(time.perf_counter() - t0)
    model.eval()
    with torch.no_grad():
        model(data["input"][:1])
        t0 = time.perf_counter()
        model(data["input"][:1])
        infer = time.perf_counter() - t0
    step = sorted(times)[len(times) // 2]
    return batch / step, infer, sum(p.numel() for p in model.parameters()), gflop


def geometry_batch(batch: int, size: int, n: int) -> dict:
    g = torch.Generator().manual_seed(0)
    r = lambda *s: torch.rand(*s, generator=g)
    normal = torch.nn.functional.normalize(r(batch, 3, size, size) - 0.5, dim=1)
    return {"input": r(batch, 3, size, size) * 2 - 1, "albedo": r(batch, 3, size, size),
            "transport": r(batch, n, size, size) - 0.5, "light": r(batch, n, 3),
            "alpha": (r(batch, 1, size, size) > 0.3).float(), "normal": normal, "image": r(batch, 3, size, size),
            "target_light": r(batch, n, 3), "target_image": r(batch, 3, size, size)}


def time_geometry(preset: str, batch: int, size: int, steps: int, threads: int, channels_last: bool,
                  compiled: bool, warmup: int = 2, bf16: bool = False, fit_stride: int = 1,
                  fit_float64: bool = False, loader=None) -> float:
    """Median images/s of GeometryNet training steps (the losses of model.networks.geometry); `loader`:
    batches from the real data pipeline (timed with the step), else one random batch."""
    from model.networks.geometry import GEOMETRY_PRESETS, GeometryNet, geometry_losses
    from model.train import loss_weights_from_args, parse_args

    torch.set_num_threads(threads)
    torch.manual_seed(0)
    model = GeometryNet(sh_order=4, fit_stride=fit_stride, **GEOMETRY_PRESETS[preset])
    if fit_float64:  # training as it was before issue 25: the light fit in float64
        model.train_fit_precision = torch.float64
    weights = loss_weights_from_args(parse_args(["--data", ".", "--out", ".", "--preset", preset]))
    data = geometry_batch(batch, size, 25)
    batches = iter(loader) if loader is not None else None
    if channels_last:
        model = model.to(memory_format=torch.channels_last)
        data["input"] = data["input"].contiguous(memory_format=torch.channels_last)
    model.train()
    step_model = torch.compile(model) if compiled else model
    opt = torch.optim.AdamW(model.parameters(), lr=1e-4)
    times = []
    for i in range(warmup + steps):
        t0 = time.perf_counter()
        if batches is not None:
            data = next(batches)
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            pred = step_model(data["input"])
        terms = geometry_losses({k: v.float() for k, v in pred.items()}, data, weights)
        opt.zero_grad()
        terms["total"].backward()
        opt.step()
        if i >= warmup:
            times.append(time.perf_counter() - t0)
    return batch / sorted(times)[len(times) // 2]


def geometry_table(args) -> None:
    import os

    print(f"torch {torch.__version__}, {platform.processor() or platform.machine()}, GeometryNet {args.geometry}, "
          f"{args.size}x{args.size}, batch {args.batch}, median of {args.steps} steps after 2 warm-ups, "
          f"load average before {os.getloadavg()[0]:.2f}\n")
    loader = None
    if args.pack:  # the real pipeline: model.train's data module on the pack, its augmentations
        from pathlib import Path

        from model.training.train_data import SceneDataModule

        data = SceneDataModule([args.data], size=args.size, order=4, batch=args.batch, seed=1, pack=Path(args.pack),
                               augment={"light_tint": 0.15}, workers=args.workers)
        data.prepare_data()
        data.setup("fit")
        loader = data.train_dataloader()
        print(f"batches from model.train's data module on {args.pack} ({args.data}), "
              f"{args.workers} loader worker processes\n")
    print("| threads | light fit in training | fit stride | channels-last | torch.compile | bf16 autocast "
          "| train images/s | ratio to 1 thread, before | ratio to 2 threads, before |")
    print("|---|---|---|---|---|---|---|---|---|")
    yes = lambda flag: "yes" if flag else "no"
    # (threads, float64 fit, fit stride, channels-last, compile, bf16): before issue 25's change, then after
    rows = [(1, True, 1, False, False, False), (2, True, 1, False, False, False),
            (1, False, 1, False, False, False), (1, False, 2, False, False, False),
            (2, False, 2, False, False, False), (2, False, 2, True, False, False)]
    if args.compile:  # minutes of compiling, and slower here: measured once (docs/benchmarks/model.md)
        rows.append((2, False, 2, False, True, False))
    if args.bf16:
        rows.append((2, False, 2, True, False, True))
    before = {}
    for threads, f64, stride, channels_last, compiled, bf16 in rows:
        ips = time_geometry(args.geometry, args.batch, args.size, args.steps, threads, channels_last, compiled,
                            bf16=bf16, fit_stride=stride, fit_float64=f64, loader=loader)
        if f64:
            before[threads] = ips
        print(f"| {threads} | {'float64' if f64 else 'float32'} | {stride} | {yes(channels_last)} | {yes(compiled)} "
              f"| {yes(bf16)} | {ips:.2f} | {ips / before[1]:.2f} | {ips / before.get(2, float('nan')):.2f} |",
              flush=True)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--batch", type=int, default=4)
    p.add_argument("--steps", type=int, default=3)
    p.add_argument("--preset", choices=sorted(PRESETS), default="default",
                   help="network layout (model.networks.network.PRESETS; paper: the heavy original)")
    p.add_argument("--width", type=int, help="override the preset's width")
    p.add_argument("--variants", action="store_true", help="also time the ablations")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    p.add_argument("--data", help="also time TrainingScenes items from this dataset folder")
    p.add_argument("--compile", action="store_true", help="with --geometry: also time torch.compile")
    p.add_argument("--bf16", action="store_true", help="with --geometry: also time bf16 autocast")
    p.add_argument("--pack", help="with --geometry and --data: batches from model.train's data module on this pack")
    p.add_argument("--workers", type=int, default=0, help="with --pack: the data module's loader processes")
    p.add_argument("--geometry", choices=("geo-small", "geo-default"),
                   help="time this GeometryNet preset under thread / channels-last / compile settings instead")
    args = p.parse_args()
    if args.geometry:
        geometry_table(args)
        return
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, {platform.processor() or platform.machine()}, "
          f"{args.size}x{args.size}, batch {args.batch}, median of {args.steps} steps after 1 warm-up\n")
    variants = {"full (order 4)": {}}
    if args.variants:
        variants.update({"without E": {"with_residual": False}, "without decomposition": {"decomposition": False},
                         "order 2": {"sh_order": 2}, "T*": {"tstar": True},
                         "Lambertian (KE-style, order 2)": {"with_residual": False, "decomposition": False,
                                                             "sh_order": 2}})
    print("| variant | params (M) | forward GFLOP/image | train images/s | ratio to full | inference s/image |")
    print("|---|---|---|---|---|---|")
    base = None
    for name, flags in variants.items():
        base_config = {**PRESETS[args.preset], **({"width": args.width} if args.width else {})}
        ips, infer, params, gflop = time_training({**base_config, **flags}, args.batch, args.size, args.steps)
        base = base or ips
        print(f"| {name} | {params / 1e6:.1f} | {gflop:.1f} | {ips:.3f} | {ips / base:.2f} | {infer:.3f} |",
              flush=True)
    if args.data:
        from model.samples.data import TrainingScenes
        from model.samples.data_augment import preset_training_lights
        from model.samples.data_splits import find_scenes
        from relight.lighting import presets

        ds = TrainingScenes(find_scenes(args.data), args.size, 4, extra_lights=preset_training_lights(4),
                            held_out=frozenset(presets.HELD_OUT))
        ds.item(0, 0)  # fills the crop cache for scene 0
        t0 = time.perf_counter()
        count = 20
        for e in range(count):
            ds.item(0, e + 1)
        print(f"\ndata: {count / (time.perf_counter() - t0):.1f} samples/s from a cached scene "
              f"(crop cache hit; a cache miss also reads and resizes the EXR)")


if __name__ == "__main__":
    main()
