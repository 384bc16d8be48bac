"""Test-time augmentation: the network run on the photo mirrored and at other working
sizes, its answers brought back into the first run's frame and averaged (issue 26).

A mirrored photo (x -> -x in the photo-camera frame, docs/conventions.md) has mirrored
transport and light: each SH coefficient keeps or flips its sign (`mirror_x`), so the
mirrored run's transport is flipped back along the rows' x and its coefficients
mirrored, and its light mirrored. Other working sizes are resampled to the first run's
grid. Transport and light are averaged there (linear quantities: a mean of estimates,
`averaged`); the albedo follows from them by the model's own rule
(relight.network.decomposition.Decomposition.with_light), so the result is one Decomposition that
relights, makes layers and follows dials like any other.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np

from relight.imaging.resample import resize_linear, resize_longest

__all__ = ["mirror_x", "average", "averaged", "augment", "runs", "disagreement", "AUGMENTATIONS", "AGREED"]

# (scale of the working size, mirrored) for each run after the first: the augmentations
# measured in docs/TRADEOFFS.md ("Best")
AUGMENTATIONS = ((1.0, True), (1.25, False), (1.25, True), (0.75, False), (0.75, True))
# Only what the photo needs: when the first augmented run (the mirror) changes the shading
# over the person by at most this (relative RMS, `disagreement`), the rest are not run. On
# the 96 held-out pairs this stops after the mirror on 26% of them at 128 px (19% and 33% of
# either half) for 0.005 dB against all six runs; at Best's 144 px on none of them (a mirrored
# run there differs more; at 160 px 0.2 would stop 24% at -0.045 dB; docs/TRADEOFFS.md).
AGREED = 0.10


@functools.lru_cache(maxsize=None)
def mirror_x(order: int) -> np.ndarray:
    """[n] signs s with f(-x, y, z) = sum_i s_i c_i Y_i(x, y, z) for f = sum_i c_i Y_i, for the
    model's SH order (trusted: checked where the decomposition was made). Each real SH basis function
    is even or odd in x: x -> -x takes the azimuth phi to pi - phi, so cos(m phi) (m >= 0) gains
    (-1)^m and sin(|m| phi) (m < 0) gains -(-1)^|m| (docs/conventions.md's basis)."""
    m = np.concatenate([np.arange(-l, l + 1) for l in range(order + 1)])
    odd = np.where(m >= 0, m % 2 == 1, m % 2 == 0)
    return np.where(odd, -1.0, 1.0).astype(np.float32)


def _in_frame(base, other, mirrored: bool):
    """other's transport [h, w, n] and light [n, 3] in base's frame (grid and handedness)."""
    transport, light = other.transport, other.light
    if mirrored:
        signs = mirror_x(other.sh_order)
        transport = transport[:, ::-1] * signs
        light = light * signs[:, None]
    h, w = base.working_size
    if transport.shape[:2] != (h, w):
        transport = resize_linear(np.ascontiguousarray(transport), h, w)
    return transport, light


class _Run(NamedTuple):
    """One augmented run's outputs at its own working grid (what _in_frame reads)."""

    transport: np.ndarray
    light: np.ndarray
    sh_order: int
    working_size: tuple


def augment(relighter, base, augmentations=AUGMENTATIONS, stop_when_agreed: float | None = None):
    """`base` (relighter's decomposition of a photo) averaged with the network's answers on the
    same crop mirrored and/or at other working sizes: [(scale of base's working size,
    mirrored)]. The network sees each crop with the same matte as `base`. With
    `stop_when_agreed`, the runs after the first are skipped when the first changes the
    shading by at most that (`disagreement`). Returns (the averaged decomposition, how many
    of `augmentations` ran)."""
    done = runs(relighter, base, augmentations, stop_when_agreed)
    return average(base, done), len(done)


def runs(relighter, base, augmentations, stop_when_agreed: float | None = None) -> list:
    """The network's answers [(run, mirrored)] on base's crop for each augmentation (see
    `augment`), not yet averaged: other networks' runs may join them (an ensemble)."""
    for item in augmentations:
        if (not isinstance(item, (tuple, list)) or len(item) != 2 or not isinstance(item[1], (bool, np.bool_))
                or not isinstance(item[0], (int, float)) or not 0.25 <= item[0] <= 4.0):
            raise ValueError(f"augmentations must be (scale in [0.25, 4], mirrored: bool) pairs, got {item!r}")
    y0, y1, x0, x1 = base.box
    crop = base.photo[y0:y1, x0:x1]
    if base.mask is not None:
        matte = base.mask[y0:y1, x0:x1]
    else:  # the network's own alpha: resampled from base's grid
        matte = None
    done, crops = [], {}
    for scale, mirrored in augmentations:
        longest = max(16, round(max(base.working_size) * scale))
        if longest not in crops and longest == max(base.working_size):  # base's own, made once by the runtime
            crops[longest] = base.photo_working, np.clip(base.alpha, 0.0, 1.0)
        elif longest not in crops:
            small = resize_longest(crop, longest)
            small_matte = resize_longest(matte, longest) if matte is not None else \
                resize_linear(base.alpha, *small.shape[:2])
            crops[longest] = small, np.clip(small_matte, 0.0, 1.0)
        small, small_matte = crops[longest]
        h, w = small.shape[:2]
        if mirrored:
            small, small_matte = small[:, ::-1], small_matte[:, ::-1]
        out = relighter.run_crop(np.ascontiguousarray(small), np.ascontiguousarray(small_matte))
        done.append((_Run(out["transport"], out["light"], base.sh_order, (h, w)), mirrored))
        if stop_when_agreed is not None and len(done) == 1 and \
                disagreement(base, *_in_frame(base, done[0][0], mirrored)) <= stop_when_agreed:
            break
    return done


def disagreement(base, transport: np.ndarray, light: np.ndarray) -> float:
    """Relative RMS change, over base's matte, of the shading T . L from base's own to another
    run's (its transport and light in base's frame): how much a second opinion differs."""
    w = base.alpha[..., None].astype(np.float64)
    own = base.transport.astype(np.float64) @ base.light.astype(np.float64)
    other = transport.astype(np.float64) @ light.astype(np.float64)
    ref = float((w * own * own).sum())
    return float(np.sqrt((w * (other - own) ** 2).sum() / ref)) if ref > 0 else 0.0


def averaged(base, runs) -> tuple[np.ndarray, np.ndarray]:
    """(transport [h, w, n], light [n, 3]), float32: `base`'s (the first run's) and `runs`'
    [(run, mirrored)] averaged in base's frame: the runtime's first change of the photo's light."""
    if not runs:
        return base.transport, base.light
    transports, lights = [base.transport.astype(np.float64)], [base.light.astype(np.float64)]
    for other, mirrored in runs:
        t, light = _in_frame(base, other, mirrored)
        transports.append(t)
        lights.append(light)
    return np.mean(transports, axis=0).astype(np.float32), np.mean(lights, axis=0).astype(np.float32)


def average(base, runs) -> object:
    """One Decomposition from `base` (the first run) and `runs` [(decomposition, mirrored)]:
    transport and light averaged in base's frame (`averaged`), the albedo following from them
    (Decomposition.with_light)."""
    if not runs:
        return base
    transport, light = averaged(base, runs)
    return base.with_light(light, transport)
