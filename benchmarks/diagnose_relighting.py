"""Where the relighting error comes from: one model, several ways to relight, held-out pairs.

Each row relights image a to light b and scores it against the path-traced
image b (fully covered person pixels, linear PSNR, as model.evaluate):

  direct              rho (T . L_b) + E . L_b, the runtime's formula
  photo-consistent    rho' = (I_a - E . L) / (T . L) with the predicted light L,
                      then rho' (T . L_b) + E . L_b (the photo's own colours)
  ... light at 0.8    the same with L rescaled to the training reference radiance
  ... true light a    the same with the ground-truth light a (needs GT: a bound)
  GT albedo           the ground-truth albedo with the predicted T and E (a bound)
  GT transport        the predicted albedo with the ground-truth T, no E (a bound)
  identity, exposure-matched identity: model.evaluate's baselines

    PYTHONPATH=. .venv/bin/python benchmarks/diagnose_relighting.py MODEL --data HELD_OUT_DIR
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
import torch

from model.scoring import metrics
from model.samples.data import EvaluationPairs, network_input
from model.samples.data_splits import find_scenes, held_out_light_names
from model.evaluate import numpy_sample
from model.scoring.pair_metrics import channels_last, exposure_ratio, render_np, with_metric_weight
from model.scoring.pair_metrics import shading_np as _shading_np
from model.scoring.predictor import Predictor
from relight.lighting import sh

# a denominator below this is "no light reaches the pixel": the photo-consistent albedo is undefined
MIN_SHADING = 1e-3
MAX_ALBEDO = 2.0  # photo-consistent albedo clip: above it the pixel is unexplained by T . L


def shading(transport: np.ndarray, light: np.ndarray) -> np.ndarray:
    """T . L [H, W, 3] (model.scoring.pair_metrics.shading_np for a non-T* network)."""
    return _shading_np(transport, light, False)


def photo_consistent_relight(image_a, transport, residual, light_a, light_b) -> np.ndarray:
    """Relight with the albedo that makes rho (T . L_a) + E . L_a equal the photo."""
    albedo = np.clip((image_a - shading(residual, light_a)) / np.maximum(shading(transport, light_a), MIN_SHADING),
                     0.0, MAX_ALBEDO)
    return albedo * shading(transport, light_b) + shading(residual, light_b)


def variants(pred: dict, sample: dict) -> dict[str, np.ndarray]:
    """Relit images [H, W, 3] by name; pred and sample hold [C, H, W] maps and [n, 3] lights."""
    t, e, rho = pred["transport"], pred["residual"], channels_last(pred["albedo"])
    image_a, light_b = channels_last(sample["image"]), sample["target_light"]
    light = np.asarray(pred["light"], np.float64)
    # a light with mean luminance <= 0 (an untrained network) has no reference scale: kept as is
    reference = sh.normalize_reference(light)[0] if sh.mean_luminance(light) > 0 else light
    return {
        "direct": render_np(pred, light_b, False),
        "photo-consistent albedo, predicted light": photo_consistent_relight(image_a, t, e, pred["light"], light_b),
        "photo-consistent albedo, predicted light at 0.8": photo_consistent_relight(image_a, t, e, reference, light_b),
        "photo-consistent albedo, true light a (bound)": photo_consistent_relight(image_a, t, e, sample["light"],
                                                                                  light_b),
        "GT albedo, predicted T and E (bound)": render_np(dict(pred, albedo=sample["albedo"]), light_b, False),
        "predicted albedo, GT T, no E (bound)": rho * shading(sample["transport"], light_b),
        "identity": image_a,
        "identity, exposure-matched": image_a * exposure_ratio(sample["light"], light_b),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("model", help=".safetensors checkpoint or .onnx file")
    p.add_argument("--data", required=True, help="farm output with at least two path-traced lights per scene")
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--max-pairs", type=int, default=0, help="0: all pairs")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--unmasked", action="store_true",
                   help="give the network image a with its rendered background instead of masked by the GT alpha")
    args = p.parse_args(argv)

    torch.set_num_threads(max(1, args.threads))
    try:
        predictor = Predictor(args.model)
        pairs = EvaluationPairs(find_scenes(args.data), args.size, predictor.order, held_out=held_out_light_names())
    except ValueError as exc:
        print(f"diagnose_relighting: {exc}", file=sys.stderr)
        return 2
    n = len(pairs) if args.max_pairs <= 0 else min(args.max_pairs, len(pairs))
    scores: dict[str, list[float]] = {}
    dc_ratios = []  # predicted / true light DC per channel: the light's level and colour error
    for i in range(n):
        sample = with_metric_weight(numpy_sample(pairs[i]), "interior")
        x = network_input(sample["image"], None) if args.unmasked else sample["input"]
        pred = {k: v[0] for k, v in predictor(np.ascontiguousarray(x[None], dtype=np.float32)).items()}
        weight, target = channels_last(sample["metric_weight"]), channels_last(sample["target_image"])
        for name, relit in variants(pred, sample).items():
            scores.setdefault(name, []).append(metrics.psnr(relit, target, weight))
        true_dc = sample["light"][0]
        if np.all(np.abs(true_dc) > 1e-12):
            dc_ratios.append(pred["light"][0] / true_dc)
    print(f"{n} pairs from {args.data}, model {args.model}, {args.size} px, input "
          f"{'with its background' if args.unmasked else 'masked'}; relit image PSNR, fully covered pixels, linear\n")
    print("| relighting | image PSNR (dB) |\n|---|---|")
    for name, values in scores.items():
        print(f"| {name} | {np.mean(values):.2f} |")
    if dc_ratios:
        r = np.asarray(dc_ratios)
        print(f"\npredicted / true light DC over {len(r)} pairs (R, G, B): mean "
              + ", ".join(f"{v:.2f}" for v in r.mean(0)) + "; standard deviation "
              + ", ".join(f"{v:.2f}" for v in r.std(0)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
