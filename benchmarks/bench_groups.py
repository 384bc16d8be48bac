"""Group photos (issue 47): people found and relit in pasted groups of the bundled people
(evaluation.pasted_groups: 2 to 5 people, touching, overlapping, apart, of different sizes).

Per group: the number of people found against the truth, each true person's best-matching matte's IoU,
and whether every person was relit (their visible pixels changed by a coloured light, the background not).

    PYTHONPATH=. .venv/bin/python benchmarks/bench_groups.py [--groups 60] [--first-seed 0] [--quality balanced]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from evaluation.pasted_groups import pasted_group
from relight.lighting.light import sh_light
from relight.network.group import decompose_people
from relight.network.quality import PRESETS, preset
from relight.network.runtime import Relighter

CHANGED = 0.05   # a person's mean change under the test light, relative to their mean value, at least this


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--groups", type=int, default=60)
    parser.add_argument("--first-seed", type=int, default=0, help="the groups are seeds FIRST .. FIRST + GROUPS - 1")
    parser.add_argument("--quality", choices=[q.key for q in PRESETS], default="balanced")
    args = parser.parse_args(argv)
    q = preset(args.quality)
    relighter = Relighter(working_size=q.working_size)
    light = np.asarray(sh_light("sunset", relighter.sh_order), np.float64)
    right, relit_all, ious, by_count, times = 0, 0, [], {}, []
    for seed in range(args.first_seed, args.first_seed + args.groups):
        g = pasted_group(seed)
        k = len(g.names)
        start = time.perf_counter()
        group = decompose_people(relighter, g.photo, **q.decompose_options(working_size=False))
        out = group.relight(light)
        times.append(time.perf_counter() - start)
        found = [d.person_matte.alpha for d in group.people]
        ok = group.count == k
        right += ok
        by_count.setdefault(k, []).append(ok)
        change = np.abs(out - g.photo).mean(axis=-1)
        relit_all += all(change[m > 0.99].mean() > CHANGED * g.photo[m > 0.99].mean() for m in g.mattes)
        for m in g.mattes:
            truth = m > 0.5
            ious.append(max(((a > 0.5) & truth).sum() / ((a > 0.5) | truth).sum() for a in found))
        if not ok:
            print(f"seed {seed}: {k} people ({', '.join(g.names)}; {', '.join(g.spacings)}), found {group.count}")
    n = args.groups
    print(f"\n{args.quality}: {n} pasted groups")
    print("| people | groups | count right |")
    print("|---|---|---|")
    for k in sorted(by_count):
        print(f"| {k} | {len(by_count[k])} | {np.mean(by_count[k]):.0%} |")
    print(f"| all | {n} | {right / n:.0%} |")
    print(f"\nevery person relit: {relit_all / n:.0%}; matte IoU per true person: mean {np.mean(ious):.3f}, "
          f"10th percentile {np.percentile(ious, 10):.3f}; seconds per group (decompose + relight): "
          f"median {np.median(times):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
