"""Issue 25, part 2, ceiling first: does the photo's surroundings tell its light better than
the person alone? Same data, same budget, one small light estimator per input:

  person      the masked photo (what the shipped network sees) + the matte
  photo       the whole photo + the matte
  background  the photo with the person cut out + the matte

    PYTHONPATH=. .venv/bin/python benchmarks/studies/study_light_context.py --train data/light_train128 \\
        --heldout data/heldout256 [--steps 1500] [--batch 16] [--seed 0]

Each estimator (on 64 px inputs: five stride-2 convolutions, width 32, global pooling, a linear layer to the
order-4 SH light [25, 3]) is trained from the same seed on the same images (128 px, mirrored
at random with the light mirrored: relight.network.tta.mirror_x) to the farm's true light, loss L1 of
the coefficients plus L1 of the log DC (colour and level). On the held-out scenes (other
people and maps) it reports the light's colour error (degrees between true and estimated DC
RGB), level error (|stops| of the DC luminance), and relit PSNR when that light is the
photo's light in the shipped network's decomposition (its transport, the albedo made
photo-consistent with the light: relight.network.refine.consistent_albedo), beside the network's own
light and the true light. Torch, CPU; writes nothing but its table.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from relight.imaging.colour import luminance  # noqa: E402 (after the repository on sys.path)

INPUTS = ("person", "photo", "background")
SIZE = 128


INPUT_SIZE = 64  # the estimators' input side: a light is low-frequency, and 4x fewer pixels than 128


def encode(image: np.ndarray, alpha: np.ndarray, kind: str) -> np.ndarray:
    """[4, s, s] float32 at INPUT_SIZE: the chosen view of the photo (sRGB-encoded to [-1, 1])
    and the matte."""
    from relight.network.prt import to_network_input
    from relight.imaging.resample import resize_linear

    a = alpha[..., 0] if alpha.ndim == 3 else alpha
    image, a = resize_linear(image, INPUT_SIZE, INPUT_SIZE), np.clip(resize_linear(a, INPUT_SIZE, INPUT_SIZE), 0, 1)
    if kind == "person":
        x = to_network_input(image, a)
    elif kind == "photo":
        x = to_network_input(image)
    elif kind == "background":
        x = to_network_input(image) * (1.0 - a)[..., None]
    else:
        raise ValueError(kind)
    return np.concatenate([x, a[..., None] * 2.0 - 1.0], axis=-1).transpose(2, 0, 1).astype(np.float32)


def load(folder: Path, size: int, with_scene: bool = False):
    """(images [N, h, w, 3], alphas [N, h, w], lights [N, 25, 3], scene index per image)."""
    from model.samples.data_splits import find_scenes
    from relight.files.dataset import read_scene
    from relight.imaging.resample import resize_linear

    images, alphas, lights, owners = [], [], [], []
    for i, path in enumerate(find_scenes(folder)):
        scene = read_scene(path, verify_hash=False)
        a = scene.alpha[..., 0]
        h, w = a.shape
        small_a = np.clip(resize_linear(a, size, size), 0, 1) if (h, w) != (size, size) else a
        for image, light in zip(scene.images, scene.lights):
            images.append(resize_linear(image, size, size) if (h, w) != (size, size) else image)
            alphas.append(small_a)
            lights.append(np.asarray(light["sh"], np.float32))
            owners.append(i)
    return np.stack(images), np.stack(alphas), np.stack(lights), np.array(owners)


def make_net(torch, in_channels: int = 4, width: int = 32, n: int = 25):
    nn = torch.nn
    layers, c = [], in_channels
    for k in range(5):
        out = width * min(2 ** k, 4)
        layers += [nn.Conv2d(c, out, 3, stride=2, padding=1), nn.GroupNorm(8, out), nn.SiLU()]
        c = out
    return nn.Sequential(*layers, nn.AdaptiveAvgPool2d(1), nn.Flatten(), nn.Linear(c, n * 3))


def dc_colour_error(est: np.ndarray, true: np.ndarray) -> np.ndarray:
    """Degrees between DC RGB vectors, per image ([N, 25, 3] each)."""
    a, b = est[:, 0], true[:, 0]
    cos = (a * b).sum(-1) / np.maximum(np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1), 1e-12)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def dc_level_error(est: np.ndarray, true: np.ndarray) -> np.ndarray:
    """|stops| between DC luminances, per image."""
    return np.abs(np.log2(np.maximum(luminance(est[:, 0]), 1e-6) / np.maximum(luminance(true[:, 0]), 1e-6)))


def train(torch, kind: str, data, steps: int, batch: int, seed: int):
    from relight.network.tta import mirror_x

    images, alphas, lights, _ = data
    x_all = np.stack([encode(im, a, kind) for im, a in zip(images, alphas)])
    signs = torch.tensor(mirror_x(4), dtype=torch.float32)[:, None]
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    net = make_net(torch)
    opt = torch.optim.AdamW(net.parameters(), lr=2e-3, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=2e-3, total_steps=steps)
    x_t, l_t = torch.from_numpy(x_all), torch.from_numpy(lights)
    start = time.perf_counter()
    for step in range(steps):
        idx = torch.from_numpy(rng.integers(0, len(x_all), batch))
        x, target = x_t[idx], l_t[idx]
        flip = torch.from_numpy(rng.random(batch) < 0.5)
        x = torch.where(flip[:, None, None, None], x.flip(-1), x)
        target = torch.where(flip[:, None, None], target * signs, target)
        pred = net(x).view(batch, 25, 3)
        dc = torch.log(pred[:, 0].clamp(min=1e-3)) - torch.log(target[:, 0].clamp(min=1e-3))
        loss = (pred - target).abs().mean() + dc.abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
    return net, time.perf_counter() - start


def predict(torch, net, kind: str, images, alphas) -> np.ndarray:
    x = torch.from_numpy(np.stack([encode(im, a, kind) for im, a in zip(images, alphas)]))
    net.eval()
    with torch.no_grad():
        return np.concatenate([net(x[i:i + 32]).view(-1, 25, 3).numpy() for i in range(0, len(x), 32)])


def relit_psnr(heldout_folder: Path, estimates: dict[str, np.ndarray]) -> dict[str, float]:
    """Mean interior PSNR of each photo relit to the other lights of its scene, with each
    estimate as the photo's light in the shipped network's decomposition (at 128 px)."""
    import dataclasses

    from model.scoring import metrics
    from model.samples.data_splits import find_scenes
    from model.scoring.metrics import interior_weight
    from relight.files.dataset import read_scene
    from relight.network.refine import consistent_albedo
    from relight.network.runtime import Relighter

    relighter = Relighter(threads=2)
    scores = {k: [] for k in estimates}
    image_index = 0
    for path in find_scenes(heldout_folder):
        scene = read_scene(path, verify_hash=False)
        alpha = scene.alpha[..., 0]
        w = interior_weight(alpha)
        for a, image in enumerate(scene.images):
            d = relighter.decompose(image, mask=alpha, working_size=SIZE)
            for name, est in estimates.items():
                light = est[image_index].astype(np.float32)
                da = dataclasses.replace(d, light=light, albedo=consistent_albedo(d, d.transport, light))
                for b, target in enumerate(scene.images):
                    if b != a:
                        lb = np.asarray(scene.lights[b]["sh"], np.float64)
                        scores[name].append(metrics.psnr(da.relight(lb), target, w))
            image_index += 1
    return {k: float(np.mean(v)) for k, v in scores.items()}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--train", required=True)
    p.add_argument("--heldout", required=True)
    p.add_argument("--steps", type=int, default=1500)
    p.add_argument("--batch", type=int, default=16)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)
    import torch

    torch.set_num_threads(args.threads)
    data = load(Path(args.train), SIZE)
    test_images, test_alphas, test_lights, _ = load(Path(args.heldout), SIZE)
    print(f"train: {len(data[0])} images of {len(set(data[3]))} scenes ({args.train}); "
          f"held out: {len(test_images)} images ({args.heldout}); {args.steps} steps of {args.batch}\n")
    from relight.network.runtime import Relighter

    relighter = Relighter(threads=args.threads)
    network = np.stack([relighter.decompose(im, mask=a, working_size=SIZE).light
                        for im, a in zip(test_images, test_alphas)])
    estimates = {"the shipped network's light": network}
    timing = {}
    for kind in INPUTS:
        net, seconds = train(torch, kind, data, args.steps, args.batch, args.seed)
        estimates[f"estimator on {kind}"] = predict(torch, net, kind, test_images, test_alphas)
        timing[f"estimator on {kind}"] = seconds
    # the network's light (its direction, from the photo's shading) with another estimate's colour and
    # level: per-channel gains that give it that estimate's DC
    for name in [f"estimator on {kind}" for kind in INPUTS] + ["true light"]:
        source = test_lights if name == "true light" else estimates[name]
        gains = np.maximum(source[:, 0], 1e-4) / np.maximum(network[:, 0], 1e-4)
        estimates[f"network's direction, colour and level of the {name}"] = network * gains[:, None, :]
    psnr = relit_psnr(Path(args.heldout), {**estimates, "true light (bound)": test_lights})
    print("| photo's light from | colour error (deg, mean / median) | level error (stops, mean / median) "
          "| relit PSNR | train s |")
    print("|---|---|---|---|---|")
    for name, est in estimates.items():
        c, lv = dc_colour_error(est, test_lights), dc_level_error(est, test_lights)
        print(f"| {name} | {c.mean():.1f} / {np.median(c):.1f} | {lv.mean():.2f} / {np.median(lv):.2f} | "
              f"{psnr[name]:.2f} | {timing.get(name, float('nan')):.0f} |")
    print(f"| true light (bound) | 0 | 0 | {psnr['true light (bound)']:.2f} | |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
