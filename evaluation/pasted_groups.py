"""Group photos pasted from the bundled people (evaluation/data/matte_eval and their reference mattes), with
each person's true matte: 2 to 5 people of different sizes, side by side, touching, overlapping or apart,
over a smooth background. The nearer person (pasted later) wins where two overlap. Seeded: the same
seed gives the same photo.

    from evaluation.pasted_groups import pasted_group
    group = pasted_group(seed)     # .photo linear float32 [H, W, 3], .mattes [k, H, W], .names
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from relight.imaging.colour import srgb_decode

__all__ = ["PEOPLE", "PastedGroup", "pasted_group"]

FOLDER = Path(__file__).resolve().parent / "data" / "matte_eval"
PEOPLE = ("astronaut", "biden", "camera", "grace_hopper", "obama", "obama_standing")
HEIGHT = 480                 # the canvas's height in pixels
SIZES = (0.5, 1.0)           # a person's height, as a share of the canvas's, drawn uniformly
MIN_VISIBLE = 0.6            # of a person's own matte left visible after the nearer ones are pasted
SPACINGS = {"touching": 0.4, "overlapping": 0.4, "apart": 0.2}   # how each neighbour stands, and how often


@dataclass
class PastedGroup:
    photo: np.ndarray        # linear float32 [H, W, 3]
    mattes: np.ndarray       # [k, H, W] float32: each person's visible coverage (sums to <= 1)
    names: list[str]         # which bundled photo each person came from, left to right
    spacings: list[str]      # how each person stands to the one on their left


def _cutout(name: str, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(sRGB [h, w, 3] in [0, 1], matte [h, w]) of a bundled person at `height` px, cut to the
    matte's columns."""
    suffix = ".png" if name == "camera" else ".jpg"
    photo = Image.open(FOLDER / f"{name}{suffix}").convert("RGB")
    matte = Image.open(FOLDER / "reference" / f"{name}.png").convert("L")
    width = max(1, round(photo.width * height / photo.height))
    rgb = np.asarray(photo.resize((width, height), Image.BILINEAR), np.float32) / 255.0
    alpha = np.asarray(matte.resize((width, height), Image.BILINEAR), np.float32) / 255.0
    cols = np.flatnonzero(alpha.max(axis=0) > 0.5)
    return rgb[:, cols[0]:cols[-1] + 1], alpha[:, cols[0]:cols[-1] + 1]


def pasted_group(seed: int, count: int | None = None) -> PastedGroup:
    """One group photo of `count` (default: 2 to 5, drawn) people, from `seed`."""
    rng = np.random.default_rng(seed)
    count = int(rng.integers(2, 6)) if count is None else count
    if not 1 <= count <= len(PEOPLE):
        raise ValueError(f"count must be 1..{len(PEOPLE)}, got {count}")
    names = [PEOPLE[i] for i in rng.permutation(len(PEOPLE))[:count]]
    for _ in range(100):   # draw until every person stays visible enough
        cutouts = [_cutout(n, round(HEIGHT * rng.uniform(*SIZES))) for n in names]
        spacings = list(rng.choice(list(SPACINGS), size=count - 1, p=list(SPACINGS.values())))
        lefts = [0]
        for (_, prev), (_, _cur), kind in zip(cutouts, cutouts[1:], spacings):
            w = prev.shape[1]
            step = {"touching": w, "overlapping": round(w * (1 - rng.uniform(0.1, 0.3))),
                    "apart": round(w * (1 + rng.uniform(0.05, 0.25)))}[kind]
            lefts.append(lefts[-1] + step)
        width = max(left + a.shape[1] for left, (_, a) in zip(lefts, cutouts))
        order = rng.permutation(count)          # paste order: the later, the nearer
        canvas, mattes = _background(rng, width), np.zeros((count, HEIGHT, width), np.float32)
        for i in order:
            rgb, a = cutouts[i]
            h, w = a.shape
            rows, cols = slice(HEIGHT - h, HEIGHT), slice(lefts[i], lefts[i] + w)
            canvas[rows, cols] = a[..., None] * rgb + (1 - a[..., None]) * canvas[rows, cols]
            mattes[:, rows, cols] *= 1 - a      # the nearer one covers the ones behind
            mattes[i, rows, cols] = a
        own = np.array([(c[1] > 0.5).sum() for c in cutouts])
        if np.all((mattes > 0.5).sum(axis=(1, 2)) >= MIN_VISIBLE * own):
            return PastedGroup(srgb_decode(canvas).astype(np.float32), mattes, names, [str(s) for s in spacings])
    raise RuntimeError(f"seed {seed}: no arrangement left every person visible")


def _background(rng: np.random.Generator, width: int) -> np.ndarray:
    """A smooth sRGB background [HEIGHT, width, 3]: a vertical gradient between two muted colours."""
    top, bottom = rng.uniform(0.3, 0.8, 3), rng.uniform(0.2, 0.7, 3)
    t = np.linspace(0.0, 1.0, HEIGHT, dtype=np.float32)[:, None, None]
    return np.broadcast_to(top * (1 - t) + bottom * t, (HEIGHT, width, 3)).astype(np.float32).copy()
