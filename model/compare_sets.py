"""Two evaluated sets of paired scenes compared per framing:
`python -m model.compare_sets FIRST SECOND [--labels A B] [--margin DB]`.

FIRST and SECOND are model.evaluate's outputs: an evaluation.json, a folder holding one, or a data
folder whose eval/ holds one. Per set, framing and overall (means over the pairs, as model.evaluate):
our relit PSNR, the exposure-matched photo's PSNR on the same pairs (model.scoring.pair_metrics's
identity row), the gain over it, and the light's response (model.scoring.metrics.light_response's slope
and correlation, pairs without a true change left out). Then SECOND less FIRST: scenes are paired by
the sidecar's seed and index (pairs within a scene by their lights), the unit is a scene (its pairs
share a person and lights, so they are not independent), and each difference is the mean over the
paired scenes +- its standard error, with the one-sided 95 % lower bound mean - t * s.e. (Student's t,
n - 1 degrees of freedom), the rule of tests/relight/network/test_shipped_model.py. A framing whose
scenes share no seed and index gets Welch's unpaired difference of the sets' per-scene means instead.
Scenes and pairs found in one set only are listed, never dropped in silence. A missing or damaged
evaluation.json (or one written before model.evaluate recorded each pair's seed and exposure-matched
PSNR) is one line naming it on stderr, exit 2.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

CONFIDENCE = 0.95  # one-sided, over scenes
ALL = "all"
# each pair of evaluation.json's per_pair: what this command reads (seed: None for scenes without one)
NUMBERS = ("relit_psnr", "matched_photo_psnr")
RESPONSE = ("light_slope", "light_correlation")   # NaN where the truth does not change


def evaluation_file(path) -> Path:
    """The evaluation.json of `path`: the file itself, PATH/evaluation.json or PATH/eval/evaluation.json."""
    path = Path(path)
    if path.is_file():
        return path
    for candidate in (path / "evaluation.json", path / "eval" / "evaluation.json"):
        if candidate.is_file():
            return candidate
    raise ValueError(f"{path / 'evaluation.json'}: missing (nor {path / 'eval' / 'evaluation.json'}); "
                     f"write it with python -m model.evaluate MODEL --data DATA --out {path}")


def _number(value, finite: bool) -> bool:
    return (isinstance(value, (int, float)) and not isinstance(value, bool)
            and (math.isfinite(value) or (not finite and math.isnan(value))))


def read_pairs(path) -> list[dict]:
    """The pairs of an evaluation.json: {"scene": (seed, index), "lights": (a, b), "framing", "relit",
    "matched", "slope", "correlation"}; ValueError naming the file when it cannot be read or lacks them."""
    file = evaluation_file(path)
    try:
        record = json.loads(file.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{file}: not a readable evaluation.json ({exc})") from None
    per_pair = record.get("per_pair") if isinstance(record, dict) else None
    pair_list = record.get("pair_list") if isinstance(record, dict) else None
    if not isinstance(per_pair, list) or not isinstance(pair_list, list) or len(per_pair) != len(pair_list) \
            or not per_pair:
        raise ValueError(f"{file}: no per_pair records matching pair_list (not model.evaluate's evaluation.json)")
    out = []
    for i, (p, ids) in enumerate(zip(per_pair, pair_list)):
        if not isinstance(p, dict) or not (isinstance(ids, list) and len(ids) == 3):
            raise ValueError(f"{file}: pair {i} is not a record")
        if "seed" not in p or "matched_photo_psnr" not in p:
            raise ValueError(f"{file}: pair {i} has no seed or matched_photo_psnr (written by an older "
                             "model.evaluate): evaluate the set again")
        bad = [k for k in NUMBERS if not _number(p.get(k), True)] + \
              [k for k in RESPONSE if not _number(p.get(k), False)]
        if bad or not isinstance(p.get("framing"), str) or not _number(p.get("scene"), True) \
                or not (p["seed"] is None or _number(p["seed"], True)):
            raise ValueError(f"{file}: pair {i} has no valid {', '.join(bad) or 'scene, seed or framing'}")
        out.append({"scene": (p["seed"], int(p["scene"])), "lights": (int(ids[1]), int(ids[2])),
                    "framing": p["framing"], "relit": float(p["relit_psnr"]),
                    "matched": float(p["matched_photo_psnr"]), "slope": float(p["light_slope"]),
                    "correlation": float(p["light_correlation"])})
    keys = [(r["scene"], r["lights"]) for r in out]
    if len(set(keys)) != len(keys):
        raise ValueError(f"{file}: two pairs share a seed, scene index and lights (scenes of two seeds "
                         "without a recorded seed?)")
    return out


def _finite_mean(values) -> float:
    values = [v for v in values if math.isfinite(v)]
    return float(np.mean(values)) if values else float("nan")


def set_summary(pairs: list[dict]) -> dict:
    """{framing or ALL: {"scenes", "pairs", "relit", "matched", "gain", "slope", "correlation"}}."""
    out = {}
    for framing in sorted({p["framing"] for p in pairs}) + [ALL]:
        rows = [p for p in pairs if framing in (ALL, p["framing"])]
        relit, matched = float(np.mean([p["relit"] for p in rows])), float(np.mean([p["matched"] for p in rows]))
        out[framing] = {"scenes": len({p["scene"] for p in rows}), "pairs": len(rows), "relit": relit,
                        "matched": matched, "gain": relit - matched,
                        "slope": _finite_mean(p["slope"] for p in rows),
                        "correlation": _finite_mean(p["correlation"] for p in rows)}
    return out


def t_quantile(df: float) -> float:
    """Student's t at CONFIDENCE (one-sided) with `df` degrees of freedom."""
    from scipy import stats

    return float(stats.t.ppf(CONFIDENCE, df))


def paired_bound(differences) -> dict:
    """mean, standard error and one-sided lower bound of per-scene differences (n < 2: no bound)."""
    d = np.asarray(differences, np.float64)
    n, mean = d.size, float(d.mean())
    if n < 2:
        return {"n": n, "mean": mean, "se": float("nan"), "bound": float("nan"), "paired": True}
    se = float(d.std(ddof=1)) / math.sqrt(n)
    return {"n": n, "mean": mean, "se": se, "bound": mean - t_quantile(n - 1) * se, "paired": True}


def welch_bound(second, first) -> dict:
    """mean(second) - mean(first) of unpaired per-scene values, Welch's standard error and lower bound."""
    x, y = np.asarray(second, np.float64), np.asarray(first, np.float64)
    mean = float(x.mean() - y.mean())
    if x.size < 2 or y.size < 2:
        return {"n": 0, "mean": mean, "se": float("nan"), "bound": float("nan"), "paired": False}
    vx, vy = x.var(ddof=1) / x.size, y.var(ddof=1) / y.size
    se = math.sqrt(vx + vy)
    if se == 0.0:
        return {"n": 0, "mean": mean, "se": 0.0, "bound": mean, "paired": False}
    df = (vx + vy) ** 2 / (vx ** 2 / (x.size - 1) + vy ** 2 / (y.size - 1))
    return {"n": 0, "mean": mean, "se": se, "bound": mean - t_quantile(df) * se, "paired": False}


def _by_scene(pairs: list[dict]) -> dict:
    scenes = defaultdict(dict)
    for p in pairs:
        scenes[p["scene"]][p["lights"]] = p
    return scenes


def _scene_means(scenes: dict) -> dict:
    """{scene: (framing, mean relit, mean gain)} over each scene's pairs."""
    return {s: (next(iter(ps.values()))["framing"], float(np.mean([p["relit"] for p in ps.values()])),
                float(np.mean([p["relit"] - p["matched"] for p in ps.values()]))) for s, ps in scenes.items()}


def compare(first: list[dict], second: list[dict]) -> dict:
    """SECOND less FIRST per framing and ALL: {"relit": bound dict, "gain": bound dict} (paired_bound over
    the scenes both sets hold, else welch_bound), and what could not be paired."""
    a, b = _by_scene(first), _by_scene(second)
    shared = sorted(set(a) & set(b), key=str)
    reframed = [s for s in shared if {p["framing"] for p in a[s].values()} != {p["framing"] for p in b[s].values()}]
    unmatched_pairs = 0
    diffs = defaultdict(lambda: {"relit": [], "gain": []})
    for s in shared:
        if s in reframed:
            continue
        lights = sorted(set(a[s]) & set(b[s]))
        unmatched_pairs += len(set(a[s]) ^ set(b[s]))
        if not lights:
            continue
        framing = a[s][lights[0]]["framing"]
        d_relit = float(np.mean([b[s][k]["relit"] - a[s][k]["relit"] for k in lights]))
        d_gain = float(np.mean([(b[s][k]["relit"] - b[s][k]["matched"]) - (a[s][k]["relit"] - a[s][k]["matched"])
                                for k in lights]))
        for key in (framing, ALL):
            diffs[key]["relit"].append(d_relit)
            diffs[key]["gain"].append(d_gain)
    means_a, means_b = _scene_means(a), _scene_means(b)
    rows = {}
    for framing in sorted({p["framing"] for p in first + second}) + [ALL]:
        if diffs[framing]["relit"]:
            rows[framing] = {k: paired_bound(diffs[framing][k]) for k in ("relit", "gain")}
            continue
        xa = [v for v in means_a.values() if framing in (ALL, v[0])]
        xb = [v for v in means_b.values() if framing in (ALL, v[0])]
        if xa and xb:
            rows[framing] = {k: welch_bound([v[i] for v in xb], [v[i] for v in xa])
                             for i, k in ((1, "relit"), (2, "gain"))}
    return {"rows": rows, "only_first": sorted(set(a) - set(b), key=str),
            "only_second": sorted(set(b) - set(a), key=str), "reframed": reframed,
            "unmatched_pairs": unmatched_pairs}


def _scene_names(scenes) -> str:
    shown = ", ".join(f"{seed}:{index}" if seed is not None else str(index) for seed, index in scenes[:12])
    return shown + (f" and {len(scenes) - 12} more" if len(scenes) > 12 else "")


def _difference(v: dict) -> str:
    se = "-" if math.isnan(v["se"]) else f"{v['se']:.2f}"
    return f"{v['mean']:+.2f} +- {se}" + ("" if v["paired"] else " (unpaired)")


def _bound(v: dict) -> str:
    return "-" if math.isnan(v["bound"]) else f"{v['bound']:+.2f}"


def markdown(labels: tuple[str, str], files: tuple[Path, Path], summaries: tuple[dict, dict], comparison: dict,
             margin: float) -> str:
    first, second = labels
    lines = [f"# {second} against {first}", "",
             f"{first}: `{files[0]}`; {second}: `{files[1]}`. PSNR in dB over the pairs (model.evaluate); "
             "slope and correlation of the light's response (model.scoring.metrics.light_response).", "",
             "| set | framing | scenes | pairs | relit PSNR | exposure-matched photo PSNR | gain over it | slope | "
             "correlation |", "|---|---|---|---|---|---|---|---|---|"]
    for label, summary in zip(labels, summaries):
        for framing, v in summary.items():
            lines.append(f"| {label} | {framing} | {v['scenes']} | {v['pairs']} | {v['relit']:.2f} | "
                         f"{v['matched']:.2f} | {v['gain']:+.2f} | {v['slope']:.2f} | {v['correlation']:.2f} |")
    lines += ["", f"{second} - {first}, per scene (mean over its pairs), mean +- standard error over the scenes; "
              f"one-sided {CONFIDENCE:.0%} lower bound (Student's t):", "",
              f"| framing | scenes paired | relit | bound | within {margin:g} dB (bound > -{margin:g}) | "
              "gain over the exposure-matched photo | bound |", "|---|---|---|---|---|---|---|"]
    for framing, v in comparison["rows"].items():
        r, g = v["relit"], v["gain"]
        within = "-" if math.isnan(r["bound"]) else ("yes" if r["bound"] > -margin else "no")
        lines.append(f"| {framing} | {r['n']} | {_difference(r)} | {_bound(r)} | {within} | {_difference(g)} | "
                     f"{_bound(g)} |")
    notes = []
    for label, key in ((first, "only_first"), (second, "only_second")):
        if comparison[key]:
            notes.append(f"- {len(comparison[key])} scenes of {label} only (seed:index), not paired: "
                         f"{_scene_names(comparison[key])}")
    if comparison["reframed"]:
        notes.append(f"- {len(comparison['reframed'])} scenes share a seed and index but not the framing, "
                     f"not paired: {_scene_names(comparison['reframed'])}")
    if comparison["unmatched_pairs"]:
        notes.append(f"- {comparison['unmatched_pairs']} pairs of paired scenes have lights the other set's "
                     "scene lacks, not paired")
    return "\n".join(lines + ([""] + notes if notes else [])) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m model.compare_sets", description=__doc__.splitlines()[0])
    p.add_argument("first", help="evaluation.json, its folder, or a data folder with eval/evaluation.json")
    p.add_argument("second", help="the same for the set compared with FIRST")
    p.add_argument("--labels", nargs=2, default=("first", "second"), metavar=("A", "B"), help="the sets' names")
    p.add_argument("--margin", type=float, default=2.0,
                   help="dB the second set may fall below the first (the 'within' column; default 2)")
    args = p.parse_args(argv)
    try:
        files = (evaluation_file(args.first), evaluation_file(args.second))
        pairs = (read_pairs(files[0]), read_pairs(files[1]))
    except ValueError as exc:
        print(f"model.compare_sets: error: {exc}", file=sys.stderr)
        return 2
    print(markdown(tuple(args.labels), files, (set_summary(pairs[0]), set_summary(pairs[1])),
                   compare(pairs[0], pairs[1]), args.margin), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
