"""Issue 25, part 3, ceiling first: is the person's skin a light probe for the light's colour?

    PYTHONPATH=. .venv/bin/python benchmarks/studies/study_skin_probe.py --data data/heldout256 \\
        [--model relight/models/geometry.onnx] [--pairs-per-scene 4]

Skin albedo varies a lot in level between people but little in colour (the farm's skin
tones: 3.4 degrees mean angle from their mean colour, farm/synthesis/material_specs.py). So where the
photo shows skin, the colour of photo / shading there says the light's colour. Each held-out
scene's skin is found from the farm's buffers (the pixels where the camera sees the unclothed
body itself: its depth within 2 mm of the rendered surface's, farm/rendering/body_pass.py), each photo
(path-traced image, true alpha as the mask) is decomposed at --working-size, and the
network's light is recoloured per channel, its luminance kept, so that the photo-consistent
albedo's mean over the skin has: the skin prior's colour (the farm's mean skin colour; a
product would find the skin with a segmenter), or the true skin albedo's colour (the bound
of the probe). Also the true mean albedo's colour over the whole person, for scale.
Relit PSNR and scale-invariant PSNR to the scene's other lights (model.scoring.metrics, interior
pixels), and the light's colour error (degrees between DC colours).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from relight.imaging.colour import luminance  # noqa: E402 (after the repository on sys.path)

SKIN_DEPTH_TOLERANCE = 0.002  # metres: the rendered surface is the body itself


def skin_prior_colour(samples: int = 20000, seed: int = 0) -> np.ndarray:
    """The farm's mean skin colour (linear RGB, luminance 1)."""
    from farm.synthesis.material_specs import sample_skin

    rng = np.random.default_rng(seed)
    colours = np.array([sample_skin(rng) for _ in range(samples)])
    mean = (colours / luminance(colours)[:, None]).mean(axis=0)
    return mean / luminance(mean)


def recoloured(d, wanted_colour: np.ndarray, where: np.ndarray):
    """d with its light's channels scaled so the photo-consistent albedo's mean over `where`
    has `wanted_colour`'s chromaticity, its luminance kept."""
    import dataclasses

    from relight.network.refine import consistent_albedo

    own = d.albedo[where].astype(np.float64).mean(axis=0)
    want = wanted_colour / luminance(wanted_colour) * luminance(own)
    gains = np.where(want > 1e-6, own / np.maximum(want, 1e-6), 1.0)
    light = (d.light * gains[None, :]).astype(np.float32)
    return dataclasses.replace(d, light=light, albedo=consistent_albedo(d, d.transport, light))


FACE_RADIUS = 0.5  # the face probe's disc: this times the distance between the eyes


def face_disc(photo: np.ndarray, landmarks_model: str, shape) -> np.ndarray | None:
    """[h, w] bool: a disc on the face (between the nose and the eyes, FACE_RADIUS x the eyes'
    distance) of the largest person, from MediaPipe's pose landmarks (the pose segmentation
    network exported with its landmark output, tools/convert_mediapipe_matte.py), mapped into
    a grid of `shape` over the photo; None when no face is seen (nose or eyes not visible)."""
    import math

    import onnxruntime as ort

    from relight.person import matte, pose_people
    from relight.imaging.colour import srgb_encode
    from relight.imaging.resample import area_shrink, sample_points

    small = srgb_encode(area_shrink(photo, matte.GUIDE_SIZE)).astype(np.float32)
    found = pose_people.detect(matte._session("detector"), small)
    if not found:
        return None
    cx, cy, side, rotation = pose_people.roi(found[0])
    c, s = math.cos(rotation), math.sin(rotation)
    t = ((np.arange(matte.NET_SIDE, dtype=np.float64) + 0.5) / matte.NET_SIDE - 0.5) * side
    u, v = np.meshgrid(t, t)
    crop = sample_points(small, c * u - s * v + cx, s * u + c * v + cy)
    session = ort.InferenceSession(landmarks_model, providers=["CPUExecutionProvider"])
    marks = session.run(["landmarks"], {"image": pose_people.nchw(crop)})[0].reshape(-1, 5)[:33]
    if min(marks[0, 3], marks[2, 3], marks[5, 3]) < 0.0:  # visibility logits of nose and eye centres
        return None
    uu, vv = (marks[:, 0] / matte.NET_SIDE - 0.5) * side, (marks[:, 1] / matte.NET_SIDE - 0.5) * side
    x, y = c * uu - s * vv + cx, s * uu + c * vv + cy          # in `small`'s pixels
    scale_y, scale_x = shape[0] / small.shape[0], shape[1] / small.shape[1]
    eyes = np.array([(x[2] + x[5]) / 2, (y[2] + y[5]) / 2])
    centre = 0.7 * np.array([x[0], y[0]]) + 0.3 * eyes
    radius = FACE_RADIUS * math.hypot(x[2] - x[5], y[2] - y[5])
    yy, xx = (np.mgrid[0:shape[0], 0:shape[1]] + 0.5)
    return ((xx / scale_x - centre[0]) ** 2 + (yy / scale_y - centre[1]) ** 2) <= radius ** 2


def colour_error(light: np.ndarray, true: np.ndarray) -> float:
    a, b = light[0], true[0]
    return float(np.degrees(np.arccos(np.clip(a @ b / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-12), -1, 1))))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True, help="a folder of held-out farm scenes")
    p.add_argument("--model", default=None, help="the relighting network (default: the registry's)")
    p.add_argument("--working-size", type=int, default=128, help="the network's crop side in pixels")
    p.add_argument("--pairs-per-scene", type=int, default=4, help="photos of each scene relit")
    p.add_argument("--threads", type=int, default=1, help="onnxruntime threads")
    p.add_argument("--landmarks-model", default=None,
                   help="the pose segmentation network with its landmark output: adds the face probe's rows")
    args = p.parse_args(argv)
    from model.scoring import metrics
    from model.samples.data_splits import find_scenes
    from relight.files.dataset import read_scene
    from relight.imaging.resample import resize_linear
    from relight.network.runtime import Relighter

    prior = skin_prior_colour()
    relighter = Relighter(args.model, threads=args.threads)
    rows = {k: {"psnr": [], "si": [], "colour": []} for k in
            ("network's light", "recoloured by the skin prior", "recoloured by the true skin colour (bound)",
             "recoloured by the true mean albedo's colour (bound)", "recoloured by the skin prior over the face disc")}
    faces = {"found": 0, "skin share": []}
    skin_share = []
    for path in find_scenes(args.data):
        scene = read_scene(path, verify_hash=False)
        if scene.body_depth is None:
            raise SystemExit(f"{path.name}: no body pass (render with the farm's default passes)")
        alpha = scene.alpha[..., 0]
        skin_full = ((scene.body_alpha[..., 0] >= 1.0) & (alpha > 0.999)
                     & (np.abs(scene.body_depth[..., 0] - scene.depth[..., 0]) < SKIN_DEPTH_TOLERANCE))
        weight = metrics.interior_weight(alpha)
        done = 0
        for a, image in enumerate(scene.images):
            if done >= args.pairs_per_scene:
                break
            d = relighter.decompose(image, mask=alpha, working_size=args.working_size)
            y0, y1, x0, x1 = d.box
            h, w = d.working_size
            skin = (resize_linear(skin_full[y0:y1, x0:x1].astype(np.float32), h, w) > 0.99) & (d.alpha >= 0.999)
            person = d.alpha >= 0.999
            if skin.sum() < 4:
                continue
            true_albedo = resize_linear(scene.albedo[y0:y1, x0:x1], h, w)
            skin_share.append(skin.sum() / max(person.sum(), 1))
            face = None
            if args.landmarks_model:
                disc = face_disc(image, args.landmarks_model, image.shape[:2])
                if disc is not None:
                    face = (resize_linear(disc[y0:y1, x0:x1].astype(np.float32), h, w) > 0.99) & (d.alpha >= 0.999)
                    if face.sum() >= 2:
                        faces["found"] += 1
                        faces["skin share"].append(float(skin[face].mean()))
                    else:
                        face = None
            variants = {
                "network's light": d,
                "recoloured by the skin prior": recoloured(d, prior, skin),
                "recoloured by the true skin colour (bound)": recoloured(d, true_albedo[skin].mean(axis=0), skin),
                "recoloured by the true mean albedo's colour (bound)":
                    recoloured(d, true_albedo[person].mean(axis=0), person),
                "recoloured by the skin prior over the face disc": d if face is None else recoloured(d, prior, face),
            }
            true_light = np.asarray(scene.lights[a]["sh"], np.float64)
            for b, target in enumerate(scene.images):
                if b == a:
                    continue
                lb = np.asarray(scene.lights[b]["sh"], np.float64)
                for name, v in variants.items():
                    relit = v.relight(lb)
                    rows[name]["psnr"].append(metrics.psnr(relit, target, weight))
                    rows[name]["si"].append(metrics.scale_invariant_psnr(relit, target, weight))
            for name, v in variants.items():
                rows[name]["colour"].append(colour_error(v.light.astype(np.float64), true_light))
            done += 1
    print(f"# {len(skin_share)} held-out photos of {args.data}, each relit to its scene's other lights; "
          f"skin {100 * np.mean(skin_share):.1f}% of the person's pixels on average (min "
          f"{100 * np.min(skin_share):.1f}%); skin prior colour {np.round(prior, 3).tolist()}\n")
    if args.landmarks_model:
        print(f"face disc found on {faces['found']} of {len(skin_share)} photos; the farm's skin mask covers "
              f"{100 * np.mean(faces['skin share'] or [np.nan]):.0f}% of it on average (where not found: the "
              f"network's light)\n")
    print("| the photo's light | colour error (deg, mean / median) | relit PSNR | SI PSNR |")
    print("|---|---|---|---|")
    for name, r in rows.items():
        print(f"| {name} | {np.mean(r['colour']):.1f} / {np.median(r['colour']):.1f} | {np.mean(r['psnr']):.2f} | "
              f"{np.mean(r['si']):.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
