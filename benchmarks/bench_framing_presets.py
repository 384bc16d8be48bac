"""Quality presets per framing (issue 37): each preset's relit PSNR, SI PSNR and face PSNR on a
held-out set, through the runtime as a user runs it (relight.network.runtime with the preset's options),
the true alpha as the mask, like benchmarks/bench_quality.py.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_framing_presets.py --data data/heldout37_hs \\
        [--presets draft,balanced,best] [--size 256] [--per-scene 4] [--threads 2] [--model M.onnx]

Every pair (scene, light a -> light b) is decomposed at the preset's settings and relit to light
b; scored against the path-traced image b over the interior pixels (model.scoring.metrics) and over the
face (model.scoring.face_region: the head mask times the interior, pairs with >= 16 face pixels). Prints
one markdown row per preset: means over the pairs, and the paired mean difference to the first
preset with its standard error.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np


def run(data, presets, size: int, per_scene: int, threads: int, model=None) -> list[dict]:
    from model.scoring import face_region, metrics
    from model.samples.data import EvaluationPairs
    from model.samples.data_splits import find_scenes, held_out_light_names
    from relight.network import quality
    from relight.network.runtime import Relighter

    pairs = EvaluationPairs(find_scenes(data), size, 4, held_out=held_out_light_names(),
                            max_pairs_per_scene=per_scene)
    faces = face_region.FaceRows(size)
    out = []
    for key in presets:
        preset = quality.preset(key)
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
            target = hwc["target_image"]
            row = {"psnr": metrics.psnr(relit, target, weight), "si_psnr": metrics.scale_invariant_psnr(relit, target, weight),
                   "face_psnr": float("nan"), "face_si_psnr": float("nan")}
            head = faces.head(pairs.paths[pairs.pairs[i][0]])
            if head is not None:
                face = face_region.face_weight(weight, head[0])
                if (face > 0.5).sum() >= face_region.MIN_FACE_PIXELS:
                    row["face_psnr"] = metrics.psnr(relit, target, face)
                    row["face_si_psnr"] = metrics.scale_invariant_psnr(relit, target, face)
            scores.append(row)
        out.append({"preset": key, "seconds": time.perf_counter() - t0, "scores": scores})
    return out


def table(results: list[dict]) -> str:
    base = results[0]["scores"]
    lines = ["| preset | pairs | relit PSNR | SI PSNR | face PSNR | face SI PSNR | relit - " + results[0]["preset"]
             + " (paired, +- SE) | face - " + results[0]["preset"] + " | seconds for all pairs |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        s = r["scores"]
        get = lambda name, rows: np.array([x[name] for x in rows])
        diff = get("psnr", s) - get("psnr", base)
        face_diff = get("face_psnr", s) - get("face_psnr", base)
        face_ok = np.isfinite(face_diff)
        se = diff.std(ddof=1) / np.sqrt(len(diff)) if len(diff) > 1 else float("nan")
        lines.append(f"| {r['preset']} | {len(s)} | {np.mean(get('psnr', s)):.2f} | {np.mean(get('si_psnr', s)):.2f} | "
                     f"{np.nanmean(get('face_psnr', s)):.2f} | {np.nanmean(get('face_si_psnr', s)):.2f} | "
                     f"{diff.mean():+.2f} +- {se:.2f} | {face_diff[face_ok].mean() if face_ok.any() else float('nan'):+.2f} | "
                     f"{r['seconds']:.1f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True)
    p.add_argument("--presets", default="draft,balanced,best")
    p.add_argument("--size", type=int, default=256, help="crop size of the pairs (px) before the runtime resizes")
    p.add_argument("--per-scene", type=int, default=4)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--model", default=None, help="a relighting .onnx (default: the registry's default)")
    a = p.parse_args(argv)
    print(table(run(a.data, [k.strip() for k in a.presets.split(",")], a.size, a.per_scene, a.threads, a.model)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
