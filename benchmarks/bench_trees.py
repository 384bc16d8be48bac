"""The runtime of two source trees on one workload, alternated in one run (a refactor must not
slow it: compare the ratio, which a load drifting on a shared machine shifts alike).

    PYTHONPATH=. .venv/bin/python benchmarks/bench_trees.py --tree before=/tmp/old_checkout --tree after=. \\
        [--model relight/models/geometry.onnx] [--size 512] [--rounds 5] [--threads 1]

Each round runs every tree once, in a fresh process with only that tree on sys.path: the
bundled astronaut photo resized to --size, the person matte, Balanced's decomposition and a
full-size relight under the sunset preset, each timed after a warm-up (median of 3 inside the
process). The same model file runs in every tree (copied beside a .sha256 of its own, so each
tree's registry is not consulted). Prints a table of medians over the rounds and each tree's
ratio to the first.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

WORKLOAD = r"""
import json, statistics, sys, time
sys.path.insert(0, sys.argv[1])
from relight import photo as photo_io
from relight.lighting.light import sh_light
from relight.imaging.resample import resize_linear
from relight.network.runtime import Relighter
size, threads, model = int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
image = resize_linear(photo_io.read_photo(sys.argv[5])[0], size, size)
relighter = Relighter(model, threads=threads, working_size=128)
light = sh_light("sunset", relighter.sh_order)
def run():
    t0 = time.perf_counter()
    d = relighter.decompose(image)
    t1 = time.perf_counter()
    d.relight(light)
    return t1 - t0, time.perf_counter() - t1
run()
times = [run() for _ in range(3)]
print(json.dumps({"decompose": statistics.median(t for t, _ in times), "relight": statistics.median(r for _, r in times)}))
"""


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tree", action="append", required=True, metavar="NAME=PATH")
    p.add_argument("--model", default=str(ROOT / "relight" / "models" / "geometry.onnx"))
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)
    trees = dict(t.split("=", 1) for t in args.tree)
    work = Path(tempfile.mkdtemp())
    model = work / "model.onnx"
    shutil.copy(args.model, model)
    sys.path.insert(0, str(ROOT))
    from relight.files.fileio import file_sha256
    from relight.models import write_sidecar

    write_sidecar(model, file_sha256(model))
    photo = ROOT / "relight" / "data" / "examples" / "astronaut.jpg"
    results = {name: [] for name in trees}
    for _ in range(args.rounds):
        for name, path in trees.items():
            done = subprocess.run([sys.executable, "-c", WORKLOAD, str(Path(path).resolve()), str(args.size),
                                   str(args.threads), str(model), str(photo)],
                                  capture_output=True, text=True, check=False, cwd=work)
            if done.returncode != 0:
                print(f"bench_trees: {name} failed:\n{done.stderr[-2000:]}", file=sys.stderr)
                return 1
            results[name].append(json.loads(done.stdout.strip().splitlines()[-1]))
    first = next(iter(trees))
    print(f"{args.rounds} rounds, {args.size} px photo, {args.threads} thread(s); medians over rounds\n")
    print(f"| tree | decompose (ms) | relight (ms) | decompose / {first} | relight / {first} |")
    print("|---|---|---|---|---|")
    med = {n: {k: statistics.median(r[k] for r in rs) for k in ("decompose", "relight")} for n, rs in results.items()}
    for name in trees:
        m = med[name]
        print(f"| {name} | {m['decompose'] * 1e3:.1f} | {m['relight'] * 1e3:.1f} | "
              f"{m['decompose'] / med[first]['decompose']:.3f} | {m['relight'] / med[first]['relight']:.3f} |")
    print("\nPer-round ratios to the first tree (min / median / max): the spread is the noise.")
    for name in list(trees)[1:]:
        for key in ("decompose", "relight"):
            r = sorted(a[key] / b[key] for a, b in zip(results[name], results[first]))
            print(f"- {name} {key}: {r[0]:.3f} / {statistics.median(r):.3f} / {r[-1]:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
