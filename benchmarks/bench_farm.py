"""Render-farm throughput: scenes/hour, path-traced images/hour and time outside path tracing.

    .venv/bin/python benchmarks/bench_farm.py --scenes 4 --workers 1,2
    .venv/bin/python benchmarks/bench_farm.py --tree before=/tmp/farm_old --rounds 2 ...

Runs the real farm (`python -m farm`, real farm.scene.render_scene) once per
worker count into a temporary folder and prints one table row each:

- scenes/hour and path-traced images/hour over the run's wall time, worker
  start-up, bpy import, validation and bookkeeping included;
- "outside PT (run)": the share of worker time (wall x workers) not spent
  inside Cycles' render calls of the K lit images, from the per-stage timings
  each scene's sidecar records (the stages named --pt-stage);
- "outside PT (warm scenes)": the same per scene, over scenes that were not
  their worker's first (the first also pays imports and the body-model build,
  once per `--recycle` scenes);
- "runner + start-up": worker time outside any scene (worker start, bpy
  import, validation, idle);
- the mean per-stage seconds of one scene.

The machine may be shared: compare rows of one run, not across runs.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def flat_timings(timings: dict, prefix: str = "") -> dict[str, float]:
    """{'stage': s} from a possibly nested timings dict ('a.b' for nested keys)."""
    flat = {}
    for key, value in timings.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(flat_timings(value, name + "."))
        elif isinstance(value, (int, float)) and not isinstance(value, bool):
            flat[name] = float(value)
        elif isinstance(value, list) and all(isinstance(v, (int, float)) for v in value):
            flat[name] = float(sum(value))  # per-light seconds -> per-scene total
    return flat


def run_once(workers: int, args, repo: Path = REPO, label: str = "this tree") -> dict:
    with tempfile.TemporaryDirectory(prefix="bench_farm_", dir=args.tmp) as tmp:
        out = Path(tmp) / "out"
        command = [sys.executable, "-m", "farm", "--out", str(out), "--scenes", str(args.scenes),
                   "--seed", str(args.seed), "--res", str(args.res), "--lights", str(args.lights),
                   "--samples", str(args.samples), "--denoise" if args.denoise else "--no-denoise",
                   "--workers", str(workers), "--no-progress"]
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(repo), env.get("PYTHONPATH")) if p)
        t0 = time.monotonic()
        r = subprocess.run(command, cwd=repo, env=env, capture_output=True, text=True)
        wall_outer = time.monotonic() - t0
        if r.returncode != 0:
            raise SystemExit(f"farm run failed ({r.returncode}): {r.stderr.strip().splitlines()[-1:]}")
        log = json.loads((out / "farm_runlog.json").read_text())["runs"][-1]
        summary = log["summary"]
        done = [rec for rec in log["scenes"] if rec["status"] == "done"]
        stages = [flat_timings(rec["timings"]) for rec in done]
        # A worker's first scene also pays for imports and the body model build.
        first_of_worker = {min(r["index"] for r in done if r["worker"] == pid) for pid in {r["worker"] for r in done}}
    names = sorted({k for s in stages for k in s})
    pt_names = [n for n in names if any(n == p or n.endswith("." + p) for p in args.pt_stage)]
    if not pt_names:
        raise SystemExit(f"no timing stage named {args.pt_stage} in the sidecars; stages: {names}")
    pt_seconds = sum(s.get(n, 0.0) for s in stages for n in pt_names)
    worker_seconds = summary["wall_seconds"] * workers
    scene_seconds = sum(r["seconds"] for r in done)
    warm = [(r, s) for r, s in zip(done, stages) if r["index"] not in first_of_worker]
    warm_share = (1.0 - sum(s.get(n, 0.0) for _, s in warm for n in pt_names) / sum(r["seconds"] for r, _ in warm)
                  if warm else float("nan"))
    return {
        "tree": label,
        "workers": workers,
        "scenes": summary["done"],
        "retried": summary["retried"],
        "failed": summary["failed"],
        # Failed attempts by kind (pids and numbers masked): "worker N killed by SIGSEGV ..." x3
        "errors": collections.Counter(re.sub(r"\d+", "N", e) for rec in log["scenes"] for e in rec["errors"]),
        "wall": summary["wall_seconds"],
        "wall_outer": wall_outer,
        "scenes_per_hour": summary["scenes_per_hour"],
        "images_per_hour": summary["images_per_hour"],
        "outside_pt": 1.0 - pt_seconds / worker_seconds,
        "outside_pt_warm": warm_share,
        "warm_scenes": len(warm),
        "runner_share": 1.0 - scene_seconds / worker_seconds,
        "pt_names": pt_names,
        "stage_means": {n: statistics.fmean(s.get(n, 0.0) for s in stages) for n in names},
    }


def warm_text(row: dict) -> str:
    if not row["warm_scenes"]:
        return "n/a (0)"
    return f"{100 * row['outside_pt_warm']:.1f}% ({row['warm_scenes']})"


def runner_only(workers: int, scenes: int, tmp_root) -> dict:
    """The runner's own cost per scene: tests/support/farm_fault_job.py writes an 8x8 scene at once,
    so what remains is dispatch, the worker round trip, validation and bookkeeping."""
    with tempfile.TemporaryDirectory(prefix="bench_runner_", dir=tmp_root) as tmp:
        out = Path(tmp) / "out"
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH")) if p)
        env["FARM_FAULT_DIR"] = tmp
        command = [sys.executable, "-m", "farm", "--out", str(out), "--scenes", str(scenes), "--seed", "0",
                   "--workers", str(workers), "--recycle", "1000", "--job-module", "tests.support.farm_fault_job",
                   "--no-progress"]
        r = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True)
        if r.returncode != 0:
            raise SystemExit(f"runner-only run failed: {r.stderr.strip().splitlines()[-1:]}")
        s = json.loads((out / "farm_runlog.json").read_text())["runs"][-1]["summary"]
    return {"workers": workers, "scenes": s["done"], "wall": s["wall_seconds"],
            "ms_per_scene": 1000 * s["wall_seconds"] * workers / s["done"]}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", type=int, default=4)
    p.add_argument("--workers", default="1,2", help="comma list of worker counts")
    p.add_argument("--seed", type=int, default=2021)
    p.add_argument("--res", type=int, default=256)
    p.add_argument("--lights", type=int, default=4)
    p.add_argument("--samples", type=int, default=64)
    p.add_argument("--denoise", action=argparse.BooleanOptionalAction, default=True)
    p.add_argument("--pt-stage", default="path_trace_render_calls",
                   help="comma list of sidecar timing stages that are Cycles path tracing")
    p.add_argument("--tmp", default=None, help="folder for the temporary outputs")
    p.add_argument("--tree", action="append", default=[], metavar="LABEL=PATH",
                   help="also run the farm of another checkout (e.g. a git worktree of an older commit), "
                        "alternating with this one; rows are labelled")
    p.add_argument("--rounds", type=int, default=1, help="alternating rounds over the trees")
    p.add_argument("--runner-only", type=int, default=0, metavar="N",
                   help="instead: N instant scenes (tests/support/farm_fault_job.py) to time the runner itself")
    args = p.parse_args()
    if args.runner_only:
        rows = [runner_only(int(w), args.runner_only, args.tmp) for w in args.workers.split(",")]
        print(f"# runner only: {args.runner_only} instant 8x8 scenes (no bpy)")
        print("| workers | scenes | wall s | worker-ms per scene |")
        print("|---|---|---|---|")
        for r in rows:
            print(f"| {r['workers']} | {r['scenes']} | {r['wall']:.2f} | {r['ms_per_scene']:.1f} |")
        return
    args.pt_stage = [s.strip() for s in args.pt_stage.split(",") if s.strip()]
    trees = [("this tree", REPO)] + [(t.split("=", 1)[0], Path(t.split("=", 1)[1]).resolve()) for t in args.tree]
    rows = [run_once(int(w), args, repo, label)
            for _ in range(args.rounds) for w in args.workers.split(",") for label, repo in trees]
    print(f"# {args.scenes} scenes, {args.res}x{args.res}, K={args.lights}, {args.samples} spp, "
          f"denoise={'on' if args.denoise else 'off'}; path-tracing stages: {', '.join(rows[0]['pt_names'])}")
    print("| tree | workers | scenes done | retried | failed | wall s | scenes/hour | path-traced images/hour "
          "| outside PT (run) | outside PT (warm scenes) | runner + start-up |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['tree']} | {r['workers']} | {r['scenes']} | {r['retried']} | {r['failed']} | {r['wall']:.1f} | "
              f"{r['scenes_per_hour']:.0f} | {r['images_per_hour']:.0f} | {100 * r['outside_pt']:.1f}% | "
              f"{warm_text(r)} | {100 * r['runner_share']:.1f}% |")
    for r in rows:
        if r["errors"]:
            kinds = "; ".join(f"{text} x{n}" for text, n in r["errors"].most_common())
            print(f"\n{r['workers']} worker(s), failed attempts: {kinds}")
    print()
    names = sorted({n for r in rows for n in r["stage_means"]})
    print("| stage (mean s per scene) | " + " | ".join(f"{r['tree']}, {r['workers']} worker(s)" for r in rows) + " |")
    print("|---|" + "---|" * len(rows))
    for n in names:
        print(f"| {n} | " + " | ".join(f"{r['stage_means'].get(n, 0.0):.2f}" for r in rows) + " |")


if __name__ == "__main__":
    main()
