"""Cut a small test fixture out of a farm clip: tests/data/farm_clip.npz (tests/relight/command/test_clip_flicker.py).

    python -m farm --out data/clips128_turn --scenes 64 --seed 28 --clip-frames 32 --motion turn \\
        --res 128 --lights 2 --samples 32 --light-pool heldout
    python tools/make_clip_fixture.py data/clips128_turn --clip 1 --frames 16 --out tests/data/farm_clip.npz

Keeps the first FRAMES frames of one clip (PRT person over the path-traced background,
model.evaluate_clips.load_clips), cropped to the columns around the person, as 8-bit
sRGB (input and truth) and 8-bit alpha: about 0.3 MB.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv=None) -> int:
    from model.evaluate_clips import load_clips
    from relight.imaging.colour import srgb_encode
    from relight.files.fileio import atomic_path

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folder")
    p.add_argument("--clip", type=int, default=0, help="which clip of the folder (in clip order)")
    p.add_argument("--frames", type=int, default=16)
    p.add_argument("--margin", type=int, default=200, help="pixels kept beside the person's columns (a narrow crop\n                   changes what the person matte sees: keep the whole frame unless it is large)")
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    clip = load_clips([args.folder], args.frames, source="prt")[args.clip]
    cols = np.flatnonzero(clip["alpha"].max(axis=(0, 1)) > 0)
    x0, x1 = max(0, cols[0] - args.margin), min(clip["alpha"].shape[2], cols[-1] + 1 + args.margin)

    def u8(x):
        return np.rint(srgb_encode(x[..., x0:x1, :]) * 255).astype(np.uint8)

    with atomic_path(args.out, ".npz") as tmp:
        np.savez_compressed(tmp, frames=u8(clip["frames"]), truth=u8(clip["truth"]),
                            alpha=np.rint(clip["alpha"][..., x0:x1] * 255).astype(np.uint8),
                            light=clip["light"], source=np.array(f"{clip['name']} frames 0-{args.frames - 1}, "
                                                                 f"columns {x0}-{x1 - 1}"))
    print(f"wrote {args.out} ({Path(args.out).stat().st_size:,} bytes) from {clip['name']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
