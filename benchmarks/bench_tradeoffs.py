"""Trade-offs (issue 8): time against error for each choice, with the Pareto front.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_tradeoffs.py --data HELD_OUT_DIR \\
        --model default=relight/models/default.onnx --model small=relight/models/small.onnx \\
        --model default-fp16=relight/models/default.fp16.onnx \\
        [--sizes 128,256,384,512,1024] [--orders 2,3,4,6] [--sections network,sh,directions,spp] \\
        [--doc docs/TRADEOFFS.md] [--plot docs/tradeoffs.png]

Sections (each replaces its own marked block of --doc, or is appended; the rest
of the document is kept):

* network: every --model (width preset, fp32/fp16) at every working size.
  Error: cross-light relighting over EvaluationPairs (model/samples/data.py) of the
  held-out scenes, cropped to --eval-size: the runtime (relight.network.runtime) decomposes
  the photo under light a with the GT alpha as mask, relights it to light b,
  and model.scoring.metrics compares that with the path-traced image under b over the
  person's pixels (PSNR, L1). Time: decompose (network at that working size,
  onnxruntime with --threads, 1 by default) plus relight, median of --repeats
  on the first pair.
* sh: the representation. GT transport truncated to order n relights the scene
  (albedo * (T_n . L_n)) against its path-traced image; time is the relight dot
  product for (n+1)^2 coefficients per megapixel (relight_ms).
  Orders above the data's SH order are skipped and named.
* directions, spp: the data side, from benchmarks/bench_bake.py (bake directions
  S against S = 4096; samples per pixel against 1024 spp).

A point is on the Pareto front when no other point of its table is at least as
fast and at least as accurate and strictly better in one of the two.
"""

from __future__ import annotations

import argparse
import datetime
import functools
import json
import os
import platform
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

SECTIONS = ("network", "sh", "directions", "spp")
DEFAULT_SIZES = (128, 256, 384, 512, 1024)
DEFAULT_ORDERS = (2, 3, 4, 6)
BALANCED_DB = 0.5  # proposal rule: Balanced is the fastest front point within this of the best PSNR
# "Interior" pixels as model/scoring/metrics.py defines them (why: the comment there); torch-free.
from model.scoring.metrics import INTERIOR_ALPHA, interior_weight  # noqa: E402
from timing import median_ms  # noqa: E402  (benchmarks/timing.py)


# ------------------------------------------------------------------ Pareto front


def pareto_front(times, errors) -> list[bool]:
    """True for each point (time, error) that no other point dominates (lower is better in
    both). Equal points do not dominate each other, so duplicates stay on the front together."""
    t = np.asarray(times, dtype=np.float64)
    e = np.asarray(errors, dtype=np.float64)
    if t.shape != e.shape or t.ndim != 1:
        raise ValueError(f"times and errors must be 1-D of equal length, got {t.shape} and {e.shape}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(e))):
        raise ValueError("times and errors must be finite")
    front = []
    for i in range(t.size):
        no_worse = (t <= t[i]) & (e <= e[i])
        better = (t < t[i]) | (e < e[i])
        front.append(not bool(np.any(no_worse & better)))
    return front


# ------------------------------------------------------------------ inputs


def parse_models(specs) -> dict[str, Path]:
    """{name: path} from "NAME=PATH" strings; names unique, files present."""
    out: dict[str, Path] = {}
    for spec in specs or []:
        name, sep, path = spec.partition("=")
        name = name.strip()
        if not sep or not name or not path:
            raise ValueError(f"--model {spec!r}: expected NAME=PATH.onnx")
        if any(c in name for c in "|\n"):
            raise ValueError(f"--model name {name!r}: '|' and line breaks would break the markdown table")
        if name in out:
            raise ValueError(f"--model name {name!r} is given twice")
        p = Path(path)
        if p.suffix != ".onnx" or not p.is_file():
            raise ValueError(f"--model {name}: {p} is not an .onnx file")
        out[name] = p
    return out


def int_list(text: str, what: str, lo: int, hi: int) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise ValueError(f"{what} must be a comma list of integers, got {text!r}") from None
    if not values or any(not lo <= v <= hi for v in values) or len(set(values)) != len(values):
        raise ValueError(f"{what} must be distinct integers in [{lo}, {hi}], got {text!r}")
    return values


# ------------------------------------------------------------------ network section


SAMPLE_KEYS = ("input_linear", "alpha", "target_light", "target_image")


def _numpy(item: dict) -> dict:
    return {k: (v.numpy() if hasattr(v, "numpy") else v) for k, v in item.items()}


def _hwc(chw: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.moveaxis(np.asarray(chw, dtype=np.float32), 0, -1))


def person_metrics(pred: np.ndarray, target: np.ndarray, alpha: np.ndarray) -> dict[str, float]:
    """model.scoring.metrics over the person: alpha-weighted ("psnr", "l1") and over the
    interior pixels, alpha > INTERIOR_ALPHA ("psnr_interior", "l1_interior")."""
    from model.scoring import metrics

    weighted = metrics.all_metrics(pred, target, alpha)
    interior = metrics.all_metrics(pred, target, interior_weight(alpha))
    return {"psnr": weighted["psnr"], "l1": weighted["l1"],
            "psnr_interior": interior["psnr"], "l1_interior": interior["l1"]}


def _mean_metrics(values: list[dict]) -> dict[str, float]:
    return {k: float(np.mean([v[k] for v in values])) for k in values[0]}


def network_points(models: dict[str, Path], data, sizes, *, eval_size: int | None = None, threads: int = 1,
                   repeats: int = 5, max_pairs: int = 64, max_pairs_per_scene: int = 4,
                   held_out_only: bool = False) -> tuple[dict, list[dict]]:
    """(info, rows): one row per (model, working size) with time and relighting error."""
    from model.samples.data import EvaluationPairs
    from model.samples.data_splits import find_scenes, held_out_light_names
    from relight.files.dataset import read_scene
    from relight.network.runtime import Relighter

    if not models:
        raise ValueError("the network section needs at least one --model NAME=PATH.onnx")
    scenes = find_scenes(data)
    if eval_size is None:
        eval_size = max(read_scene(scenes[0], verify_hash=False).resolution)
    pairs_by_order: dict[int, EvaluationPairs] = {}
    info = {"eval_size": eval_size, "scenes": len(scenes), "models": {}}
    rows = []
    for name, path in models.items():
        timed = Relighter(path, threads=threads)
        scorer = Relighter(path)  # all cores: the error does not depend on the thread count
        md = timed.metadata
        config = json.loads(md.get("relight.network_config", "{}") or "{}")
        info["models"][name] = {"path": str(path), "sha256": timed.sha256,
                                "training_data": md.get("relight.training_data", "?"),
                                "precision": md.get("relight.precision", "fp32"), "sh_order": timed.sh_order,
                                "width": config.get("width")}
        order = timed.sh_order
        if order not in pairs_by_order:
            pairs_by_order[order] = EvaluationPairs(scenes, eval_size, order, held_out_only=held_out_only,
                                                    held_out=held_out_light_names(),
                                                    max_pairs_per_scene=max_pairs_per_scene)
        pairs = pairs_by_order[order]
        count = min(len(pairs), max_pairs)
        # only what is used: a pair's transport at 1024 px alone is ~100 MB
        samples = [{k: v for k, v in _numpy(pairs[i]).items() if k in SAMPLE_KEYS} for i in range(count)]
        info["pairs"] = count
        for size in sizes:
            scores, upscale = [], []
            for s in samples:
                photo, alpha = _hwc(s["input_linear"]), _hwc(s["alpha"])[..., 0]
                d = scorer.decompose(photo, mask=alpha, working_size=size)
                relit = d.relight(s["target_light"].astype(np.float64))
                scores.append(person_metrics(relit, _hwc(s["target_image"]), alpha))
                y0, y1, x0, x1 = d.box
                upscale.append(max(d.working_size) / max(y1 - y0, x1 - x0))
            first = samples[0]
            photo, alpha = _hwc(first["input_linear"]), _hwc(first["alpha"])[..., 0]
            light = first["target_light"].astype(np.float64)
            decompose = functools.partial(timed.decompose, photo, mask=alpha, working_size=size)
            decompose_ms = median_ms(decompose, repeats)
            decomposition = decompose()
            relight_ms = median_ms(functools.partial(decomposition.relight, light), repeats)
            rows.append({"model": name, "precision": info["models"][name]["precision"],
                         "width": info["models"][name]["width"], "working_size": size,
                         "network_input": "x".join(map(str, decomposition.working_size)),
                         "upscale": float(np.median(upscale)), "decompose_ms": decompose_ms,
                         "relight_ms": relight_ms, "total_ms": decompose_ms + relight_ms,
                         **_mean_metrics(scores)})
    front = pareto_front([r["total_ms"] for r in rows], [-r["psnr_interior"] for r in rows])
    for r, f in zip(rows, front):
        r["front"] = f
    return info, rows


def propose_quality(rows: list[dict], balanced_db: float = BALANCED_DB) -> list[dict]:
    """Draft / Balanced / Best from the network front: the fastest front point, the fastest
    within `balanced_db` dB of the best interior PSNR, and the best (ties: the faster)."""
    front = sorted((r for r in rows if r["front"]), key=lambda r: (r["total_ms"], -r["psnr_interior"]))
    if not front:
        return []
    best = max(front, key=lambda r: (r["psnr_interior"], -r["total_ms"]))
    balanced = next(r for r in front if r["psnr_interior"] >= best["psnr_interior"] - balanced_db)
    return [dict(r, preset=p) for p, r in (("draft", front[0]), ("balanced", balanced), ("best", best))]


# ------------------------------------------------------------------ SH order section


def prt_image(scene, k: int, order: int) -> np.ndarray:
    """albedo * (T_n . L_n) [H, W, 3] of light k with transport and light cut to `order`."""
    from relight.network import prt
    from relight.lighting import sh

    n = sh.num_coeffs(order)
    light = np.asarray(scene.lights[k]["sh"], dtype=np.float64)[:n]
    return prt.render(scene.albedo, scene.transport[..., :n], None, light)


def relight_ms(order: int, repeat: int, pixels: int = 512 * 512) -> float:
    """Median ms of the relighting product albedo * (T L) + E L for `pixels` pixels at SH `order`."""
    rng = np.random.default_rng(order)
    n = (order + 1) ** 2
    albedo = rng.uniform(0, 1, (pixels, 3)).astype(np.float32)
    T = rng.normal(0, 0.3, (pixels, n)).astype(np.float32)
    E = rng.normal(0, 0.05, (pixels, n)).astype(np.float32)
    L = rng.normal(0, 0.3, (n, 3)).astype(np.float32)

    def once():
        out = albedo * (T @ L)
        out += E @ L
        return out

    return median_ms(once, repeat)


def sh_order_points(data, orders, *, repeat: int = 7, max_scenes: int = 64,
                    timing_pixels: int = 1_000_000) -> tuple[dict, list[dict]]:
    """(info, rows): per SH order, the GT-transport PRT image error and the relight cost per
    megapixel (timed on `timing_pixels` pixels, scaled to 10^6)."""
    from model.samples.data_splits import find_scenes
    from relight.files.dataset import has_transport, read_scene, read_sidecar, traced_lights

    paths = find_scenes(data)[:max_scenes]
    metas = [read_sidecar(p) for p in paths]
    usable = [p for p, m in zip(paths, metas) if has_transport(m) and traced_lights(m)]
    if not usable:
        raise ValueError(f"{data}: the SH section needs scenes with both transport and path-traced passes")
    data_order = min(int(m["sh_order"]) for p, m in zip(paths, metas) if p in usable)
    kept = [o for o in orders if o <= data_order]
    skipped = [o for o in orders if o > data_order]
    scores: dict[int, list[dict]] = {o: [] for o in kept}
    resolution = None
    for path in usable:  # one scene in memory at a time (49 transport planes at 1024 px are ~200 MB)
        s = read_scene(path)
        resolution = resolution or list(s.resolution)
        for order in kept:
            scores[order] += [person_metrics(prt_image(s, k, order), image, s.alpha[..., 0])
                              for k, image in enumerate(s.images)]
    rows = []
    for order in kept:
        rows.append({"order": order, "coeffs": (order + 1) ** 2, "images": len(scores[order]),
                     **_mean_metrics(scores[order]),
                     "relight_ms_per_mp": relight_ms(order, repeat, pixels=timing_pixels) * 1e6 / timing_pixels})
    if rows:
        front = pareto_front([r["relight_ms_per_mp"] for r in rows], [-r["psnr_interior"] for r in rows])
        for r, f in zip(rows, front):
            r["front"] = f
    info = {"data_order": data_order, "skipped": skipped, "scenes": len(usable), "resolution": resolution}
    return info, rows


# ------------------------------------------------------------------ data-side sections


def directions_points(counts, reference: int) -> tuple[str, list[dict]]:
    from bench_bake import directions_rows

    info, rows = directions_rows(counts, reference)
    for kind in {r["bake"] for r in rows}:  # one front per bake kind: they answer different questions
        group = [r for r in rows if r["bake"] == kind]
        for r, f in zip(group, pareto_front([r["seconds"] for r in group], [r["mean"] for r in group])):
            r["front"] = f
    return info, rows


def spp_points(resolution: int, counts, reference: int) -> tuple[str, list[dict]]:
    from bench_bake import spp_rows

    info, rows = spp_rows(resolution, counts, reference)
    for r, f in zip(rows, pareto_front([r["seconds"] for r in rows], [r["error"] for r in rows])):
        r["front"] = f
    return info, rows


# ------------------------------------------------------------------ markdown


INTERIOR_NOTE = (f"\"Interior\": pixels with GT alpha > {INTERIOR_ALPHA} (the Pareto front uses these, as "
                 "model/evaluate.py's default mask does); the plain columns weight every pixel by its alpha "
                 "(`model.evaluate --mask alpha`), edges included, where the target holds the other light's "
                 "background.")


def _mark(front: bool) -> str:
    return "**front**" if front else ""


def machine_line() -> str:
    import onnxruntime

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    when = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    return (f"Measured {when} on {platform.machine()}, {os.cpu_count()} cores (load average {load:.1f}), "
            f"numpy {np.__version__}, onnxruntime {onnxruntime.__version__}.")


def network_markdown(info: dict, rows: list[dict], threads: int, repeats: int) -> str:
    lines = ["## Network width, precision and working size", ""]
    random = [n for n, m in info["models"].items() if "random" in str(m["training_data"]).lower()]
    if random:
        lines += [(f"**Random-weight models ({', '.join(random)}): these figures test the tool's mechanics "
                   "and say nothing about quality.**"), ""]
    lines += [(f"Error: cross-light relighting of {info['pairs']} held-out pairs (model/samples/data.py "
              f"EvaluationPairs, {info['scenes']} scenes cropped to {info['eval_size']} px): runtime "
              "decompose with the GT alpha as mask, relight to light b, model.scoring.metrics against the path-traced "
              "image under b over the person's pixels. Time: decompose (network) + relight of the first pair, "
              f"onnxruntime {threads} thread(s), median of {repeats}. {INTERIOR_NOTE} Upscale > 1: the network saw the "
              "evaluation crop enlarged, so that size cannot show its finer detail; judging it needs data "
              "rendered at least that large."), ""]
    lines += ["| model | sha256 | precision | width | training data |", "|---|---|---|---|---|"]
    for name, m in info["models"].items():
        lines.append(f"| {name} | {m['sha256'][:12]} | {m['precision']} | {m['width']} | {m['training_data']} |")
    lines += ["", ("| model | precision | working size | network input | upscale | decompose ms | relight ms "
                   "| total ms | PSNR interior (dB) | L1 interior x100 | PSNR (dB) | L1 x100 | Pareto |"),
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: r["total_ms"]):
        lines.append(f"| {r['model']} | {r['precision']} | {r['working_size']} | {r['network_input']} "
                     f"| {r['upscale']:.2f} | {r['decompose_ms']:.1f} | {r['relight_ms']:.2f} "
                     f"| {r['total_ms']:.1f} | {r['psnr_interior']:.2f} | {100 * r['l1_interior']:.2f} "
                     f"| {r['psnr']:.2f} | {100 * r['l1']:.2f} | {_mark(r['front'])} |")
    proposal = propose_quality(rows)
    if proposal:
        lines += ["", (f"Rule for relight/network/quality.py (Draft: fastest front point; Balanced: fastest front point "
                       f"within {BALANCED_DB} dB of the best; Best: the best interior PSNR), applied to this table:"),
                  "",
                  "| preset | model | precision | working size | total ms | PSNR interior (dB) |",
                  "|---|---|---|---|---|---|"]
        for p in proposal:
            lines.append(f"| {p['preset']} | {p['model']} | {p['precision']} | {p['working_size']} "
                         f"| {p['total_ms']:.1f} | {p['psnr_interior']:.2f} |")
    return "\n".join(lines) + "\n"


def sh_markdown(info: dict, rows: list[dict], repeat: int) -> str:
    lines = ["## SH order (representation)", "",
             (f"Ground-truth transport and light cut to order n relight each scene (albedo * (T_n . L_n)); "
              f"error against the path-traced image over the person's pixels, mean over "
              f"{rows[0]['images'] if rows else 0} images of {info['scenes']} scenes "
              f"({info['resolution'][0]}x{info['resolution'][1]}, data baked at order {info['data_order']}). "
              "Even at the data's own order PRT differs from path tracing (bake noise, the specular "
              "approximation, interreflections): that is the floor. Time: albedo * (T . L) + "
              f"E . L per megapixel, float32, median of {repeat}. {INTERIOR_NOTE}"), ""]
    if info["skipped"]:
        lines += [(f"Skipped order(s) {', '.join(map(str, info['skipped']))}: they need a data set baked at order "
                   f"{max(info['skipped'])} (`python -m farm ... --order {max(info['skipped'])}`); this one is "
                   f"order {info['data_order']}."),
                  ""]
    lines += [("| order | coefficients | relight ms / MP | PSNR interior (dB) | L1 interior x100 | PSNR (dB) "
               "| L1 x100 | Pareto |"), "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['order']} | {r['coeffs']} | {r['relight_ms_per_mp']:.1f} | {r['psnr_interior']:.2f} "
                     f"| {100 * r['l1_interior']:.2f} | {r['psnr']:.2f} | {100 * r['l1']:.2f} "
                     f"| {_mark(r['front'])} |")
    return "\n".join(lines) + "\n"


def directions_markdown(info: str, rows: list[dict]) -> str:
    lines = ["## Bake directions", "", (info.replace("\n", " ") + " (benchmarks/bench_bake.py directions_rows); "
                                        "one front per bake kind."), "",
             "| bake | S | bake seconds | mean abs error | 99th pct abs error | Pareto |", "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['bake']} | {r['S']} | {r['seconds']:.2f} | {r['mean']:.4f} | {r['p99']:.4f} "
                     f"| {_mark(r['front'])} |")
    return "\n".join(lines) + "\n"


def spp_markdown(info: str, rows: list[dict]) -> str:
    lines = ["## Samples per pixel", "", info + " (benchmarks/bench_bake.py spp_rows).", "",
             "| spp | denoise | render seconds | relative error | Pareto |", "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['spp']} | {r['denoise']} | {r['seconds']:.2f} | {r['error']:.4f} "
                     f"| {_mark(r['front'])} |")
    return "\n".join(lines) + "\n"


def replace_section(doc: str, name: str, body: str) -> str:
    """`doc` with the block between this section's markers replaced by `body` (appended when absent)."""
    begin, end = f"<!-- bench_tradeoffs:{name} begin -->", f"<!-- bench_tradeoffs:{name} end -->"
    block = f"{begin}\n{body.rstrip()}\n{end}"
    if begin in doc:
        if doc.count(begin) != 1 or doc.count(end) != 1 or doc.index(end) < doc.index(begin):
            raise ValueError(f"section {name!r}: its markers are duplicated or out of order")
        return doc[:doc.index(begin)] + block + doc[doc.index(end) + len(end):]
    return doc.rstrip() + "\n\n" + block + "\n"


# ------------------------------------------------------------------ plot


def plot(results: dict, out: Path) -> Path:
    """One panel per measured section: time against error, front points filled and joined."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    from relight.files.fileio import atomic_path

    panels = []
    if "network" in results:
        rows = results["network"][1]
        groups = {name: [r for r in rows if r["model"] == name] for name in dict.fromkeys(r["model"] for r in rows)}
        panels.append(("Network: width, precision, working size", "decompose + relight (ms)",
                       "relighting PSNR, interior (dB)",
                       [(name, [(r["total_ms"], r["psnr_interior"], r["front"], str(r["working_size"])) for r in g])
                        for name, g in groups.items()], True, False))
    if "sh" in results and results["sh"][1]:
        rows = results["sh"][1]
        panels.append(("SH order (GT transport)", "relight ms per MP", "PRT vs path-traced PSNR, interior (dB)",
                       [("order", [(r["relight_ms_per_mp"], r["psnr_interior"], r["front"], f"N={r['order']}")
                                   for r in rows])],
                       False, False))
    if "directions" in results:
        rows = results["directions"][1]
        panels.append(("Bake directions S", "bake seconds", "mean abs error of T.L",
                       [(kind, [(r["seconds"], r["mean"], r["front"], str(r["S"])) for r in rows if r["bake"] == kind])
                        for kind in dict.fromkeys(r["bake"] for r in rows)], True, True))
    if "spp" in results:
        rows = results["spp"][1]
        panels.append(("Samples per pixel", "render seconds", "relative error",
                       [(label, [(r["seconds"], r["error"], r["front"], str(r["spp"])) for r in rows
                                 if r["denoise"] == label]) for label in dict.fromkeys(r["denoise"] for r in rows)],
                       True, False))
    if not panels:
        raise ValueError("nothing to plot")
    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 4.4), squeeze=False)
    for ax, (title, xlabel, ylabel, series, logx, front_per_series) in zip(axes[0], panels):
        every = []
        for i, (label, pts) in enumerate(series):
            colour = f"C{i}"
            xs, ys, fr, tags = zip(*pts) if pts else ((), (), (), ())
            ax.scatter(xs, ys, facecolors=[colour if f else "none" for f in fr], edgecolors=colour, zorder=3)
            ax.scatter([], [], color=colour, label=label)  # legend entry, always filled
            for x, y, tag in zip(xs, ys, tags):
                ax.annotate(tag, (x, y), textcoords="offset points", xytext=(4, 3), fontsize=7)
            if front_per_series:  # each series has its own front (the bake kinds)
                front = sorted((x, y) for x, y, f in zip(xs, ys, fr) if f)
                if len(front) > 1:
                    ax.plot(*zip(*front), color=colour, linestyle="--", linewidth=1, zorder=2)
            every += [(x, y, f) for x, y, f in zip(xs, ys, fr)]
        front = sorted((x, y) for x, y, f in every if f)
        if not front_per_series and len(front) > 1:
            ax.plot(*zip(*front), color="0.4", linestyle="--", linewidth=1, zorder=2, label="Pareto front")
        if logx:
            ax.set_xscale("log")
        ax.set_title(title, fontsize=10)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.text(0.005, 0.005, "filled: on the Pareto front (no other point both at least as fast and as good, "
             "and better in one); dashed: the front", fontsize=7)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out, ".png") as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return out


# ------------------------------------------------------------------ main


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--data", help="held-out scene folder (farm --light-pool heldout); network and sh sections")
    p.add_argument("--sh-data", help="scene folder for the sh section when it differs from --data "
                                     "(e.g. a held-out set baked at order 6)")
    p.add_argument("--model", action="append", metavar="NAME=PATH.onnx", help="ONNX model, repeatable")
    p.add_argument("--sections", default="network,sh", help=f"comma list of {','.join(SECTIONS)}")
    p.add_argument("--sizes", default=",".join(map(str, DEFAULT_SIZES)), help="working sizes (px)")
    p.add_argument("--orders", default=",".join(map(str, DEFAULT_ORDERS)), help="SH orders")
    p.add_argument("--eval-size", type=int, default=None,
                   help="side of the evaluation crops (default: the data's resolution)")
    p.add_argument("--threads", type=int, default=1, help="onnxruntime threads for the timings")
    p.add_argument("--repeats", type=int, default=5, help="timed runs per point (median)")
    p.add_argument("--max-pairs", type=int, default=64, help="evaluation pairs per model and size")
    p.add_argument("--max-pairs-per-scene", type=int, default=4)
    p.add_argument("--held-out-only", action="store_true", help="relight only towards held-out lights")
    p.add_argument("--directions", default="64,128,256,512,1024", help="bake directions S")
    p.add_argument("--directions-reference", type=int, default=4096)
    p.add_argument("--spp", default="16,32,64,128,256", help="samples per pixel")
    p.add_argument("--spp-reference", type=int, default=1024)
    p.add_argument("--spp-resolution", type=int, default=128)
    p.add_argument("--doc", default=str(ROOT / "docs" / "TRADEOFFS.md"), help="markdown file to update")
    p.add_argument("--plot", default=str(ROOT / "docs" / "tradeoffs.png"), help="PNG to write")
    return p


def run(argv=None) -> dict:
    """Parse, measure, write --doc and --plot; returns the measured sections."""
    from relight.files.fileio import atomic_write_text

    args = build_parser().parse_args(argv)
    sections = [s.strip() for s in args.sections.split(",") if s.strip()]
    unknown = [s for s in sections if s not in SECTIONS]
    if unknown or not sections:
        raise ValueError(f"--sections must be a comma list of {','.join(SECTIONS)}, got {args.sections!r}")
    if args.repeats < 1 or args.threads < 1 or args.max_pairs < 1:
        raise ValueError("--repeats, --threads and --max-pairs must be >= 1")
    if ({"network", "sh"} & set(sections)) and not args.data:
        raise ValueError("the network and sh sections need --data HELD_OUT_DIR")
    models = parse_models(args.model)
    sizes = int_list(args.sizes, "--sizes", 16, 4096)
    orders = int_list(args.orders, "--orders", 0, 16)
    doc_path = Path(args.doc)
    doc = doc_path.read_text(encoding="utf-8") if doc_path.is_file() else "# Trade-offs\n"
    command = "PYTHONPATH=. .venv/bin/python benchmarks/bench_tradeoffs.py " + " ".join(
        sys.argv[1:] if argv is None else argv)
    header = f"Command: `{command}`\n\n{machine_line()}\n\n"
    results = {}
    for section in sections:
        if section == "network":
            results[section] = network_points(models, args.data, sizes, eval_size=args.eval_size,
                                              threads=args.threads, repeats=args.repeats, max_pairs=args.max_pairs,
                                              max_pairs_per_scene=args.max_pairs_per_scene,
                                              held_out_only=args.held_out_only)
            text = network_markdown(*results[section], args.threads, args.repeats)
        elif section == "sh":
            results[section] = sh_order_points(args.sh_data or args.data, orders, repeat=max(args.repeats, 3))
            text = sh_markdown(*results[section], max(args.repeats, 3))
        elif section == "directions":
            results[section] = directions_points(int_list(args.directions, "--directions", 16, 65536),
                                                 args.directions_reference)
            text = directions_markdown(*results[section])
        else:
            results[section] = spp_points(args.spp_resolution, int_list(args.spp, "--spp", 1, 65536),
                                          args.spp_reference)
            text = spp_markdown(*results[section])
        title, _, rest = text.partition("\n\n")
        text = f"{title}\n\n{header}{rest}"
        print(text)
        doc = replace_section(doc, section, text)
    atomic_write_text(doc_path, doc)
    written = plot(results, Path(args.plot))
    print(f"wrote {doc_path} and {written}")
    return results


def main(argv=None) -> int:
    try:
        run(argv)
    except ValueError as exc:
        print(f"bench_tradeoffs: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
