"""The photo's light on held-out scenes (issue 25): the shipped network's fitted light, the
same light given the light estimator's colour and level (relight.light_estimate), and the
true light's colour and level or the whole true light as bounds.

    PYTHONPATH=. .venv/bin/python benchmarks/eval_light_estimate.py --data data/heldout256 \\
        [--estimator runs/light/model.safetensors] [--pairs 96] [--working-size 128]

Each held-out pair (scene, light a -> light b; model.data.EvaluationPairs at 256 px) is
decomposed by relight.runtime.Relighter with the true alpha as its mask, its light replaced
as each row says (the albedo re-derived by the network's photo-consistent rule), and relit
to light b: PSNR and scale-invariant PSNR (model.metrics) over the interior pixels against
the path-traced image b. The light's colour error is the angle between the estimated and
true DC RGB of light a, its level error |log2| of their DC luminances. --estimator takes a
checkpoint of model.train_light (run in torch) or an .onnx file; without it, the installed
estimator (relight/models/models.json).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_quality import load_pairs, score  # noqa: E402

LUMA = np.array([0.2126, 0.7152, 0.0722])


def colour_error(est: np.ndarray, true: np.ndarray) -> float:
    a, b = est[0], true[0]
    return float(np.degrees(np.arccos(np.clip(a @ b / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-12), -1, 1))))


def level_error(est: np.ndarray, true: np.ndarray) -> float:
    return float(abs(np.log2(max(est[0] @ LUMA, 1e-9) / max(true[0] @ LUMA, 1e-9))))


def estimator_fn(path: str | None):
    """x [1, 4, 64, 64] -> light [n, 3] of the estimator at `path` (or the installed one)."""
    if path is None:
        from relight.light_estimate import LightEstimate

        installed = LightEstimate()
        if not installed.available:
            raise SystemExit("eval_light_estimate: no light estimator installed; pass --estimator")
        return installed.run
    if path.endswith(".onnx"):
        import onnxruntime as ort

        session = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
        return lambda x: dict(zip(("light", "albedo_mean"),
                                  (v[0] for v in session.run(["light", "albedo_mean"], {"x": x}))))
    import torch

    from model.checkpoint import load_model

    net = load_model(path)

    def run(x):
        with torch.no_grad():
            return {k: v.numpy()[0] for k, v in net(torch.from_numpy(x)).items()}
    return run


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True)
    p.add_argument("--estimator", default=None)
    p.add_argument("--model", default=None, help="relighting network (default: the installed one)")
    p.add_argument("--pairs", type=int, default=96)
    p.add_argument("--working-size", type=int, default=128)
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)
    from relight.light_estimate import INTERIOR, estimator_input, with_albedo_level, with_light_colour
    from relight.refine import consistent_albedo
    from relight.runtime import Relighter

    estimate = estimator_fn(args.estimator)
    relighter = Relighter(args.model, threads=args.threads)
    pairs = load_pairs(args.data, args.pairs)
    rows = {k: {"psnr": [], "si": [], "colour": [], "level": []} for k in
            ("network's fitted light", "network's light, estimator's colour and level",
             "network's light and level, estimator's colour",
             "estimator's light", "half network's, half estimator's light",
             "network's light, shading level of the estimator's", "network's light, shading level of the true (bound)",
             "network's light, estimator's mean albedo (shipped)", "network's light, true mean albedo (bound)",
             "network's light, mean albedo halfway to the estimator's (geometric)",
             "network's light and albedo level, estimator's albedo colour",
             "network's light, true colour and level (bound)", "true light (bound)")}
    for pair in pairs:
        d = relighter.decompose(pair["photo"], mask=pair["alpha"], working_size=args.working_size)
        answer = estimate(estimator_input(d.photo_working, d.alpha))
        est = answer["light"].astype(np.float32)
        y0, y1, x0, x1 = d.box
        from relight.resample import resize_linear

        true_albedo = resize_linear(pair["albedo"][y0:y1, x0:x1], *d.working_size)
        full = d.alpha >= INTERIOR
        true_mean = true_albedo[full].mean(axis=0) if full.any() else true_albedo.reshape(-1, 3).mean(0)
        true = pair["light_a"].astype(np.float32)
        def shading_matched(target):
            # per-channel gains making the mean shading over the person the target light's (both
            # through the network's transport): the level the photo's pixels see, not the DC term
            w = d.alpha.reshape(-1)
            t = d.transport.reshape(-1, d.transport.shape[-1])
            own = (w[:, None] * (t @ d.light)).sum(0)
            want = (w[:, None] * (t @ target)).sum(0)
            new = (d.light * np.where(own > 1e-9, want / np.maximum(own, 1e-9), 1.0)[None]).astype(np.float32)
            return dataclasses.replace(d, light=new, albedo=consistent_albedo(d, d.transport, new))

        own_mean = d.albedo[full].mean(axis=0) if full.any() else d.albedo.reshape(-1, 3).mean(0)
        est_mean = np.asarray(answer["albedo_mean"], np.float64)
        luma = np.array([0.2126, 0.7152, 0.0722])
        variants = {
            "network's light, estimator's mean albedo (shipped)": with_albedo_level(d, answer["albedo_mean"]),
            "network's light, mean albedo halfway to the estimator's (geometric)":
                with_albedo_level(d, np.sqrt(own_mean * est_mean)),
            "network's light and albedo level, estimator's albedo colour":
                with_albedo_level(d, est_mean * float(own_mean @ luma) / float(est_mean @ luma)),
            "network's light, true mean albedo (bound)": with_albedo_level(d, true_mean),
            "network's light, shading level of the estimator's": shading_matched(est),
            "network's light, shading level of the true (bound)": shading_matched(true),
            "network's fitted light": d,
            "network's light, estimator's colour and level": with_light_colour(d, est),
            "network's light and level, estimator's colour": with_light_colour(d, est, level=False),
            "estimator's light": dataclasses.replace(d, light=est, albedo=consistent_albedo(d, d.transport, est)),
            "half network's, half estimator's light": dataclasses.replace(
                d, light=(half := 0.5 * (d.light + est)), albedo=consistent_albedo(d, d.transport, half)),
            "network's light, true colour and level (bound)": with_light_colour(d, true),
            "true light (bound)": dataclasses.replace(d, light=true, albedo=consistent_albedo(d, d.transport, true)),
        }
        for name, v in variants.items():
            psnr, si = score(v.relight(pair["light_b"]), pair)
            r = rows[name]
            r["psnr"].append(psnr)
            r["si"].append(si)
            r["colour"].append(colour_error(v.light.astype(np.float64), pair["light_a"]))
            r["level"].append(level_error(v.light.astype(np.float64), pair["light_a"]))
    print(f"# {len(pairs)} held-out pairs of {args.data}, working size {args.working_size}, estimator "
          f"{args.estimator or 'installed'}\n")
    print("| photo's light | colour error (deg, mean / median) | level error (stops, mean / median) "
          "| relit PSNR | SI PSNR |")
    print("|---|---|---|---|---|")
    for name, r in rows.items():
        print(f"| {name} | {np.mean(r['colour']):.1f} / {np.median(r['colour']):.1f} | "
              f"{np.mean(r['level']):.2f} / {np.median(r['level']):.2f} | {np.mean(r['psnr']):.2f} | "
              f"{np.mean(r['si']):.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
