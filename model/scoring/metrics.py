"""Evaluation metrics over the person's pixels: L1, L2 (MSE), PSNR, and the light's response
(light_response: how much of a change of light the relit person follows).

Convention (docs/model.md): metrics compare *linear* values as they are (no
clipping, no tone mapping); each pixel is weighted by the ground-truth alpha
(soft coverage) and channels are averaged. PSNR = 10 log10(peak^2 / MSE) with
peak = 1.0 (the reference radiance of a white Lambertian point is 0.8, so 1.0
is "a bright lit pixel"); MSE is floored at 1e-10, capping PSNR at 100 dB for
identical images. Sums run in float64, so values up to ~1e150 stay finite.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

# A pixel at least this covered is the person's "interior". A partly covered pixel mixes in
# the background of each light, which no relighting method is asked to predict; weighting
# those pixels by alpha lets them dominate every method's error (held-out set: the oracle
# scored 19.2 dB alpha-weighted, 29.8 dB interior; docs/EVALUATION.md).
INTERIOR_ALPHA = 0.999


def interior_weight(alpha) -> np.ndarray:
    """float32 weight: 1 where alpha > INTERIOR_ALPHA, else 0."""
    return (np.asarray(alpha) > INTERIOR_ALPHA).astype(np.float32)


def fit_channel_gains(pred, target, mask=None) -> np.ndarray:
    """Per-channel gains k minimising the weighted squared error of k * pred against target.

    k_c = sum(w p t) / sum(w p^2) (1 where a channel of pred is all zero). A
    diagnostic: the error left after it is what no global colour or exposure
    correction could remove.
    """
    p, t, m, _ = _prepare(pred, target, mask)
    num = (m[..., None] * p * t).sum(axis=(0, 1))
    den = (m[..., None] * p * p).sum(axis=(0, 1))
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 1.0)


def spatial_change(first, second, mask=None) -> float:
    """How much the image changes between two lights beyond a global colour/exposure:
    sqrt(sum w |second - k * first|^2 / sum w |second|^2), k the per-channel gains
    (fit_channel_gains). 0 when the second is the first recoloured; a light that moves
    across the body (shading that changes place) gives a large value."""
    p, t, m, _ = _prepare(first, second, mask)
    k = fit_channel_gains(first, second, mask)
    err = (m[..., None] * (t - k * p) ** 2).sum()
    ref = (m[..., None] * t * t).sum()
    return float(np.sqrt(err / ref)) if ref > 0 else 0.0


def luminance_ratio(numerator, denominator, mask=None) -> float:
    """Mask-weighted mean Rec.709 luminance of `numerator` over that of `denominator` (how much
    darker one relit image is than another: a light from behind against one from the front)."""
    from relight.imaging.colour import luminance

    a = luminance(np.asarray(numerator, np.float64).reshape(-1, 3))
    b = luminance(np.asarray(denominator, np.float64).reshape(-1, 3))
    w = np.ones(len(a)) if mask is None else np.asarray(mask, np.float64).reshape(-1)
    below = float((b * w).sum())
    return float((a * w).sum()) / below if below > 0 else float("nan")


LOG_FLOOR = 1e-3   # linear luminance floor of light_response's log change (an 8-bit step near black)
# a centred log change whose RMS is below this is no change: float32 images resolve a ratio to ~1e-7,
# so an exposure-only change (a constant log ratio) leaves a residue of that order, not a pattern
NO_CHANGE_RMS = 1e-6


class LightResponse(NamedTuple):
    """light_response's result: the slope and correlation, and the number of pixels measured."""

    slope: float
    correlation: float
    pixels: int


def light_response(photo, relit, target, mask=None, floor: float = LOG_FLOOR) -> LightResponse:
    """How the relit person's change of light follows the true one (issue 45).

    x = log lum(target) - log lum(photo), the true change from the photo's light a to light b;
    y = log lum(relit) - log lum(photo), the relit change (lum: Rec.709 luminance, floored at
    `floor`). Over the mask's pixels (weighted by it), each with its weighted mean removed (an
    exposure change is no pattern):
      slope = sum w x y / sum w x^2       (least squares of y on x; 1 = physics, 0 = no response)
      correlation = sum w x y / sqrt(sum w x^2 * sum w y^2)   (the pattern, whatever its size).
    A relit change of k times the true one gives slope k and correlation sign(k); adding noise n
    uncorrelated with x keeps the slope and gives correlation k sx / sqrt(k^2 sx^2 + sn^2).
    Degenerate cases: a true change under NO_CHANGE_RMS (b is a's exposure change, or the same
    light) has nothing to follow: slope and correlation NaN; a relit change under it while the
    truth changes (the photo returned as it is) responds with 0 and 0. An empty mask and NaN or
    Inf pixels raise ValueError, as the other metrics do.
    """
    from relight.imaging.colour import luminance

    p, r, m, _ = _prepare(photo, relit, mask)
    t, _, _, _ = _prepare(target, photo, mask)
    w = m.reshape(-1)
    keep = w > 0
    w = w[keep]
    base = np.log(np.maximum(luminance(p).reshape(-1)[keep], floor))
    x = np.log(np.maximum(luminance(t).reshape(-1)[keep], floor)) - base
    y = np.log(np.maximum(luminance(r).reshape(-1)[keep], floor)) - base
    total = w.sum()
    x = x - (w * x).sum() / total
    y = y - (w * y).sum() / total
    sxx, syy, sxy = (w * x * x).sum(), (w * y * y).sum(), (w * x * y).sum()
    if not math.sqrt(sxx / total) >= NO_CHANGE_RMS:
        return LightResponse(float("nan"), float("nan"), int(keep.sum()))
    if not math.sqrt(syy / total) >= NO_CHANGE_RMS:
        return LightResponse(0.0, 0.0, int(keep.sum()))
    return LightResponse(float(sxy / sxx), float(np.clip(sxy / math.sqrt(sxx * syy), -1.0, 1.0)), int(keep.sum()))


PSNR_PEAK = 1.0
MSE_FLOOR = 1e-10  # PSNR cap: 10 log10(1 / 1e-10) = 100 dB


def colour_cast_deg(image, reference, mask=None) -> float:
    """Angle (degrees) between the mask-weighted mean RGB of `image` and of `reference`.

    0 when the image is the reference up to exposure; a person relit under a
    white light who turns grey-green against the photo reads tens of degrees.
    A photo taken under coloured light also differs by that light's colour.
    """
    image = np.asarray(image, dtype=np.float64).reshape(-1, 3)
    reference = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
    w = np.ones(len(image)) if mask is None else np.asarray(mask, dtype=np.float64).reshape(-1)
    if w.sum() <= 0:
        raise ValueError("colour_cast_deg needs a non-empty mask")
    a = (image * w[:, None]).sum(0)
    b = (reference * w[:, None]).sum(0)
    norms = np.linalg.norm(a) * np.linalg.norm(b)
    if norms <= 0:
        return 90.0  # a black image has no colour to compare
    return float(np.degrees(np.arccos(np.clip(a @ b / norms, -1.0, 1.0))))


def _prepare(pred, target, mask):
    p = np.asarray(pred, dtype=np.float64)
    t = np.asarray(target, dtype=np.float64)
    if p.shape != t.shape:
        raise ValueError(f"prediction shape {p.shape} != target shape {t.shape}")
    if p.ndim != 3:
        raise ValueError(f"images must be [H, W, C], got shape {p.shape}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(t))):
        raise ValueError("images contain NaN or Inf")
    if mask is None:
        m = np.ones(p.shape[:2])
    else:
        m = np.asarray(mask, dtype=np.float64)
        if m.shape == p.shape[:2] + (1,):
            m = m[..., 0]
        if m.shape != p.shape[:2]:
            raise ValueError(f"mask shape {m.shape} does not match image {p.shape[:2]}")
        if not np.all(np.isfinite(m)) or m.min() < 0:
            raise ValueError("mask must be finite and >= 0")
    total = m.sum()
    if not total > 0:
        raise ValueError("mask is empty: no pixel to measure")
    return p, t, m, total


def l1(pred, target, mask=None) -> float:
    """Alpha-weighted mean absolute error over pixels and channels."""
    p, t, m, total = _prepare(pred, target, mask)
    return float((np.abs(p - t) * m[..., None]).sum() / (total * p.shape[2]))


def _scaled_mse(pred, target, mask) -> tuple[float, float]:
    """(m, s) with MSE = m * s^2; dividing by s = max |error| first keeps the squares finite."""
    p, t, m, total = _prepare(pred, target, mask)
    diff = p - t
    scale = float(np.max(np.abs(diff)))
    if scale == 0.0:
        return 0.0, 0.0
    return float(((diff / scale) ** 2 * m[..., None]).sum() / (total * p.shape[2])), scale


def l2(pred, target, mask=None) -> float:
    """Alpha-weighted mean squared error over pixels and channels (inf beyond ~1e154 errors)."""
    normalized, scale = _scaled_mse(pred, target, mask)
    with np.errstate(over="ignore"):
        return float(np.float64(normalized) * scale * scale)


def psnr(pred, target, mask=None, peak: float = PSNR_PEAK) -> float:
    """10 log10(peak^2 / max(MSE, 1e-10)) in dB, computed in the log domain: finite for any finite input."""
    normalized, scale = _scaled_mse(pred, target, mask)
    if normalized == 0.0:
        log_mse = math.log10(MSE_FLOOR)
    else:
        log_mse = max(math.log10(normalized) + 2.0 * math.log10(scale), math.log10(MSE_FLOOR))
    return 20.0 * math.log10(peak) - 10.0 * log_mse


def scale_invariant_psnr(pred, target, mask=None, peak: float = PSNR_PEAK) -> float:
    """PSNR after per-channel least-squares gains fitted to the target (fit_channel_gains):
    colour and level are ambiguous from one photo, so this scores the shading pattern
    itself (the usual practice for intrinsic images and relighting)."""
    p = np.asarray(pred, dtype=np.float64)
    return psnr(p * fit_channel_gains(p, target, mask), target, mask, peak)


def all_metrics(pred, target, mask=None) -> dict[str, float]:
    """{"l1", "l2", "psnr", "si_psnr"} for one image."""
    return {"l1": l1(pred, target, mask), "l2": l2(pred, target, mask), "psnr": psnr(pred, target, mask),
            "si_psnr": scale_invariant_psnr(pred, target, mask)}
