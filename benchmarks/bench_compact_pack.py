"""What the compact training pack (model.samples.compact_pack) costs in accuracy and buys in bytes
(issue 45): per JPEG quality, the bytes per scene and each training map's error against the exact
pack, over the exact pack's first scenes.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_compact_pack.py ~/.cache/relight/campaigns/scale45/pack.npz \\
        [--scenes 40] [--qualities 75,85,90,95] [--without depth body]

Errors are over the person (alpha > 0.5): PSNR of the traced images, of albedo x (T . L) under
each scene's own lights (what the bank lights' targets are made of) and of the albedo, each
through a 1/2.2 curve after dividing by the exact map's brightest value; the normal's angle
(median and 95th percentile); the transport's relative error (|dT| / |T|, root mean square).
Prints one markdown row per quality. Scenes are spread over the pack (every k-th).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from model.samples.compact_pack import decode_scene, encode_scene
from model.samples.data import scene_prt
from model.samples.training_pack import iter_training_pack, read_manifest


def psnr_display(want: np.ndarray, got: np.ndarray, mask: np.ndarray) -> float:
    """PSNR of [C, S, S] maps over `mask` through a 1/2.2 curve, both divided by want's peak."""
    top = max(float(want.max()), 1e-12)
    curve = lambda a: np.clip(a / top, 0, 1) ** (1 / 2.2)
    err = float(((curve(want) - curve(got)) ** 2)[:, mask].mean())
    return 10 * np.log10(1 / max(err, 1e-20))


def scene_errors(exact, coded) -> dict:
    mask = exact.alpha[0] > 0.5
    cos = np.clip((exact.normal * coded.normal).sum(axis=0)[mask], -1, 1)
    angles = np.degrees(np.arccos(cos))
    dt = np.linalg.norm(coded.transport - exact.transport, axis=0)[mask]
    return {"image": np.mean([psnr_display(a, b, mask) for a, b in zip(exact.images, coded.images)
                              if a is not None]),
            "prt": np.mean([psnr_display(scene_prt(exact, light), scene_prt(coded, light), mask) for light in exact.lights]),
            "albedo": psnr_display(exact.albedo, coded.albedo, mask),
            "normal_median": float(np.median(angles)), "normal_p95": float(np.percentile(angles, 95)),
            "transport": float(np.sqrt((dt ** 2).mean() / (np.linalg.norm(exact.transport, axis=0)[mask] ** 2).mean()))}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("pack", help="an exact training pack")
    p.add_argument("--scenes", type=int, default=40)
    p.add_argument("--qualities", default="75,85,90,95")
    p.add_argument("--without", nargs="*", default=["depth", "body"], choices=("depth", "body"))
    args = p.parse_args(argv)
    qualities = [int(q) for q in args.qualities.split(",")]
    total = len(read_manifest(args.pack)["scenes"])
    every = max(total // args.scenes, 1)
    rows = {q: [] for q in qualities}
    sizes = {q: [] for q in qualities}
    for i, (scene, rec) in enumerate(iter_training_pack(args.pack, every * args.scenes)):
        if i % every:
            continue
        if "depth" in args.without:
            scene.depth = None
        if "body" in args.without:
            scene.body = None
        for q in qualities:
            blob, floats, coded = encode_scene(scene, q)
            full = {**rec, **coded, "body": scene.body is not None}
            rows[q].append(scene_errors(scene, decode_scene(blob, floats, full)))
            sizes[q].append(len(blob) + floats.nbytes)
    n = len(rows[qualities[0]])
    print(f"{n} scenes of {args.pack} (every {every}th), without {', '.join(args.without) or 'nothing'}\n")
    print("| JPEG quality | kB per scene | scenes per 38 MiB | traced images, dB | albedo x T.L, dB | albedo, dB "
          "| normal, median / p95 deg | transport, relative |")
    print("|---|---|---|---|---|---|---|---|")
    for q in qualities:
        m = {k: np.mean([r[k] for r in rows[q]]) for k in rows[q][0]}
        kb = np.mean(sizes[q]) / 1024
        print(f"| {q} | {kb:.1f} | {int(38 * 1024 / kb)} | {m['image']:.1f} | {m['prt']:.1f} | {m['albedo']:.1f} "
              f"| {m['normal_median']:.2f} / {m['normal_p95']:.2f} | {m['transport']:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
