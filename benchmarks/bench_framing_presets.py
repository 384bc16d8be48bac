"""Quality presets per framing (issues 37, 45): each preset's relit PSNR, SI PSNR, face PSNR and the
light's response on a held-out set, through the runtime as a user runs it (relight.network.runtime
with the preset's model and options), the true alpha as the mask, like benchmarks/bench_quality.py.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_framing_presets.py --data data/heldout37_hs \\
        [--presets draft,balanced,best] [--size 256] [--per-scene 4] [--threads 2] \\
        [--model M.onnx | --model-for best=LARGE.onnx ...] [--side-sun]

Every pair (scene, light a -> light b) is decomposed at the preset's settings and relit to light
b; scored against the path-traced image b over the interior pixels (model.scoring.metrics) and over the
face (model.scoring.face_region: the head mask times the interior, pairs with >= 16 face pixels); the
light's response is the slope and correlation of the relit log-luminance change against the true one
(model.scoring.metrics.light_response). `--side-sun` keeps only a map -> a hard sun 40-140 degrees off
the camera axis (model.samples.data_splits.side_sun_pairs). Each preset runs its own registered model
(relight/network/quality.py) unless --model (every preset) or --model-for KEY=FILE (one) names
another, to measure candidates before they are registered. Prints one markdown row per preset and
framing: means over the pairs, and the paired mean difference to the first preset with its standard
error.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import defaultdict

import numpy as np


def run(data, presets, size: int, per_scene: int, threads: int, models: dict | None = None,
        side_sun: bool = False) -> list[dict]:
    """[{"preset", "model", "seconds", "scores": [per pair {"framing", "psnr", ...}]}], the pairs in
    the same order for every preset. `models`: {preset key: ONNX file} overriding the registry's."""
    from model.evaluate import framing_of
    from model.samples.data import EvaluationPairs
    from model.samples.data_splits import find_scenes, held_out_light_names
    from model.scoring import face_region, metrics
    from relight.network import quality
    from relight.network.runtime import Relighter

    pairs = EvaluationPairs(find_scenes(data), size, 4, held_out=held_out_light_names(),
                            max_pairs_per_scene=per_scene, side_sun=side_sun)
    framings = [framing_of(path) for path in pairs.paths]
    faces = face_region.FaceRows(size)
    out = []
    for key in presets:
        preset = quality.preset(key)
        model = (models or {}).get(key) or quality.model_path(key)
        relighter = Relighter(model, threads=threads, working_size=preset.working_size)
        options = preset.decompose_options()
        options.pop("matte_method", None)  # the true alpha is the mask: no segmenter
        scores, t0 = [], time.perf_counter()
        for i in range(len(pairs)):
            item = pairs[i]
            hwc = {k: np.ascontiguousarray(np.moveaxis(item[k].numpy().astype(np.float32), 0, -1))
                   for k in ("input_linear", "alpha", "target_image")}
            alpha = hwc["alpha"][..., 0]
            dec = relighter.decompose(hwc["input_linear"], mask=alpha, **options)
            relit = dec.relight(item["target_light"].numpy().astype(np.float64))
            weight = metrics.interior_weight(alpha)
            photo, target = hwc["input_linear"], hwc["target_image"]
            response = metrics.light_response(photo, relit, target, weight)
            row = {"framing": framings[pairs.pairs[i][0]], "psnr": metrics.psnr(relit, target, weight),
                   "si_psnr": metrics.scale_invariant_psnr(relit, target, weight),
                   "slope": response.slope, "correlation": response.correlation,
                   "face_psnr": float("nan"), "face_si_psnr": float("nan")}
            head = faces.head(pairs.paths[pairs.pairs[i][0]])
            if head is not None:
                face = face_region.face_weight(weight, head[0])
                if (face > 0.5).sum() >= face_region.MIN_FACE_PIXELS:
                    row["face_psnr"] = metrics.psnr(relit, target, face)
                    row["face_si_psnr"] = metrics.scale_invariant_psnr(relit, target, face)
            scores.append(row)
        out.append({"preset": key, "model": str(model), "seconds": time.perf_counter() - t0, "scores": scores})
    return out


def _short(path: str) -> str:
    """A model file as the table names it: its folder and name."""
    parts = str(path).replace("\\", "/").rsplit("/", 2)
    return "/".join(parts[-2:])


def _column(rows: list[dict], name: str) -> np.ndarray:
    return np.array([x[name] for x in rows], np.float64)


def table(results: list[dict]) -> str:
    """One row per preset and framing ("all" last when there are several), the differences paired
    with the first preset's same pairs."""
    first = results[0]["preset"]
    by_framing = defaultdict(list)  # framing -> pair indices
    for i, row in enumerate(results[0]["scores"]):
        by_framing[row["framing"]].append(i)
    groups = sorted(by_framing.items())
    if len(groups) > 1:
        groups.append(("all", list(range(len(results[0]["scores"])))))
    lines = [f"| preset | model | framing | pairs | relit PSNR | SI PSNR | face PSNR | slope | correlation | "
             f"relit - {first} (paired, +- SE) | face - {first} | seconds for all pairs |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for framing, index in groups:
        base = [results[0]["scores"][i] for i in index]
        for r in results:
            s = [r["scores"][i] for i in index]
            diff = _column(s, "psnr") - _column(base, "psnr")
            face_diff = _column(s, "face_psnr") - _column(base, "face_psnr")
            face_ok = np.isfinite(face_diff)
            se = diff.std(ddof=1) / np.sqrt(len(diff)) if len(diff) > 1 else float("nan")
            face = np.nanmean(_column(s, "face_psnr")) if face_ok.any() else float("nan")
            lines.append(f"| {r['preset']} | {_short(r['model'])} | {framing} | {len(s)} | "
                         f"{_column(s, 'psnr').mean():.2f} | {_column(s, 'si_psnr').mean():.2f} | {face:.2f} | "
                         f"{np.nanmean(_column(s, 'slope')):.2f} | {np.nanmean(_column(s, 'correlation')):.2f} | "
                         f"{diff.mean():+.2f} +- {se:.2f} | "
                         f"{face_diff[face_ok].mean() if face_ok.any() else float('nan'):+.2f} | {r['seconds']:.1f} |")
    return "\n".join(lines)


def _model_for(text: str) -> tuple[str, str]:
    key, sep, path = text.partition("=")
    if not sep or not path:
        raise argparse.ArgumentTypeError(f"expected KEY=FILE.onnx, got {text!r}")
    return key.strip().lower(), path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True)
    p.add_argument("--presets", default="draft,balanced,best")
    p.add_argument("--size", type=int, default=256, help="crop size of the pairs (px) before the runtime resizes")
    p.add_argument("--per-scene", type=int, default=4)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--model", default=None, help="a relighting .onnx for every preset (default: each preset's own)")
    p.add_argument("--model-for", type=_model_for, action="append", default=[], metavar="KEY=FILE",
                   help="the .onnx one preset runs (repeatable), e.g. best=runs/large.onnx")
    p.add_argument("--side-sun", action="store_true", help="only a map -> a hard sun 40-140 degrees off the axis")
    a = p.parse_args(argv)
    presets = [k.strip().lower() for k in a.presets.split(",")]
    models = {k: a.model for k in presets} if a.model else {}
    models.update(dict(a.model_for))
    print(table(run(a.data, presets, a.size, a.per_scene, a.threads, models, a.side_sun)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
