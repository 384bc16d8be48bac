"""Where the geometry-first network's light goes wrong (issue 25): its light fit redone with
one input at a time replaced by the truth, on held-out pairs, and the relit PSNR of each
(issue 14's version of this diagnosis asked the same of the first geometry-first model).

    PYTHONPATH=. .venv/bin/python benchmarks/diagnose_light_fit.py runs/MODEL/model.safetensors \\
        --data data/heldout256 [--every 2] [--size 128]

For each pair (model.samples.data.EvaluationPairs at --size, every --every-th) the network's own
transport T is kept and the photo's light is fitted (model.networks.physics.fit_light, ridge 0.1,
the network's light prior) against the photo with: the network's albedo prior; that prior
rescaled per channel to the true albedo's mean over the person; the true albedo; none (0.5
grey everywhere); then
a robust refit (Cauchy weights on the relative residual, 6 rounds), the gradient refinement
of relight.network.refine (8 iterations), the fitted light with the true light's DC, and the true
light itself; last, the fit with the true albedo and the farm's baked T. Each light relights
the photo by the network's photo-consistent albedo rule (model.networks.physics) to the pair's other
light; PSNR (model.scoring.metrics) over the interior pixels against the path-traced image.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("model", help="a GeometryNet checkpoint (.safetensors)")
    p.add_argument("--data", required=True)
    p.add_argument("--every", type=int, default=2)
    p.add_argument("--size", type=int, default=128)
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)
    import torch

    from model.networks import physics
    from model.training.checkpoint import load_model
    from model.samples.data import EvaluationPairs
    from model.samples.data_splits import find_scenes, held_out_light_names
    from model.scoring.metrics import interior_weight, psnr
    from relight.network.refine import refine_light

    torch.set_num_threads(args.threads)
    net = load_model(args.model)
    pairs = EvaluationPairs(find_scenes(args.data), args.size, 4, held_out=held_out_light_names(),
                            body_prior=getattr(net, "body_prior", False))
    rows: dict[str, list[float]] = {}
    for i in range(0, len(pairs), args.every):
        s = pairs[i]
        x = s["input"][None]
        with torch.no_grad():
            out = net(x)
            photo = physics.linear_from_network_input(x[:, :3])
            w = s["alpha"][None] * (s["alpha"][None] > 0.999)
            T, prior_light, albedo_prior = out["transport"], out["light_prior"], out["albedo_prior"]
            true_albedo, true_light = s["albedo"][None], s["light"][None]

            def fit(transport, albedo, weight=w):
                return physics.fit_light(transport, albedo, photo, weight, prior_light, 0.1)

            gain = (true_albedo * w).sum((2, 3), keepdim=True) / (albedo_prior * w).sum((2, 3), keepdim=True).clamp(
                min=1e-6)
            fitted = fit(T, albedo_prior)
            robust = fitted
            for _ in range(6):
                rel = ((albedo_prior * torch.einsum("bnhw,bnc->bchw", T, robust) - photo) / (photo + 0.02)).abs()
                rel = rel.mean(dim=1, keepdim=True)
                c = rel[w > 0].median()
                robust = fit(T, albedo_prior, w / (1 + (rel / c) ** 2))
            refined, _ = refine_light(T[0].numpy().transpose(1, 2, 0), s["input_linear"].numpy().transpose(1, 2, 0),
                                      s["alpha"].numpy()[0], fitted[0].numpy(), 8)
            lights = {
                "the network's albedo prior (as shipped)": (fitted, T),
                "the prior rescaled to the true albedo's mean per channel": (fit(T, albedo_prior * gain), T),
                "the true albedo": (fit(T, true_albedo), T),
                "no albedo (0.5 grey)": (fit(T, torch.full_like(albedo_prior, 0.5)), T),
                "the prior, robust refit (Cauchy, 6 rounds)": (robust, T),
                "the prior, then relight.network.refine (8 iterations)": (torch.from_numpy(np.asarray(refined, np.float32))[None], T),
                "the prior, then the true light's DC": (fitted * (true_light[:, :1] / fitted[:, :1].clamp(min=1e-6)), T),
                "the true light (no fit)": (true_light, T),
                "the true albedo and the farm's baked T": (fit(s["transport"][None], true_albedo), s["transport"][None]),
            }
            weight = interior_weight(s["alpha"].numpy()[0])
            target = s["target_image"].numpy().transpose(1, 2, 0)
            for name, (light, transport) in lights.items():
                shading = torch.einsum("bnhw,bnc->bchw", transport, light)
                albedo = physics.photo_consistent_albedo(photo, shading, w)
                relit = (albedo * torch.einsum("bnhw,bnc->bchw", transport, s["target_light"][None]))[0]
                rows.setdefault(name, []).append(psnr(relit.numpy().transpose(1, 2, 0), target, weight))
    print(f"# {args.model}: {len(next(iter(rows.values())))} held-out pairs of {args.data} at {args.size} px\n")
    print("| the photo's light fitted with | relit PSNR (dB) |")
    print("|---|---|")
    for name, values in rows.items():
        print(f"| {name} | {np.mean(values):.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
