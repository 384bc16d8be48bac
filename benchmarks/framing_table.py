"""Print the per-framing accuracy table of docs/EVALUATION.md from `python -m model.evaluate` runs.

    python benchmarks/framing_table.py LABEL=runs/eval37_hs [LABEL=RUN ...]

One row per run: the whole person (relit, SI, the untouched photo's SI, the exposure-matched
identity, normals' median) and the face (the farm's head mask: relit, SI, the untouched photo's
SI, normals' median), plus the issue-37 margins: relit minus the exposure-matched identity and
SI minus the untouched photo's SI (both goals are >= +2 dB on head-and-shoulders).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

COLUMNS = ("run", "pairs", "relit", "SI", "untouched SI", "exposure-matched", "relit - exp.-matched",
           "SI - untouched SI", "normals median", "face relit", "face SI", "face untouched SI",
           "face normals median")


def row(label: str, run: Path) -> list[str]:
    """One table row from RUN/evaluation.json."""
    d = json.loads((run / "evaluation.json").read_text())
    m = d["methods"]
    ours, ident = m["ours"]["relighting/image"], m["identity"]["relighting/image"]
    expo = m["identity, exposure-matched"]["relighting/image"]
    face = d.get("face") or {}
    fm = face.get("methods", {})
    cells = [label, str(d["pairs"]), f"{ours['psnr']:.2f}", f"{ours['si_psnr']:.2f}", f"{ident['si_psnr']:.2f}",
             f"{expo['psnr']:.2f}", f"{ours['psnr'] - expo['psnr']:+.2f}", f"{ours['si_psnr'] - ident['si_psnr']:+.2f}",
             f"{d['geometry']['ours']['normal_median_deg']:.1f}"]
    if fm:
        cells += [f"{fm['ours']['psnr']:.2f}", f"{fm['ours']['si_psnr']:.2f}", f"{fm['identity']['si_psnr']:.2f}",
                  f"{face['normal_median_deg']:.1f}"]
    else:
        cells += ["-"] * 4
    return cells


def main(argv: list[str]) -> int:
    if not argv:
        print(__doc__, file=sys.stderr)
        return 2
    rows = []
    for spec in argv:
        label, _, path = spec.rpartition("=")
        run = Path(path)
        if not (run / "evaluation.json").is_file():
            print(f"framing_table: error: no evaluation.json in {run}", file=sys.stderr)
            return 2
        rows.append(row(label or run.name, run))
    print("| " + " | ".join(COLUMNS) + " |")
    print("|" + "---|" * len(COLUMNS))
    for cells in rows:
        print("| " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
