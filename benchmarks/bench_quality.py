"""Speed for accuracy (issue 26): each candidate preset's held-out accuracy against its time on
a 512 x 512 photo, the Pareto front, and the presets a stated rule picks from it.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_quality.py --data HELD_OUT_DIR \\
        [--pairs 48] [--size 512] [--threads 2] [--repeats 5] [--doc docs/TRADEOFFS.md]

A candidate is a working size, test-time augmentations (relight.network.tta: the photo mirrored,
and at 0.75x / 1.25x the size), refinement iterations (relight.network.refine) and the person
segmenter's method (relight.person.matte: the ensemble, or the selfie model alone), other networks
averaged in, and whether the model's level prior (relight.network.level) is applied. Accuracy:
every held-out pair (scene, light a -> light b) decomposed at that setting with the true
alpha as mask (so the segmenter does not enter it) and relit to light b, against the
path-traced image b over the interior pixels: PSNR and scale-invariant PSNR
(model.scoring.metrics), the worst pair's change against the network alone at the trained size,
and the share of that baseline's gain over identity (the photo as it is) that is kept; exposure-matched
identity (the photo scaled by the true lights' DC ratio) is printed as an oracle. Time:
segmenter + decomposition + augmentations + refinement + one full-size relight of the
bundled astronaut photo resized to --size, median of --repeats with the candidates
alternated (a load drifting on a shared machine shifts them alike: compare ratios).

The rule (the table quality.py follows): Draft = the fastest front point that keeps >= 90% of
the baseline's gain over identity (issue 26; plain identity: the network does not beat the
exposure-matched oracle, so no share of a gain over it exists; with the level prior the
baseline's gain over plain identity is 1.4 dB, several standard errors) and is within 0.5 dB of
the baseline (paired mean); Balanced = the network at its trained size averaged with its run on
the mirrored crop (`BALANCED`; issue 37: the least test-time work that makes the relit person
mirror-equivariant, docs/TRADEOFFS.md; until 2026-11-27 the network alone); Best = the fastest
front point within 0.05 dB (a tie, well inside the pairs' standard error) of the most accurate
front point within 3 s.
"""

from __future__ import annotations

import argparse
import datetime
import os
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_tradeoffs import pareto_front, replace_section  # noqa: E402

TRAINED_SIZE = 128     # the shipped network's training crops: the baseline ("network alone")
DRAFT_DB = 0.5         # Draft: at most this much below the baseline (paired mean PSNR)
DRAFT_SHARE = 0.9      # Draft: and at least this share of the baseline's gain over identity
BEST_SECONDS = 3.0
BEST_TIE_DB = 0.05     # Best: the fastest front point within this of the most accurate (a tie)


@dataclass(frozen=True)
class Candidate:
    working_size: int
    augment: tuple = ()
    refine: int = 0
    matte_method: str = "ensemble"
    until_agreed: float | None = None  # relight.network.tta: stop after the first run when it agrees
    ensemble: tuple = ()  # registry names of other networks averaged in (Relighter.member)
    level: bool = True    # the model's level prior (relight.network.level) applied, where it has one

    @property
    def label(self) -> str:
        parts = [f"{self.working_size} px"]
        if self.augment:
            mirrored = any(m for _, m in self.augment)
            parts.append("mirror" if self.augment == ((1.0, True),) else
                         f"{len(self.augment) + 1} runs{'' if mirrored else ' (scales)'}")
            if self.until_agreed is not None:
                parts[-1] += f" (2 when the mirror agrees within {self.until_agreed:g})"
        if self.refine:
            parts.append(f"refine {self.refine}")
        if self.matte_method != "ensemble":
            parts.append(f"{self.matte_method} matte")
        if self.ensemble:
            parts.append(f"+ {len(self.ensemble)} other network{'s' if len(self.ensemble) > 1 else ''}")
        if not self.level:
            parts.append("no level prior")
        return ", ".join(parts)


BALANCED = Candidate(TRAINED_SIZE, ((1.0, True),))  # the rule's Balanced: the mirrored crop averaged in


def candidates(ensemble: tuple = ()) -> list[Candidate]:
    """The candidates timed and scored; with `ensemble` (registry names), the network alone and
    Best's runs with those networks averaged in too."""
    from relight.network import tta

    mirror = ((1.0, True),)
    scales = ((1.25, False), (0.75, False))
    out = [Candidate(s) for s in (64, 80, 96, 112, 128, 160)]
    out += [Candidate(s, matte_method="selfie") for s in (64, 80, 96, 112, 128)]
    out += [Candidate(TRAINED_SIZE, mirror), Candidate(TRAINED_SIZE, tta.AUGMENTATIONS),
            Candidate(TRAINED_SIZE, refine=2), Candidate(TRAINED_SIZE, refine=8),
            Candidate(TRAINED_SIZE, mirror, 8), Candidate(TRAINED_SIZE, scales, 8),
            Candidate(TRAINED_SIZE, tta.AUGMENTATIONS, 8), Candidate(160, tta.AUGMENTATIONS, 8),
            Candidate(TRAINED_SIZE, tta.AUGMENTATIONS, until_agreed=tta.AGREED),
            Candidate(TRAINED_SIZE, tta.AUGMENTATIONS, 8, until_agreed=tta.AGREED),
            Candidate(160, tta.AUGMENTATIONS), Candidate(160, tta.AUGMENTATIONS, until_agreed=tta.AGREED),
            Candidate(144, tta.AUGMENTATIONS, until_agreed=tta.AGREED),
            Candidate(176, tta.AUGMENTATIONS, until_agreed=tta.AGREED),
            Candidate(192, tta.AUGMENTATIONS, until_agreed=tta.AGREED),
            Candidate(TRAINED_SIZE, tta.AUGMENTATIONS, 16),
            Candidate(TRAINED_SIZE, level=False),
            Candidate(TRAINED_SIZE, tta.AUGMENTATIONS, until_agreed=tta.AGREED, level=False)]
    if ensemble:
        out += [Candidate(TRAINED_SIZE, ensemble=tuple(ensemble)),
                Candidate(TRAINED_SIZE, tta.AUGMENTATIONS, until_agreed=tta.AGREED, ensemble=tuple(ensemble)),
                Candidate(TRAINED_SIZE, tta.AUGMENTATIONS, ensemble=tuple(ensemble))]
    return out


def decompose(relighter, photo, candidate: Candidate, mask=None):
    """The decomposition a candidate gives (relight.network.runtime does the same for a preset)."""
    return relighter.decompose(photo, mask=mask, working_size=candidate.working_size,
                               matte_method=candidate.matte_method, augment=candidate.augment,
                               refine=candidate.refine, augment_until_agreed=candidate.until_agreed,
                               ensemble=candidate.ensemble, level=candidate.level)


def load_pairs(data, count: int, per_scene: int = 4) -> list[dict]:
    from model.samples.data import photo_pairs

    return list(photo_pairs(data, 256, count, per_scene))


def score(pred, pair) -> tuple[float, float]:
    from model.scoring import metrics
    from model.scoring.metrics import interior_weight

    w = interior_weight(pair["alpha"])
    return (metrics.psnr(pred, pair["target"], w), metrics.scale_invariant_psnr(pred, pair["target"], w))


def accuracy(relighter, pairs, cands) -> dict[Candidate, np.ndarray]:
    """{candidate: [pairs, 2] (PSNR, SI PSNR)}, plus "identity" (the photo as it is) and
    "exposure-matched identity" (scaled per channel by the true lights' DC ratio: an oracle)."""
    out = {c: [] for c in cands}
    out["identity"], out["exposure-matched identity"] = [], []
    for pair in pairs:
        gain = pair["light_b"][0] / np.where(pair["light_a"][0] > 0, pair["light_a"][0], 1.0)
        out["identity"].append(score(pair["photo"], pair))
        out["exposure-matched identity"].append(score(pair["photo"] * gain.astype(np.float32), pair))
        for c in cands:
            d = decompose(relighter, pair["photo"], c, mask=pair["alpha"])
            out[c].append(score(d.relight(pair["light_b"]), pair))
    return {k: np.array(v) for k, v in out.items()}


def timings(model_path, cands, size: int, threads: int, repeats: int) -> dict[Candidate, float]:
    from relight.files import photo as photo_io
    from relight.lighting.light import sh_light
    from relight.imaging.resample import resize_linear
    from relight.network.runtime import Relighter

    image = resize_linear(photo_io.read_photo(ROOT / "relight" / "data" / "examples" / "astronaut.jpg")[0],
                          size, size)
    relighter = Relighter(model_path, threads=threads)
    light = sh_light("sunset", relighter.sh_order)

    def run(c):
        decompose(relighter, image, c).relight(light)

    for c in cands:
        run(c)  # warm-up: sessions, caches
    times = {c: [] for c in cands}
    for _ in range(repeats):
        for c in cands:
            t = time.perf_counter()
            run(c)
            times[c].append(time.perf_counter() - t)
    return {c: statistics.median(v) * 1e3 for c, v in times.items()}


def rows_from(acc, ms, cands) -> list[dict]:
    baseline = next(c for c in cands if c == Candidate(TRAINED_SIZE))
    base, identity = acc[baseline], acc["identity"]
    base_gain = base[:, 0].mean() - identity[:, 0].mean()
    rows = []
    for c in cands:
        a = acc[c]
        diff = a[:, 0] - base[:, 0]
        rows.append({"candidate": c, "label": c.label, "ms": ms[c], "psnr": float(a[:, 0].mean()),
                     "si_psnr": float(a[:, 1].mean()), "worst": float(diff.min()),
                     "vs_base": float(diff.mean()), "se": float(diff.std(ddof=1) / np.sqrt(diff.size)),
                     "si_vs_base": float((a[:, 1] - base[:, 1]).mean()),
                     "share": float((a[:, 0].mean() - identity[:, 0].mean()) / base_gain) if base_gain > 0
                     else float("nan")})
    front = pareto_front([r["ms"] for r in rows], [-r["psnr"] for r in rows])
    for r, f in zip(rows, front):
        r["front"] = f
    return rows


def propose(rows: list[dict]) -> dict[str, dict]:
    """The rule of the module docstring, applied to the rows (the rows without the model's level
    prior are references: switching it off saves no time)."""
    front = sorted((r for r in rows if r["front"] and r["candidate"].level), key=lambda r: r["ms"])
    draft = next((r for r in front if r["vs_base"] >= -DRAFT_DB and r["share"] >= DRAFT_SHARE), None)
    balanced = next((r for r in rows if r["candidate"] == BALANCED), None)
    within = [r for r in front if r["ms"] <= BEST_SECONDS * 1e3]
    top = max((r["psnr"] for r in within), default=None)
    best = next((r for r in within if r["psnr"] >= top - BEST_TIE_DB), None) if within else None
    return {"draft": draft, "balanced": balanced, "best": best}


def markdown(rows, chosen, acc, info: str) -> str:
    lines = [info, "",
             "| candidate | ms (512 px photo) | PSNR | SI PSNR | PSNR vs network alone (paired mean +- SE) "
             "| SI vs network alone | worst pair | share of gain over identity | front |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: r["ms"]):
        lines.append(f"| {r['label']} | {r['ms']:.0f} | {r['psnr']:.2f} | {r['si_psnr']:.2f} | "
                     f"{r['vs_base']:+.2f} +- {r['se']:.2f} | {r['si_vs_base']:+.2f} | {r['worst']:+.2f} | "
                     f"{r['share']:.2f} | {'*' if r['front'] else ''} |")
    for name in ("identity", "exposure-matched identity"):
        a = acc[name]
        lines.append(f"| {name} | | {a[:, 0].mean():.2f} | {a[:, 1].mean():.2f} | | | | | |")
    lines.append("")
    for key, r in chosen.items():
        lines.append(f"- {key}: " + (f"{r['label']} ({r['ms']:.0f} ms, {r['psnr']:.2f} dB, SI {r['si_psnr']:.2f})"
                                     if r else "none meets the rule"))
    return "\n".join(lines)


def plot(rows: list[dict], chosen: dict, out: Path) -> Path:
    """Time against PSNR (and SI PSNR), the front joined, the chosen presets named."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    from relight.files.fileio import atomic_path

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, key, title in ((axes[0], "psnr", "relit PSNR (dB)"), (axes[1], "si_psnr", "scale-invariant PSNR (dB)")):
        for r in rows:
            ax.scatter(r["ms"], r[key], s=22, color="C0" if r["front"] else "0.6", zorder=3)
        front = sorted((r for r in rows if r["front"]), key=lambda r: r["ms"])
        ax.plot([r["ms"] for r in front], [r[key] for r in front], color="C0", lw=1)
        for name, r in chosen.items():
            if r is not None:
                ax.annotate(f"{name}: {r['label']}", (r["ms"], r[key]), fontsize=7, xytext=(4, -10),
                            textcoords="offset points")
        ax.set_xscale("log")
        ax.set_xlabel("ms on a 512 x 512 photo (segmenter to relit image)")
        ax.set_ylabel(title)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    with atomic_path(out, ".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True)
    p.add_argument("--model", default=None, help="ONNX file (default: the registry's default model)")
    p.add_argument("--pairs", type=int, default=96)
    p.add_argument("--per-scene", type=int, default=4, help="pairs (light a -> light b) per scene at most")
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--accuracy-cache", default=None, metavar="NPZ",
                   help="reuse the accuracy of an earlier run from this file (written when missing): "
                        "re-time on a quiet machine without recomputing it")
    p.add_argument("--doc", default=None, help="write the table into this markdown file's bench_quality section")
    p.add_argument("--plot", default=None, help="write the front as a PNG plot here")
    p.add_argument("--ensemble", nargs="*", default=(), metavar="NAME",
                   help="registry names of other networks: adds candidates that average them in")
    args = p.parse_args(argv)
    from relight.network.runtime import Relighter

    cands = candidates(tuple(args.ensemble))
    pairs = load_pairs(args.data, args.pairs, args.per_scene)
    if not pairs:
        print(f"error: no held-out pairs in {args.data}", file=sys.stderr)
        return 2
    cache = Path(args.accuracy_cache) if args.accuracy_cache else None
    keys = {c.label: c for c in cands}
    if cache is not None and cache.is_file():
        with np.load(cache, allow_pickle=False) as z:
            acc = {keys.get(k, k): z[k] for k in z.files}
        missing = [c.label for c in cands if c not in acc]
        if missing:
            print(f"error: {cache} lacks {', '.join(missing)}: delete it to recompute", file=sys.stderr)
            return 2
    else:
        acc = accuracy(Relighter(args.model, threads=args.threads), pairs, cands)
        if cache is not None:
            np.savez(cache, **{(k.label if isinstance(k, Candidate) else k): v for k, v in acc.items()})
    ms = timings(args.model, cands, args.size, args.threads, args.repeats)
    rows = rows_from(acc, ms, cands)
    chosen = propose(rows)
    info = (f"{len(pairs)} held-out pairs of {args.data}; time on a {args.size}x{args.size} photo, "
            f"{args.threads} threads, median of {args.repeats}, load average {os.getloadavg()[0]:.1f}, "
            f"{datetime.date.today()}")
    text = markdown(rows, chosen, acc, info)
    print(text)
    if args.plot:
        plot(rows, chosen, Path(args.plot))
    if args.doc:
        from relight.files.fileio import atomic_write_text

        doc = Path(args.doc)
        atomic_write_text(doc, replace_section(doc.read_text() if doc.exists() else "", "quality", text))
    return 0


if __name__ == "__main__":
    sys.exit(main())
