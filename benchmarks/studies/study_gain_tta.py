"""Issue 26: does Best gain from running the network on the photo at other exposures and white
balances (per-channel gains g: the photo times g is the same person under the light times g)?

    PYTHONPATH=. .venv/bin/python benchmarks/studies/study_gain_tta.py --data data/heldout256 [--pairs 96]

Each held-out pair (the runtime protocol of benchmarks/bench_quality.py: 256 px crop, true
alpha as the mask, 128 px working size) is decomposed once; the network runs again on the
working crop times each gain, its light divided back by the gain, and the runs are averaged
as relight.network.tta averages (transport and light, albedo re-derived), then the level prior. Printed:
relit PSNR, paired against the single run.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

EXPOSURE_1 = [(0.5,) * 3, (2.0,) * 3]
EXPOSURE_HALF = [(2 ** -0.5,) * 3, (2 ** 0.5,) * 3]
WARM_COOL = [(np.exp(0.2), 1.0, np.exp(-0.2)), (np.exp(-0.2), 1.0, np.exp(0.2))]
SETS = {  # name: (gains, mirrored as well)
    "network once": ([], False),
    "+ exposure -1 / +1 EV": (EXPOSURE_1, False),
    "+ exposure -0.5 / +0.5 EV": (EXPOSURE_HALF, False),
    "+ warmer / cooler (red and blue x e^+-0.2)": (WARM_COOL, False),
    "+ warmer / cooler, greener / less green": (WARM_COOL + [(1.0, np.exp(0.2), 1.0), (1.0, np.exp(-0.2), 1.0)],
                                                 False),
    "mirrored (Best's first run)": ([], True),
    "mirrored + exposure -0.5 / +0.5 EV, each mirrored too": (EXPOSURE_HALF, True),
}


def gain_runs(relighter, base, gains, mirrored: bool):
    """relight.network.tta runs of the network on base's working crop times each gain (and mirrored)."""
    from relight.network import tta

    done = list(tta.runs(relighter, base, ((1.0, True),))) if mirrored else []
    for g in gains:
        g = np.asarray(g, np.float32)
        for mirror in ((False, True) if mirrored else (False,)):
            small, matte = base.photo_working, base.alpha
            if mirror:
                small, matte = small[:, ::-1], matte[:, ::-1]
            out = relighter.run_crop(np.ascontiguousarray(small * g), np.ascontiguousarray(matte))
            done.append((tta._Run(out["transport"], out["light"] / g[None, :], base.sh_order, base.working_size),
                         mirror))
    return done


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True)
    p.add_argument("--pairs", type=int, default=None)
    p.add_argument("--model", default=str(ROOT / "relight/models/geometry.onnx"))
    args = p.parse_args(argv)
    from model.scoring import metrics
    from model.samples.data import photo_pairs
    from relight.network import tta
    from relight.network.level import apply as apply_level
    from relight.network.runtime import Relighter

    relighter = Relighter(args.model, threads=2)
    scores = {name: [] for name in SETS}
    for pair in photo_pairs(args.data, 256, args.pairs):
        base = relighter.decompose(pair["photo"], mask=pair["alpha"], level=False, working_size=128)
        weight = metrics.interior_weight(pair["alpha"])
        for name, (gains, mirrored) in SETS.items():
            d, _ = apply_level(tta.average(base, gain_runs(relighter, base, gains, mirrored)), relighter.level_prior)
            scores[name].append(metrics.psnr(d.relight(pair["light_b"]), pair["target"], weight))
    print(paired_table(scores, "network once", args.data))
    return 0


def paired_table(scores: dict, baseline: str, data) -> str:
    """Markdown table of each set's mean relit PSNR and its paired difference to `baseline`'s."""
    once = np.array(scores[baseline])
    lines = [f"{len(once)} held-out pairs of {data}, level prior on\n",
             "| runs averaged | relit PSNR | vs the network once (paired mean +- SE) | worst pair |", "|---|---|---|---|"]
    for name, values in scores.items():
        diff = np.array(values) - once
        lines.append(f"| {name} | {np.mean(values):.2f} | {diff.mean():+.2f} +- "
                     f"{diff.std() / np.sqrt(len(diff)):.2f} | {diff.min():+.2f} |")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
