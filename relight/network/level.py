"""The photo's light level and colour, shrunk toward what the model's training lights give
(issue 25).

One photo cannot tell a bright light on a dark person from the reverse: the geometry-first
network takes the level and colour of the photo's light from its albedo prior, and on
held-out farm scenes the gain that would make its relit image right varies by 0.46 stops
(sd) from photo to photo. That gain is predictable from the network's own answer: where the
fitted shading over the person is brighter than usual, the prior was too dark, and the
reverse (a noisy estimate is best shrunk toward its typical value). A LevelPrior is that
regression, fitted once per model on scenes lit by training lights (never the held-out
ones; `python -m export.level_prior`), in log2 units, with m_c the person's mean
fitted shading (T . L)_c, l = log2 of its luminance and x_c = log2 m_c - l its colour:

    gain of channel c    y_c = a_c + b_c * l + k_c * x_c

The light is divided by 2^y_c per channel (`leveled`) and the albedo follows from it by the
model's own photo-consistent rule (relight.network.decomposition.Decomposition.with_light), so the photo is reproduced as before and only how bright and
what colour the person comes out under a new light changes. The gains are bounded
(MAX_STOPS) and the features clamped, so black, white or saturated photos stay finite.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np

from relight.imaging.colour import LUMINANCE_WEIGHTS

__all__ = ["LevelPrior", "METADATA_KEY", "features", "fit_prior", "apply", "leveled"]

METADATA_KEY = "relight.level_prior"  # the ONNX metadata entry that carries a model's prior
MAX_STOPS = 2.0        # the largest change of level or colour one photo gets, either way
MIN_SHADING = 1e-4     # a darker mean shading is "no light": its log is clamped here
MIN_SLOPE, MAX_SLOPE = -1.0, 1.5  # slopes outside: the correction would exceed the error it corrects
# ridge on the slopes (stops^2 per unit^2 of feature, per pair): a feature that hardly varies over
# the calibration pairs (green's colour: sd 0.03) gets no slope from its noise
SLOPE_RIDGE = 0.002
MAX_INTERCEPT = 8.0    # stops


@dataclass(frozen=True)
class LevelPrior:
    """rows = ((a_r, b_r, k_r), (a_g, b_g, k_g), (a_b, b_b, k_b)) (module docstring)."""

    rows: tuple
    pairs: int = 0  # how many calibration pairs it was fitted on (0: unknown)

    def __post_init__(self):
        try:
            rows = tuple(tuple(float(v) for v in row) for row in self.rows)
        except (TypeError, ValueError):
            raise ValueError(f"LevelPrior: rows must be numbers, got {self.rows!r}") from None
        if len(rows) != 3 or any(len(row) != 3 for row in rows):
            raise ValueError("LevelPrior: rows needs three (a, b, k) rows, one a colour channel")
        for a, b, k in rows:
            if not all(math.isfinite(v) for v in (a, b, k)) or abs(a) > MAX_INTERCEPT or \
                    not (MIN_SLOPE <= b <= MAX_SLOPE and MIN_SLOPE <= k <= MAX_SLOPE):
                raise ValueError(f"LevelPrior: intercepts must be finite within +-{MAX_INTERCEPT} stops and slopes "
                                 f"in [{MIN_SLOPE}, {MAX_SLOPE}], got {(a, b, k)}")
        object.__setattr__(self, "rows", rows)

    def gains(self, transport: np.ndarray, light: np.ndarray, weight: np.ndarray) -> np.ndarray:
        """[3] factors for the albedo (the light is divided by them) of one decomposition:
        transport [h, w, n], light [n, 3], weight [h, w] (the person's pixels): 2 ** the rows'
        log2 gains at its features (`features`), within +-MAX_STOPS."""
        lum, colour = features(transport, light, weight)
        stops = np.array([a + b * lum + k * x for (a, b, k), x in zip(self.rows, colour)])
        return np.exp2(np.clip(stops, -MAX_STOPS, MAX_STOPS))

    def to_metadata(self) -> str:
        return json.dumps({"rows": [list(row) for row in self.rows], "pairs": int(self.pairs)}, sort_keys=True)

    @classmethod
    def from_metadata(cls, text: str | None) -> "LevelPrior | None":
        """The prior a model's metadata carries (None when it has none); ValueError when malformed."""
        if text is None:
            return None
        try:
            d = json.loads(text)
            return cls(tuple(tuple(row) for row in d["rows"]), int(d.get("pairs", 0)))
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise ValueError(f"model metadata {METADATA_KEY} is malformed: {exc}") from None


def features(transport: np.ndarray, light: np.ndarray, weight: np.ndarray) -> tuple[float, np.ndarray]:
    """(l, x[3]): log2 of the luminance of the person's mean shading (T . L) and each
    channel's log2 ratio to it (its colour), both clamped (no light: MIN_SHADING)."""
    w = np.asarray(weight, np.float64)
    total = float(w.sum())
    if not total > 0:
        mean = np.full(3, MIN_SHADING)
    else:
        # the mean of T . L is (the mean of T) . L: one weighted sum of T, not the shading image
        t = np.asarray(transport)
        mean = (w.reshape(-1) @ t.reshape(-1, t.shape[-1]).astype(np.float64)) @ np.asarray(light, np.float64) / total
    mean = np.maximum(np.nan_to_num(mean, nan=MIN_SHADING), MIN_SHADING)
    lum = max(float(mean @ np.asarray(LUMINANCE_WEIGHTS, np.float64)), MIN_SHADING)
    return math.log2(lum), np.log2(mean) - math.log2(lum)


def fit_prior(lums, colours, log_gains) -> LevelPrior:
    """Least-squares LevelPrior from calibration pairs: each pair's features (`features`: l and
    x[3]) and the log2 per-channel gains [3] that make its relit image right. Per channel,
    y_c ~ a_c + b_c l + k_c x_c, ridge SLOPE_RIDGE on the slopes of the centred features;
    slopes are then clipped to [MIN_SLOPE, MAX_SLOPE] (a positive
    slope shrinks the network's estimate toward the typical one, a negative one expands it:
    the network's answer was too timid) and the intercept refitted."""
    lums = np.asarray(lums, np.float64).reshape(-1)
    colours = np.asarray(colours, np.float64).reshape(-1, 3)
    log_gains = np.asarray(log_gains, np.float64).reshape(-1, 3)
    if lums.size < 4 or colours.shape[0] != lums.size or log_gains.shape[0] != lums.size or not (
            np.all(np.isfinite(lums)) and np.all(np.isfinite(colours)) and np.all(np.isfinite(log_gains))):
        raise ValueError(f"fit_prior: need at least 4 finite calibration pairs, got {lums.size}")
    rows = []
    for c in range(3):
        centred = np.stack([lums - lums.mean(), colours[:, c] - colours[:, c].mean()], axis=1)
        y = log_gains[:, c] - log_gains[:, c].mean()
        normal = centred.T @ centred + SLOPE_RIDGE * lums.size * np.eye(2)
        b, k = np.linalg.solve(normal, centred.T @ y)
        b, k = (float(np.clip(v, MIN_SLOPE, MAX_SLOPE)) for v in (b, k))
        a = float(np.clip(np.mean(log_gains[:, c] - b * lums - k * colours[:, c]), -MAX_INTERCEPT, MAX_INTERCEPT))
        rows.append((a, b, k))
    return LevelPrior(tuple(rows), pairs=int(lums.size))


def leveled(prior: LevelPrior, transport: np.ndarray, light: np.ndarray, weight: np.ndarray):
    """(light [n, 3] float32 divided by the prior's gains, the gains [3]) for one photo's
    transport [h, w, n], light [n, 3] and person weight [h, w]: the runtime's change of the
    photo's light level and colour (the albedo follows from it: Decomposition.with_light)."""
    gains = prior.gains(transport, light, weight)
    return (light / gains[None, :]).astype(np.float32), gains


def apply(decomposition, prior: LevelPrior | None):
    """(decomposition with its light divided by the prior's gains (`leveled`) and the albedo
    following from it, the gains [3] or None). Models without a photo-consistent albedo (a
    residual E) and models without a prior are returned as they are."""
    d = decomposition
    if prior is None or d.has_residual:
        return d, None
    light, gains = leveled(prior, d.transport, d.light, d.alpha)
    return d.with_light(light), gains
