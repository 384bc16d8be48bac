"""Issue 25/26: which of the network's own numbers predict the relit level error?

    PYTHONPATH=. .venv/bin/python benchmarks/studies/study_level_features.py \\
        --calib data/calib128 --heldout data/heldout256 [--model relight/models/geometry.onnx] \\
        [--quality balanced|best] [--cache /tmp/level_rows.npz]

The shipped LevelPrior (relight.network.level) regresses each channel's log2 relit gain on two
numbers of the decomposition: the person's mean fitted shading (its log luminance l and
colour x_c). This study records more candidate features per pair, and for each pair the
sufficient statistics of its relit error as a function of per-channel gains
(sum w r^2, sum w r t, sum w t^2, sum w: the relit image scales by the gain, so the PSNR
of any gain is exact in closed form). Regressions with each feature set are fitted on the
calibration set's PRT pairs under mixed training lights (as `export.level_prior
--mixed-lights`) and scored on the held-out pairs (held-out maps never fitted).
A leave-one-scene-out fit on the held-out pairs themselves is printed for reference (the
in-sample bound of each feature set).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from relight.imaging.colour import luminance  # noqa: E402 (after the repository on sys.path)

FLOOR = 1e-4

FEATURES = ("l", "xr", "xg", "xb", "L", "Lxr", "Lxg", "Lxb", "dir", "photo", "albedo", "bg", "spread",
            "lb", "b1", "b2", "b3")


def _log2(v):
    return math.log2(max(float(v), FLOOR))


THUMB = 8  # the appearance features: 8 x 8 matte-weighted means of log albedo, log shading, log photo


def thumbnails(d) -> np.ndarray:
    """[THUMB * THUMB * 8]: the person's log albedo (3), log shading luminance (1) and log photo (3)
    as matte-weighted means over an 8 x 8 grid of the crop, and the grid's matte coverage (1)."""
    from relight.imaging.resample import resize_linear

    a = np.asarray(d.alpha, np.float32)[..., None]
    logs = [np.log2(np.maximum(d.albedo, 1e-3)),
            np.log2(np.maximum(luminance(d.transport @ d.light), 1e-3))[..., None],
            np.log2(np.maximum(d.photo_working, 1e-3))]
    grid = resize_linear(np.concatenate([v * a for v in logs] + [a], axis=-1).astype(np.float32), THUMB, THUMB)
    cover = grid[..., -1:]
    return np.concatenate([(grid[..., :-1] / np.maximum(cover, 1e-3)).ravel(), cover.ravel()])


def pair_row(d, pair):
    """(features [len(FEATURES)], stats [4, 3]) of one decomposition and its pair."""
    from model.scoring.metrics import interior_weight
    from relight.network.level import features
    from relight.lighting.sh import mean_luminance

    l, x = features(d.transport, d.light, d.alpha)
    light = np.asarray(d.light, np.float64)
    dc = np.maximum(light[0] / (2 * math.sqrt(math.pi)), FLOOR)
    big = _log2(mean_luminance(light))
    dc_colour = np.log2(dc) - _log2(luminance(dc))
    directional = float(np.linalg.norm(luminance(light[1:4])) / max(abs(luminance(light[0])), FLOOR))
    w = np.asarray(d.alpha, np.float64)
    person = w > 0.5
    photo_lum = luminance(np.asarray(d.photo_working, np.float64))
    albedo_lum = luminance(np.asarray(d.albedo, np.float64))
    shading = np.asarray(d.transport, np.float64) @ light
    shading_lum = np.maximum(luminance(shading), FLOOR)
    crop_photo = luminance(np.asarray(pair["photo"], np.float64))
    background = np.asarray(pair["alpha"]) < 0.05
    feats = [l, *x, big, *dc_colour, directional,
             _log2(photo_lum[person].mean()) if person.any() else math.log2(FLOOR),
             _log2(albedo_lum[person].mean()) if person.any() else math.log2(FLOOR),
             _log2(crop_photo[background].mean()) if background.any() else math.log2(FLOOR),
             float(np.std(np.log2(shading_lum[person]))) if person.any() else 0.0]
    # the target light: the relit shading's level against the fitted one, and its first band
    light_b = np.asarray(pair["light_b"], np.float64)
    relit_shading = np.maximum(luminance(np.asarray(d.transport, np.float64) @ light_b), FLOOR)
    feats += [_log2(relit_shading[person].mean()) - l if person.any() else 0.0,
              *(luminance(light_b[1:4]) / max(abs(luminance(light_b[0])), FLOOR))]
    relit = np.asarray(d.relight(pair["light_b"]), np.float64)
    target = np.asarray(pair["target"], np.float64)
    wi = interior_weight(pair["alpha"])[..., None].astype(np.float64)
    stats = np.stack([(wi * relit * relit).sum((0, 1)), (wi * relit * target).sum((0, 1)),
                      (wi * target * target).sum((0, 1)), np.repeat(wi.sum(), 3)])
    return np.array(feats, np.float64), stats


def collect(relighter, data, mixed: bool, quality: str, count: int | None = None):
    from export.level_prior import _mixed_pairs, _options, _pairs

    n_per_scene = 2 if mixed else 4
    rows, stats, scenes, thumbs = [], [], [], []
    pairs = _mixed_pairs(data, count) if mixed else _pairs(data, count)
    for i, pair in enumerate(pairs):
        d = relighter.decompose(pair["photo"], mask=pair["alpha"], level=False, **_options(quality))
        f, s = pair_row(d, pair)
        rows.append(f)
        stats.append(s)
        scenes.append(i // n_per_scene)
        thumbs.append(thumbnails(d))
    return np.array(rows), np.array(stats), np.array(scenes), np.array(thumbs)


def psnr_with(stats, stops):
    """Mean PSNR (peak 1) over pairs of relit images times 2^stops [N, 3]."""
    g = np.exp2(stops)
    rr, rt, tt, n = stats[:, 0], stats[:, 1], stats[:, 2], stats[:, 3]
    sse = (g * g * rr - 2 * g * rt + tt).sum(1)
    mse = np.maximum(sse / n.sum(1), 1e-10)
    return float(np.mean(-10 * np.log10(mse)))


def best_stops(stats):
    return np.log2(np.maximum(stats[:, 1], 1e-12) / np.maximum(stats[:, 0], 1e-12))


def fit(X, Y, ridge):
    """Per-channel ridge regression on centred features; X [N, k] (per channel: [N, 3, k])."""
    coefs = []
    for c in range(3):
        Xc = X[:, c] if X.ndim == 3 else X
        mu = Xc.mean(0)
        A = Xc - mu
        y = Y[:, c]
        beta = np.linalg.solve(A.T @ A + ridge * len(y) * np.eye(A.shape[1]), A.T @ (y - y.mean()))
        coefs.append((y.mean() - mu @ beta, beta))
    return coefs


def predict(coefs, X):
    return np.stack([a + (X[:, c] if X.ndim == 3 else X) @ b for c, (a, b) in enumerate(coefs)], axis=1)


def design(F, names):
    """[N, 3, k]: per channel, the named features (x / Lx pick the channel's own colour)."""
    cols = []
    for name in names:
        if name in ("x", "Lx"):
            idx = [FEATURES.index(name + ch) for ch in "rgb"]
            cols.append(F[:, idx])
        else:
            cols.append(np.repeat(F[:, FEATURES.index(name)][:, None], 3, axis=1))
    return np.stack(cols, axis=2)


SETS = {
    "none (network as it is)": None,
    "shipped: l, x": ("l", "x"),
    "l, x, L": ("l", "x", "L"),
    "l, x, L, Lx": ("l", "x", "L", "Lx"),
    "l, x, photo": ("l", "x", "photo"),
    "l, x, L, dir": ("l", "x", "L", "dir"),
    "l, x, L, spread": ("l", "x", "L", "spread"),
    "l, x, bg": ("l", "x", "bg"),
    "l, x, L, Lx, dir, photo, spread": ("l", "x", "L", "Lx", "dir", "photo", "spread"),
    "all": ("l", "x", "L", "Lx", "dir", "photo", "bg", "spread"),
    "l, x, lb (target)": ("l", "x", "lb"),
    "l, x, b1-3 (target)": ("l", "x", "b1", "b2", "b3"),
    "l, x, lb, b1-3 (target)": ("l", "x", "lb", "b1", "b2", "b3"),
}


def appearance(Fc, Tc, Yc, Sc, Fh, Th, Sh) -> str:
    """A row for the thumbnails (with l and x): standardised ridge regression, its weight chosen
    by 5-fold cross-validation over the calibration pairs grouped by scene (2 pairs a scene)."""
    def ridge(X, Y, lam):
        mu, sd = X.mean(0), X.std(0) + 1e-6
        A = (X - mu) / sd
        B = np.linalg.solve(A.T @ A + lam * len(A) * np.eye(A.shape[1]), A.T @ (Y - Y.mean(0)))
        return lambda Z: Y.mean(0) + ((Z - mu) / sd) @ B

    Xc, Xh = np.c_[Fc[:, :4], Tc], np.c_[Fh[:, :4], Th]
    fold = (np.arange(len(Xc)) // 2) % 5
    scores = {}
    for lam in (0.1, 1.0, 10.0, 100.0):
        cv = np.zeros_like(Yc)
        for k in range(5):
            cv[fold == k] = ridge(Xc[fold != k], Yc[fold != k], lam)(Xc[fold == k])
        scores[lam] = psnr_with(Sc, np.clip(cv, -2, 2))
    lam = max(scores, key=scores.get)
    pred = np.clip(ridge(Xc, Yc, lam)(Xh), -2, 2)
    return (f"| l, x + 8x8 thumbnails of log albedo, shading, photo (ridge {lam:g} by CV) | "
            f"{psnr_with(Sh, pred):.2f} | |")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--calib", required=True)
    p.add_argument("--heldout", required=True)
    p.add_argument("--model", default=str(ROOT / "relight/models/geometry.onnx"))
    p.add_argument("--quality", default="balanced")
    p.add_argument("--cache", default=None, help="npz of the collected rows (reused when it exists)")
    p.add_argument("--ridge", type=float, default=0.002)
    p.add_argument("--pairs", type=int, default=None, help="at most this many pairs of each set (a quick look)")
    args = p.parse_args(argv)
    from relight.network.runtime import Relighter

    cache = Path(args.cache) if args.cache else None
    if cache and cache.exists():
        z = np.load(cache)
        Fc, Sc, Fh, Sh, scenes, Tc, Th = (z[k] for k in ("Fc", "Sc", "Fh", "Sh", "scenes", "Tc", "Th"))
    else:
        relighter = Relighter(args.model, threads=2)
        Fc, Sc, calib_scenes, Tc = collect(relighter, args.calib, True, args.quality, args.pairs)
        Fh, Sh, scenes, Th = collect(relighter, args.heldout, False, args.quality, args.pairs)
        if cache:
            np.savez(cache, Fc=Fc, Sc=Sc, Fh=Fh, Sh=Sh, scenes=scenes, Tc=Tc, Th=Th)
    Yc, Yh = best_stops(Sc), best_stops(Sh)
    print(f"{len(Fc)} calibration pairs (mixed training lights), {len(Fh)} held-out pairs; quality {args.quality}")
    print(f"held-out: as it is {psnr_with(Sh, np.zeros_like(Yh)):.2f} dB; per-pair best gains "
          f"{psnr_with(Sh, Yh):.2f} dB; sd of the best log2 gain (luminance) {np.std(luminance(Yh)):.2f} stops")
    print("\n| features | held-out PSNR, fitted on calibration | held-out, leave-one-scene-out (in-sample) |")
    print("|---|---|---|")
    for label, names in SETS.items():
        if names is None:
            print(f"| {label} | {psnr_with(Sh, np.zeros_like(Yh)):.2f} | |")
            continue
        Xc, Xh = design(Fc, names), design(Fh, names)
        pred = np.clip(predict(fit(Xc, Yc, args.ridge), Xh), -2, 2)
        loso = np.zeros_like(Yh)
        for s in np.unique(scenes):
            out = scenes == s
            loso[out] = predict(fit(Xh[~out], Yh[~out], args.ridge), Xh[out])
        print(f"| {label} | {psnr_with(Sh, pred):.2f} | {psnr_with(Sh, np.clip(loso, -2, 2)):.2f} |")
    print(appearance(Fc, Tc, Yc, Sc, Fh, Th, Sh))
    corr = [np.corrcoef(Fh[:, i], luminance(Yh))[0, 1] for i in range(len(FEATURES))]
    corr_c = [np.corrcoef(Fc[:, i], luminance(Yc))[0, 1] for i in range(len(FEATURES))]
    print("\ncorrelation of each feature with the luminance log gain (held-out / calibration):")
    for name, a, b in zip(FEATURES, corr, corr_c):
        print(f"  {name:8s} {a:+.2f} / {b:+.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
