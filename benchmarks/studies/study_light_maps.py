"""How the photo's light estimate grows with the number of HDR maps it was trained on.

    PYTHONPATH=. .venv/bin/python benchmarks/studies/study_light_maps.py --runs runs/maps --counts 2 4 8 16 23 \
        --heldout data/heldout256 --seen data/trainmaps256 [--train --jobs 2]

Each run is the release's recipe at the comparison budget (model.train: geo-default, 800 steps of
batch 8 at 128 px, fit stride 2, front-facing, light tint 0.15, seed 1, one thread), with every
input and target a PRT image (`--extra-light-prob 1`, so that the share of path-traced inputs does
not change with K) lit only by K of the training maps (`--light-maps K`: a nested choice, each set
inside the next). The same scenes, steps and seed for every K: only the number of maps differs.

Printed per K: on the held-out maps (`--heldout`), relit PSNR, SI PSNR, relit PSNR given the true
input light, the light gap between the two, and the input light's colour error; on scenes under
training maps (`--seen`, optional; best the held-out scenes themselves, rendered with the same
seed and `--light-pool train`), the light gap on the pairs whose input map was one of the K
against the pairs whose map was not. Then the held-out gap fitted against log2 K: what the next
doubling of maps would buy, and the K at which the gap would reach the issue's 2 dB if the line
held (an extrapolation, said as one). Last, per K and data set, the light's colour error regressed
on the true light's own colour: a slope near 1 says the estimate is grey.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

RECIPE = ["--preset", "geo-default", "--size", "128", "--batch", "8", "--lr", "1e-3", "--lr-schedule", "cosine",
          "--warmup", "100", "--light-tint", "0.15", "--fit-stride", "2", "--front-facing", "--threads", "1",
          "--seed", "1", "--val-every", "1000", "--ckpt-every", "400", "--extra-light-prob", "1.0", "--quiet"]


def train_and_evaluate(k: int, args) -> None:
    """Train run k (unless its weights exist) and evaluate it on each data set (unless done)."""
    run = Path(args.runs) / f"k{k}"
    py = sys.executable
    if not (run / "model.safetensors").is_file():
        with open(Path(args.runs) / f"k{k}.log", "w") as log:
            subprocess.run([py, "-m", "model.train", "--data", *args.data, "--pack", args.pack, "--out", str(run),
                            "--steps", str(args.steps), "--light-maps", str(k), *RECIPE],
                           stdout=log, stderr=subprocess.STDOUT, check=True)
    for name, data in (("eval", args.heldout), ("seen", args.seen)):
        out = Path(args.runs) / f"{name}_k{k}"
        if data and not (out / "evaluation.json").is_file():
            with open(Path(args.runs) / f"{name}_k{k}.txt", "w") as log:
                subprocess.run([py, "-m", "model.evaluate", str(run / "model.safetensors"), "--data", data,
                                "--size", "128", "--out", str(out), "--threads", "1", "--sheet-rows", "2"],
                               stdout=log, stderr=subprocess.STDOUT, check=True)


def maps_of(run: Path) -> set[str]:
    record = json.loads((run / "model.json").read_text())
    return set(record["training"]["light_maps"])


def gap(pairs: list[dict]) -> tuple[float, int]:
    """Mean of (relit PSNR given the true input light - relit PSNR) over `pairs`, and their count."""
    if not pairs:
        return float("nan"), 0
    return float(np.mean([p["true_light_psnr"] - p["relit_psnr"] for p in pairs])), len(pairs)


def rows(args) -> list[dict]:
    out = []
    for k in args.counts:
        run = Path(args.runs) / f"k{k}"
        held = json.loads((Path(args.runs) / f"eval_k{k}" / "evaluation.json").read_text())
        relit = held["methods"]["ours"]["relighting/image"]
        row = {"k": k, "relit": relit["psnr"], "si": relit["si_psnr"], "colour": held["geometry"]["ours"]["light_colour_deg"],
               "level": held["geometry"]["ours"]["relit_level_stops"]}
        row["gap"], _ = gap(held["per_pair"])
        row["true_light"] = row["relit"] + row["gap"]
        seen_json = Path(args.runs) / f"seen_k{k}" / "evaluation.json"
        if seen_json.is_file():
            maps = maps_of(run)
            pairs = json.loads(seen_json.read_text())["per_pair"]
            row["seen_in"] = gap([p for p in pairs if p["light_a"] in maps])
            row["seen_out"] = gap([p for p in pairs if p["light_a"] not in maps])
        out.append(row)
    return out


def colour_against_own_colour(evaluation: Path, data) -> tuple[float, float, float, float]:
    """(slope, intercept, correlation, the lights' mean own colour) of the pairs' light colour error (degrees) on the true input
    light's own colour (its DC colour's angle from grey, model.scoring.metrics.colour_cast_deg): slope 1
    and intercept 0 is a light read as grey whatever its colour."""
    from model.samples.data_splits import find_scenes
    from model.scoring.metrics import colour_cast_deg
    from relight.files.dataset import light_map_name, read_sidecar

    lights = {}
    for path in find_scenes(data):
        meta = read_sidecar(path)
        lights.update({(meta["index"], light_map_name(light)): light["sh"][0] for light in meta["lights"]})
    pairs = json.loads(Path(evaluation).read_text())["per_pair"]
    own = np.array([colour_cast_deg(lights[(p["scene"], p["light_a"])], (1.0, 1.0, 1.0)) for p in pairs])
    error = np.array([p["light_colour_deg"] for p in pairs])
    slope, intercept = np.polyfit(own, error, 1)
    return float(slope), float(intercept), float(np.corrcoef(own, error)[0, 1]), float(own.mean())


def fmt_gap(value: tuple[float, int]) -> str:
    g, n = value
    return "-" if n == 0 else f"{g:.2f} ({n})"


def report(table: list[dict]) -> str:
    lines = ["| maps K | relit PSNR | SI PSNR | with the true input light | light gap | light colour (deg) | "
             "relit level (stops) | gap, training-map scenes: map among the K (pairs) | the others (pairs) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in table:
        lines.append(f"| {r['k']} | {r['relit']:.2f} | {r['si']:.2f} | {r['true_light']:.2f} | {r['gap']:.2f} | "
                     f"{r['colour']:.1f} | {r['level']:.2f} | {fmt_gap(r.get('seen_in', (0, 0)))} | "
                     f"{fmt_gap(r.get('seen_out', (0, 0)))} |")
    k = np.log2([r["k"] for r in table])
    g = np.array([r["gap"] for r in table])
    slope, intercept = np.polyfit(k, g, 1)
    lines.append("")
    lines.append(f"held-out light gap = {intercept:.2f} {slope:+.2f} x log2 K (least squares over K = "
                 f"{', '.join(str(r['k']) for r in table)})")
    if slope < -0.05:  # dB per doubling: less is a flat line within round-off and run-to-run noise
        need = 2.0 ** ((2.0 - intercept) / slope)
        lines.append(f"if the line held, the gap would reach 2 dB at K = {need:.0f} maps (an extrapolation)")
    else:
        lines.append("the gap does not fall with K on this budget: more maps alone would not close it")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", default="runs/maps")
    p.add_argument("--counts", type=int, nargs="+", default=[2, 4, 8, 16, 23])
    p.add_argument("--heldout", default="data/heldout256")
    p.add_argument("--seen", default=None, help="scenes under training maps (for the gap on seen maps)")
    p.add_argument("--data", nargs="+", default=["data/train128", "data/train128b"])
    p.add_argument("--pack", default="runs/pack2.npz")
    p.add_argument("--steps", type=int, default=800)
    p.add_argument("--train", action="store_true", help="train and evaluate what is missing")
    p.add_argument("--jobs", type=int, default=2)
    args = p.parse_args(argv)
    if args.train:
        with ThreadPoolExecutor(args.jobs) as pool:
            list(pool.map(lambda k: train_and_evaluate(k, args), args.counts))
    print(report(rows(args)))
    print()
    for k in args.counts:
        for name, data in (("held-out maps", args.heldout), ("training maps", args.seen)):
            evaluation = Path(args.runs) / f"{'eval' if data == args.heldout else 'seen'}_k{k}" / "evaluation.json"
            if data and evaluation.is_file():
                slope, intercept, r, mean = colour_against_own_colour(evaluation, data)
                print(f"K = {k}, {name}: light colour error = {slope:.2f} x the light's own colour "
                      f"{intercept:+.1f} degrees (correlation {r:.2f}; the lights' own colour {mean:.1f} on average)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
