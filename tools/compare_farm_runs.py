"""Are two farm runs the same scenes? Compares each scene's JSON sidecar (less its timings,
the code version and the list of skipped passes, which name passes one tree has and the other
lacks) and every EXR channel the two files share, bit for bit.

    python tools/compare_farm_runs.py RUN_A RUN_B

Made for refactors that must not change the farm's output (issue 29): render the same
`--seed` with each tree (the same `--passes`), then compare. Exit 0 when identical, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

VOLATILE = ("timings", "skipped", "code_version")


def stable(record):
    """The sidecar without what differs between two runs of the same scene."""
    if isinstance(record, dict):
        return {k: stable(v) for k, v in record.items() if k not in VOLATILE}
    if isinstance(record, list):
        return [stable(v) for v in record]
    return record


def compare(run_a: Path, run_b: Path) -> list[str]:
    import OpenEXR

    problems = []
    names_a = sorted(p.name for p in run_a.glob("scene_*.json"))
    names_b = sorted(p.name for p in run_b.glob("scene_*.json"))
    if names_a != names_b or not names_a:
        return [f"scene lists differ or are empty: {len(names_a)} against {len(names_b)}"]
    for name in names_a:
        a, b = (stable(json.loads((run / name).read_text())) for run in (run_a, run_b))
        if a != b:
            keys = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
            problems.append(f"{name}: sidecar differs in {', '.join(keys)}")
        exr = name.replace(".json", ".exr")
        ca, cb = (OpenEXR.File(str(run / exr)).channels() for run in (run_a, run_b))
        for channel in sorted(set(ca) & set(cb)):
            if not np.array_equal(ca[channel].pixels, cb[channel].pixels):
                problems.append(f"{exr}: channel {channel} differs")
        if set(ca) != set(cb):
            problems.append(f"{exr}: channels only in one run: {sorted(set(ca) ^ set(cb))}")
    return problems


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run_a", type=Path)
    p.add_argument("run_b", type=Path)
    args = p.parse_args(argv)
    problems = compare(args.run_a, args.run_b)
    for line in problems:
        print(line)
    if not problems:
        print(f"identical: {len(list(args.run_a.glob('scene_*.json')))} scenes")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
