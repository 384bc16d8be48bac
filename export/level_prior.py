"""python -m export.level_prior MODEL.onnx --data CALIBRATION_DIR [...] [--write] [--check HELD_OUT_DIR] [--quality KEY]

Calibrates a relighting model's LevelPrior (relight.network.level): on farm scenes lit by
training lights (never the held-out maps: render them with `python -m farm ...
--light-pool train`), every pair (scene, light a -> light b) is decomposed by the
runtime as `relight image` would (the true alpha as the mask, a quality preset's work,
Balanced by default, the prior off), and the per-channel gains that would make its relit image match the
path-traced image under b are regressed on the network's fitted shading over the
person. With --write the prior goes into the ONNX file's metadata (relight.level_prior),
the file is rewritten atomically and its SHA-256 updated beside it and, where the model
is registered, in the registry. With --check, held-out pairs are relit with and without
the prior and both PSNRs printed.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

CROP = 256          # the pairs' crop size, as benchmarks/bench_quality.py scores them


def _pairs(data, count: int | None):
    from model.samples.data import photo_pairs

    return photo_pairs(data, CROP, count)


def _mixed_pairs(data, count: int | None, seed: int = 0):
    """Pairs under lights no map gives, as the photo's light is in a real photo: each scene's
    first two path-traced pairs re-rendered by PRT (albedo x (T . L)) under two mixes of its own
    lights and the training presets (model.samples.data_augment.random_mixed_light), seeded per pair."""
    from model.samples.data import photo_pairs
    from model.samples.data_augment import preset_training_lights, random_mixed_light

    bank = [light for _, light in preset_training_lights(4)]
    for i, pair in enumerate(photo_pairs(data, CROP, count, per_scene=2, transport=True)):
        rng = np.random.default_rng([seed, i])
        light_a, light_b = (random_mixed_light(own, bank[rng.integers(len(bank))], rng).astype(np.float64)
                            for own in (pair["light_a"], pair["light_b"]))
        albedo, transport = pair["albedo"].astype(np.float64), pair["transport"].astype(np.float64)
        alpha = pair["alpha"][..., None].astype(np.float64)
        photo = albedo * np.maximum(transport @ light_a, 0.0)
        yield {"photo": (alpha * photo + (1 - alpha) * pair["photo"]).astype(np.float32), "alpha": pair["alpha"],
               "target": (albedo * np.maximum(transport @ light_b, 0.0)).astype(np.float32), "light_b": light_b}


def _options(quality: str) -> dict:
    """Relighter.decompose's options for a preset, less the segmenter (the pairs carry their mask)."""
    from relight.network.quality import preset

    options = preset(quality).decompose_options()
    options.pop("matte_method")
    return options


def calibration_rows(relighter, data, count: int | None = None, quality: str = "balanced", mixed: bool = False):
    """(lums, colours, log2 gains [N, 3]) of the pairs in `data` (relight.network.level.features of
    each decomposition, and the per-channel least-squares gains of its relit image); with
    `mixed`, of its PRT pairs under mixed lights (`_mixed_pairs`) instead."""
    from model.scoring.metrics import interior_weight
    from relight.network.level import features

    lums, colours, gains = [], [], []
    for pair in (_mixed_pairs(data, count) if mixed else _pairs(data, count)):
        d = relighter.decompose(pair["photo"], mask=pair["alpha"], level=False, **_options(quality))
        relit = d.relight(pair["light_b"]).astype(np.float64)
        w = interior_weight(pair["alpha"])[..., None]
        num = (w * relit * pair["target"]).sum((0, 1))
        den = (w * relit * relit).sum((0, 1))
        if not (np.all(num > 0) and np.all(den > 0)):
            continue  # nothing lit to compare: no evidence either way
        lum, colour = features(d.transport, d.light, d.alpha)
        lums.append(lum)
        colours.append(colour)
        gains.append(np.log2(num / den))
    return np.array(lums), np.array(colours), np.array(gains)


def held_out_psnr(relighter, data, count: int | None = None, quality: str = "balanced") -> tuple[float, float, int]:
    """Mean relit PSNR of held-out pairs without and with the model's level prior."""
    from model.scoring import metrics
    from model.scoring.metrics import interior_weight

    without, with_prior = [], []
    for pair in _pairs(data, count):
        w = interior_weight(pair["alpha"])
        for level, out in ((False, without), (True, with_prior)):
            d = relighter.decompose(pair["photo"], mask=pair["alpha"], level=level, **_options(quality))
            out.append(metrics.psnr(d.relight(pair["light_b"]), pair["target"], w))
    return float(np.mean(without)), float(np.mean(with_prior)), len(without)


def write_prior(model_path: Path, prior) -> str:
    """Store `prior` in the ONNX file's metadata (atomically) and update its hashes; returns the
    new SHA-256."""
    import onnx

    from export.onnx_export import read_metadata, save_atomic, set_metadata
    from relight import models
    from relight.network.level import METADATA_KEY

    model = onnx.load(str(model_path))
    metadata = read_metadata(model)
    metadata[METADATA_KEY] = prior.to_metadata()
    set_metadata(model, metadata)
    _, digest = save_atomic(model, model_path)
    registry = models.load_registry(models.REGISTRY_PATH)
    for name, entry in registry["models"].items():
        if (models.REGISTRY_PATH.parent / entry["file"]).resolve() == model_path.resolve():
            models.register_model(name, model_path, digest, metadata,
                                  make_default=registry.get("default") == name)
    return digest


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m export.level_prior", description=__doc__.splitlines()[0])
    p.add_argument("model", type=Path, help="a relighting model (.onnx)")
    p.add_argument("--data", nargs="+", required=True, help="calibration farm folders (training lights only)")
    p.add_argument("--pairs", type=int, default=None, help="at most this many calibration pairs")
    p.add_argument("--write", action="store_true", help="store the prior in MODEL's metadata")
    p.add_argument("--check", default=None, metavar="HELD_OUT_DIR",
                   help="relight these held-out pairs with and without the prior")
    p.add_argument("--quality", default="balanced", help="the quality preset whose work is calibrated")
    p.add_argument("--mixed-lights", action="store_true",
                   help="calibrate on PRT pairs under mixed training lights (lights the network never saw "
                        "whole) instead of the path-traced pairs")
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)
    try:
        from relight.network.level import fit_prior
        from relight.network.runtime import Relighter

        relighter = Relighter(args.model, threads=args.threads)
        rows = [calibration_rows(relighter, folder, args.pairs, args.quality, args.mixed_lights)
                for folder in args.data]
        lums, colours, gains = (np.concatenate([r[i] for r in rows]) for i in range(3))
        prior = fit_prior(lums, colours, gains)
        print(f"calibrated on {prior.pairs} pairs: {prior.to_metadata()}")
        if args.write:
            digest = write_prior(args.model, prior)
            print(f"wrote the prior into {args.model} (sha256 {digest})")
        if args.check:
            relighter = Relighter(args.model, threads=args.threads)
            relighter.level_prior = prior
            without, with_prior, n = held_out_psnr(relighter, args.check, quality=args.quality)
            print(f"held-out {args.check}: {n} pairs, relit PSNR {without:.2f} dB without the prior, "
                  f"{with_prior:.2f} with it")
    except (ValueError, OSError) as exc:
        print(f"export.level_prior: error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
