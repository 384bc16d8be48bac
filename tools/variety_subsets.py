"""The variety point of issue 45's scaling study: two folders of links into a farm folder, of the
same number of scenes, one with half of what the farm varies in a look and one with all of it.

    .venv/bin/python tools/variety_subsets.py FARM_DIR OUT_DIR [--exclude FIRST LAST] [--seed 45]

narrow/  every scene whose garments are all plain or denim (no stripes, checks, knit or noise
         prints) and whose hair is short, long, medium or bald (four of the eight styles);
broad/   as many scenes drawn at random (seed) from the same pool, every look.
Scenes with indices in [FIRST, LAST) are left out of both (a set kept for calibration). Only scenes
whose EXR is there count. Each folder holds links to the scene's .json and .exr; a rerun adds
what is missing. docs/EVALUATION.md, "The curve in variety".
"""

from __future__ import annotations

import argparse
import random
import sys
from pathlib import Path

from relight.files.dataset import read_sidecar

NARROW_PATTERNS = frozenset({"none", "denim"})
NARROW_HAIR = frozenset({"short", "long", "medium", "bald"})


def is_narrow(appearance: dict) -> bool:
    """Whether a scene's look (its sidecar's "appearance") lies in the narrow half."""
    patterns = {garment["material"]["pattern"] for garment in appearance["garments"].values()}
    return patterns <= NARROW_PATTERNS and appearance["hair"]["style"] in NARROW_HAIR


def subsets(farm: Path, exclude: tuple[int, int] | None = None, seed: int = 45) -> dict[str, list[Path]]:
    """{"narrow": [...], "broad": [...]}: the scenes' .json paths, in index order."""
    pool, narrow = [], []
    for path in sorted(farm.glob("scene_*.json")):
        if not path.with_suffix(".exr").is_file():
            continue
        meta = read_sidecar(path)  # ValueError naming the file when it is not a finished scene's
        try:
            index, look = int(meta["index"]), is_narrow(meta["appearance"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{path}: no look in the sidecar ({exc!r})") from None
        if exclude and exclude[0] <= index < exclude[1]:
            continue
        pool.append(path)
        if look:
            narrow.append(path)
    broad = sorted(random.Random(seed).sample(pool, len(narrow)))
    return {"narrow": narrow, "broad": broad}


def link(paths: list[Path], out: Path) -> None:
    """Links in `out` to each scene's .json and .exr (kept when already there)."""
    out.mkdir(parents=True, exist_ok=True)
    for path in paths:
        for source in (path, path.with_suffix(".exr")):
            target = out / source.name
            if not target.is_symlink():
                target.symlink_to(source.resolve())


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("farm", type=Path, help="a farm folder (scene_NNNNNN.json and .exr)")
    p.add_argument("out", type=Path, help="where narrow/ and broad/ go")
    p.add_argument("--exclude", type=int, nargs=2, metavar=("FIRST", "LAST"), help="indices left out")
    p.add_argument("--seed", type=int, default=45)
    args = p.parse_args(argv)
    try:
        sets = subsets(args.farm, tuple(args.exclude) if args.exclude else None, args.seed)
        for name, paths in sets.items():
            link(paths, args.out / name)
            print(f"{args.out / name}: {len(paths)} scenes")
    except (ValueError, OSError) as exc:
        print(f"variety_subsets: error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
