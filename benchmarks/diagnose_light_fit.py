"""Where the geometry-first model's error is: its light fit with the true albedo, its own
albedo prior and none, against the true input light; and its albedo's colour.

    PYTHONPATH=. .venv/bin/python benchmarks/diagnose_light_fit.py RUN/model.safetensors \\
        --data HELD_OUT_DIR [--size 128] [--max-pairs 64]

For every held-out pair (scene, light a -> b) the network's normals and
visibility give T; the photo's light is then fitted (model.physics.fit_light,
the model's own ridge and light head as the prior, rescaled to mean luminance
0.8 as the model does) with three albedos: the farm's true albedo, the
network's albedo prior, and none (0.5 grey everywhere). Each fitted light
relights the photo by the model's own rule (photo-consistent albedo, the
shading floored in deep shadow) to light b; the table gives the relit PSNR on fully covered
pixels and the fitted light's relative SH error. The true input light is the
reference row. Below it: the albedo prior's and the final albedo's PSNR and
the per-channel gains that would map each to the truth (model.metrics).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from model import metrics, physics  # noqa: E402
from model.checkpoint import load_model  # noqa: E402
from model.data import EvaluationPairs  # noqa: E402
from model.data_splits import find_scenes, held_out_light_names  # noqa: E402
from model.geometry import REFERENCE_LUMINANCE, mean_luminance  # noqa: E402


def _hwc(t: torch.Tensor) -> np.ndarray:
    return t[0].permute(1, 2, 0).double().numpy()


def relit_with(net, out, photo, weight, albedo_for_fit, light_b, light_override=None):
    """The model's relit image under light_b when its light fit uses `albedo_for_fit`."""
    if light_override is None:
        light = physics.fit_light(out["transport"], albedo_for_fit, photo, weight, out["light_prior"], net.ridge)
        if net.fixed_level:
            light = light * (REFERENCE_LUMINANCE / mean_luminance(light).clamp(min=0.02))[:, None, None]
    else:
        light = light_override
    shading = torch.einsum("bnhw,bnc->bchw", out["transport"], light)
    albedo = physics.photo_consistent_albedo(photo, shading, weight, net.reliable)
    return albedo * torch.einsum("bnhw,bnc->bchw", out["transport"], light_b), light


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("model", help="geometry-first checkpoint (.safetensors)")
    p.add_argument("--data", required=True)
    p.add_argument("--size", type=int, default=128)
    p.add_argument("--max-pairs", type=int, default=64)
    p.add_argument("--threads", type=int, default=0)
    args = p.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    net = load_model(args.model)
    if getattr(net, "arch", None) != "geometry":
        print("diagnose_light_fit: error: needs a geometry-first checkpoint", file=sys.stderr)
        return 2
    pairs = EvaluationPairs(find_scenes(args.data), args.size, net.sh_order, held_out=held_out_light_names())
    rows = {k: {"psnr": [], "light": []} for k in ("true input light", "fit, true albedo",
                                                   "fit, network albedo prior (the model)",
                                                   "fit, no albedo (0.5 grey)", "light head alone")}
    albedo_rows = {"albedo prior": [], "final albedo": []}
    gains = {"albedo prior": [], "final albedo": []}
    for i in range(min(len(pairs), args.max_pairs)):
        s = pairs[i]
        x = s["input"][None]
        with torch.no_grad():
            out = net(x)
            photo = physics.linear_from_network_input(x)
            weight = out["alpha"] * 0 + s["alpha"][None]  # the GT matte, as the evaluation masks
            light_b = s["target_light"][None]
            true_a = s["light"][None]
            mask = metrics.interior_weight(s["alpha"][0].numpy())
            gt = s["target_image"].permute(1, 2, 0).numpy()
            cases = {
                "true input light": (None, true_a),
                "fit, true albedo": (s["albedo"][None], None),
                "fit, network albedo prior (the model)": (out["albedo_prior"], None),
                "fit, no albedo (0.5 grey)": (torch.full_like(out["albedo_prior"], 0.5), None),
                "light head alone": (None, out["light_prior"] * (REFERENCE_LUMINANCE / mean_luminance(
                    out["light_prior"]).clamp(min=0.02))[:, None, None]),
            }
            for name, (alb, override) in cases.items():
                relit, light = relit_with(net, out, photo, weight, alb, light_b, override)
                rows[name]["psnr"].append(metrics.psnr(_hwc(relit), gt, mask))
                rows[name]["light"].append(float(torch.linalg.norm(light - true_a) / torch.linalg.norm(true_a)))
            gt_albedo = s["albedo"].permute(1, 2, 0).numpy()
            for name, alb in (("albedo prior", out["albedo_prior"]), ("final albedo", out["albedo"])):
                a = _hwc(alb)
                albedo_rows[name].append(metrics.psnr(a, gt_albedo, mask))
                gains[name].append(metrics.fit_channel_gains(a, gt_albedo, mask))
    n = len(rows["true input light"]["psnr"])
    print(f"# Light fit and albedo of `{args.model}` ({n} held-out pairs of `{args.data}`, {args.size} px)\n")
    print("| input light | relit PSNR (dB) | light rel. SH L2 |")
    print("|---|---|---|")
    for name, r in rows.items():
        print(f"| {name} | {np.mean(r['psnr']):.2f} | {np.mean(r['light']):.3f} |")
    print("\n| albedo | PSNR (dB) | per-channel gains to the truth (mean R, G, B) | mean abs log2 gain |")
    print("|---|---|---|---|")
    for name in albedo_rows:
        g = np.array(gains[name])
        print(f"| {name} | {np.mean(albedo_rows[name]):.2f} | {', '.join(f'{v:.2f}' for v in g.mean(0))} | "
              f"{np.abs(np.log2(g)).mean():.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
