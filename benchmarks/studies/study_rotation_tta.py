"""Issue 26: does Best gain from runs on the crop turned in the image plane?

    PYTHONPATH=. .venv/bin/python benchmarks/studies/study_rotation_tta.py --data data/heldout256 [--degrees 10] [--pairs 96]

Turning the photo by an angle in the image plane is turning the world about the camera's view
axis (+Y; image right is +X, up +Z): the network's answer on the turned crop, its transport
turned back on the pixel grid and the SH of transport and light rotated back
(relight.lighting.sh_rotation), is a second opinion like Best's mirrored and rescaled runs
(relight.network.tta). Held-out pairs in the runtime protocol (benchmarks/bench_quality.py: 256 px
crops, true alpha, 128 px), level prior on, paired against the network once.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks" / "studies"))

from study_gain_tta import paired_table  # noqa: E402


def about_view_axis(degrees: float) -> np.ndarray:
    """The world rotation an image turned counter-clockwise by `degrees` shows: X toward Z."""
    t = np.radians(degrees)
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def turned_run(relighter, base, degrees: float, mirrored: bool = False):
    """A relight.network.tta run of the network on base's working crop turned by `degrees`
    (counter-clockwise as displayed: scipy.ndimage.rotate's sense), in base's frame."""
    from scipy import ndimage

    from relight.lighting import sh_rotation
    from relight.network import tta

    small, matte = base.photo_working, base.alpha
    if mirrored:
        small, matte = small[:, ::-1], matte[:, ::-1]
    turned = ndimage.rotate(small, degrees, axes=(1, 0), reshape=False, order=1, mode="nearest")
    turned_matte = ndimage.rotate(matte, degrees, axes=(1, 0), reshape=False, order=1, mode="constant")
    out = relighter.run_crop(np.ascontiguousarray(turned, np.float32),
                             np.ascontiguousarray(np.clip(turned_matte, 0.0, 1.0), np.float32))
    back = sh_rotation.rotation_matrix(about_view_axis(degrees).T, base.sh_order)
    transport = ndimage.rotate(out["transport"], -degrees, axes=(1, 0), reshape=False, order=1, mode="nearest")
    n = transport.shape[-1]
    transport = (transport.reshape(-1, n) @ back.T).reshape(transport.shape).astype(np.float32)
    light = (back @ out["light"]).astype(np.float32)
    return tta._Run(transport, light, base.sh_order, base.working_size), mirrored


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True)
    p.add_argument("--pairs", type=int, default=None)
    p.add_argument("--degrees", type=float, default=10.0)
    p.add_argument("--model", default=str(ROOT / "relight/models/geometry.onnx"))
    args = p.parse_args(argv)
    from model.scoring import metrics
    from model.samples.data import photo_pairs
    from relight.network import tta
    from relight.network.level import apply as apply_level
    from relight.network.runtime import Relighter

    r = Relighter(args.model, threads=2)
    a = args.degrees
    names = ("network once", "mirrored", f"turned +-{a:g} deg", "Best's six runs",
             f"Best's six + turned +-{a:g}", f"Best's six + turned +-{a:g}, plain and mirrored")
    scores = {name: [] for name in names}
    for pair in photo_pairs(args.data, 256, args.pairs):
        base = r.decompose(pair["photo"], mask=pair["alpha"], level=False, working_size=128)
        six = tta.runs(r, base, tta.AUGMENTATIONS)
        turned = [turned_run(r, base, a), turned_run(r, base, -a)]
        turned_mirrored = [turned_run(r, base, a, True), turned_run(r, base, -a, True)]
        sets = ([], six[:1], turned, six, six + turned, six + turned + turned_mirrored)
        weight = metrics.interior_weight(pair["alpha"])
        for name, runs in zip(names, sets):
            d, _ = apply_level(tta.average(base, runs), r.level_prior)
            scores[name].append(metrics.psnr(d.relight(pair["light_b"]), pair["target"], weight))
    print(paired_table(scores, "network once", args.data))
    return 0


if __name__ == "__main__":
    sys.exit(main())
