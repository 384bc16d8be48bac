"""python -m model.average START.safetensors END.safetensors --weight W --out OUT.safetensors

A network between two checkpoints of one config: every weight (1 - W) * START's + W * END's
(model.training.checkpoint.interpolate_models). Issue 45: the release and a warm restart trained on
from it with the sun-response loss, averaged half and half, keep most of the restart's gain in the
light's response and lose less of the full body's level than the restart alone (docs/EVALUATION.md,
"Half-way between the release and its sun-response restart").
OUT gets END's metadata and the two files' SHA-256 and W; export it with `python -m export OUT`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m model.average", description=__doc__.splitlines()[2])
    p.add_argument("start", type=Path, help="the first checkpoint (.safetensors)")
    p.add_argument("end", type=Path, help="the second checkpoint, of the same config")
    p.add_argument("--weight", type=float, default=0.5, help="END's share, in [0, 1] (default 0.5)")
    p.add_argument("--out", type=Path, required=True, help="the averaged checkpoint (.safetensors)")
    args = p.parse_args(argv)
    try:
        from model.training.checkpoint import interpolate_models, save_model

        model, meta = interpolate_models(args.start, args.end, args.weight)
        save_model(model, args.out, meta)
    except (ValueError, OSError) as exc:
        print(f"model.average: error: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {args.out}: {1 - args.weight:g} x {args.start} + {args.weight:g} x {args.end}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
