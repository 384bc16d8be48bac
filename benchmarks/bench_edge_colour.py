"""The albedo layer along the matte's soft edge: the person's own colour (relight.network.foreground)
against the photo's mix of person and background (the rule before), on held-out farm scenes.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_edge_colour.py --data data/heldout256 [--scenes 24]

Each scene's photo (light a, its rendered background kept) is decomposed with its true alpha as
the mask (Balanced's settings), and its albedo layer is compared with the true albedo on the
pixels where the alpha is soft (0.05-0.95), after per-channel gains fitted on the interior
(alpha 1) pixels: those take out the light's colour and level, which the edge does not change,
so what is left there is the edge's own error. Weighted by the alpha, as the layer composites
over another background. Also printed: the same on the interior (the reference: the network's
own albedo error) and the time of the albedo layer, both rules, on the scene's full size.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def edge_errors(d, truth: np.ndarray, alpha: np.ndarray) -> tuple[float, float, float]:
    """(alpha-weighted mean |layer - g truth| on the soft edge, the same on the interior, ms)."""
    t = time.perf_counter()
    layer = d.layer("albedo")
    ms = (time.perf_counter() - t) * 1e3
    inside, soft = alpha >= 1.0, (alpha > 0.05) & (alpha < 0.95)
    g = (layer[inside] * truth[inside]).sum(axis=0) / np.maximum((truth[inside] ** 2).sum(axis=0), 1e-12)
    err = np.abs(layer - truth * g.astype(np.float32))
    a = alpha[..., None]
    edge = float((a * err)[soft].sum() / (3 * alpha[soft].sum()))
    return edge, float(err[inside].mean()), ms


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True)
    p.add_argument("--scenes", type=int, default=24)
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)

    from model.samples.data import photo_pairs
    from relight.network import quality
    from relight.network.decomposition import Decomposition
    from relight.network.runtime import Relighter

    relighter = Relighter(quality.model_path("balanced"), threads=args.threads)
    person_colour = Decomposition._edge_colour

    def photo_only(self, r0, r1):  # the rule before: the photo's own mix of person and background
        return None

    rows = {"person's colour (relight.network.foreground)": [], "the photo (before)": []}
    for pair in photo_pairs(args.data, 256, args.scenes, 1):
        d = relighter.decompose(pair["photo"], mask=pair["alpha"], **{
            k: v for k, v in quality.preset("balanced").decompose_options().items() if k != "matte_method"})
        for label, rule in zip(rows, (person_colour, photo_only)):
            Decomposition._edge_colour = rule
            try:
                d._smooth_prepared = None
                rows[label].append(edge_errors(d, pair["albedo"], pair["alpha"]))
            finally:
                Decomposition._edge_colour = person_colour
    print(f"{len(rows[next(iter(rows))])} held-out scenes of {args.data}, 256 px, true alpha, Balanced\n")
    print("| albedo layer on the soft edge | edge error (alpha-weighted mean abs, gains fitted inside) "
          "| interior error | albedo layer (ms, median) |")
    print("|---|---|---|---|")
    for label, v in rows.items():
        a = np.array(v)
        print(f"| {label} | {a[:, 0].mean():.4f} | {a[:, 1].mean():.4f} | {statistics.median(a[:, 2]):.2f} |")
    new, old = np.array(rows[next(iter(rows))])[:, 0], np.array(rows["the photo (before)"])[:, 0]
    print(f"\nedge error, paired ratio new / before: {np.mean(new / old):.3f} "
          f"(scenes better: {int(np.sum(new < old))} of {new.size})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
