"""One light for a group (issue 47): farm group scenes relit with the light fitted from everyone against each
person's own light.

For each group scene and each pair of its path-traced lights (photo under a -> truth under b), every person
is decomposed at their own crop from their true mask (relight.network.group's path, the matte taken as
given so that only the light differs), then relit by b twice: with their own estimate of the photo's light
(alone) and with the one light of relight.network.group.joint_light (together). PSNR over each person's
fully covered pixels, and over everyone's.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_group_light.py DATA [--quality balanced]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from relight.files.dataset import list_finished_scenes, read_scene, traced_lights
from relight.network.group import joint_light
from relight.network.quality import PRESETS, preset
from relight.network.runtime import Relighter


def psnr(pred: np.ndarray, gt: np.ndarray, where: np.ndarray) -> float:
    mse = float(np.mean((np.clip(pred[where], 0, 1) - np.clip(gt[where], 0, 1)) ** 2))
    return 10 * math.log10(1.0 / max(mse, 1e-12))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("--quality", choices=[q.key for q in PRESETS], default="balanced")
    args = parser.parse_args(argv)
    q = preset(args.quality)
    relighter = Relighter(working_size=q.working_size)
    options = q.decompose_options(working_size=False)
    alone, together, everyone_alone, everyone_together, worst = [], [], [], [], []
    for path in list_finished_scenes(args.data):
        scene = read_scene(path)
        if not scene.people:
            continue
        traced = traced_lights(scene.meta)
        for a, b in [(a, b) for a in traced for b in traced if a != b][:2]:
            photo, target = scene.images[a], scene.images[b]
            light_b = np.asarray(scene.meta["lights"][b]["sh"], np.float64)[:(relighter.sh_order + 1) ** 2]
            people = [relighter.decompose(photo, m[..., 0], **options) for m in scene.people]
            shared = joint_light(people)
            together_people = [d.with_light(shared) for d in people]
            own_image, joint_image = photo.copy(), photo.copy()
            for d, j in zip(people, together_people):
                d.relight(light_b, out=own_image, accumulate=True)
                j.relight(light_b, out=joint_image, accumulate=True)
            union = np.zeros(photo.shape[:2], bool)
            for m in scene.people:
                inside = m[..., 0] > 0.99
                if inside.sum() < 20:
                    continue
                union |= inside
                s_alone, s_together = psnr(own_image, target, inside), psnr(joint_image, target, inside)
                alone.append(s_alone)
                together.append(s_together)
                worst.append(s_together - s_alone)
            everyone_alone.append(psnr(own_image, target, union))
            everyone_together.append(psnr(joint_image, target, union))
    print(f"{args.quality}; {len(everyone_alone)} pairs of group scenes, {len(alone)} people\n")
    print("| light | everyone's pixels, dB | per person, dB |")
    print("|---|---|---|")
    print(f"| each person's own | {np.mean(everyone_alone):.2f} | {np.mean(alone):.2f} |")
    print(f"| one for the photo | {np.mean(everyone_together):.2f} | {np.mean(together):.2f} |")
    w = np.array(worst)
    print(f"\none light - own light, per person: mean {w.mean():+.2f} dB, worst {w.min():+.2f}, "
          f"people more than 1 dB worse: {(w < -1).sum()} of {w.size}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
