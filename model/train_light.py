"""python -m model.train_light: train the light estimator (model/light_estimator.py) on the
farm's path-traced images, as Lightning's examples train a model.

    python -m model.train_light --data data/train128 --pack runs/pack128.npz --out runs/light \\
        [--steps 1500] [--batch 16] [--lr 2e-3] [--light-tint 0.15] [--exposure-jitter 0] [--seed 0]

Samples (LightSamples): a scene of the training bodies, one of its path-traced lights that
is not held out, the image masked by the true alpha as the runtime masks it by the person
matte, in the estimator's input (relight.light_estimate.estimator_input); its light and the
person's mean albedo the targets. Exact augmentations: a horizontal mirror (the light's
mirror signs), a per-channel light tint of luminance 1, and optionally an exposure gain
(image and light alike; off by default: with it the level has nothing to go by but the
photo's brightness, and the validation error rose from 0.09 to 0.3-0.5 stops). Validation:
the light's colour error (degrees between DC colours) and level error (stops), and the
mean albedo's, on the held-out bodies. Writes OUT/model.safetensors (+ .json) like model.train.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import lightning as L
import numpy as np
import torch

from model.checkpoint import save_model
from model.data_augment import mirror_signs, random_light_tint
from model.data_crops import DEFAULT_PADDING, PackedScenes, SceneCache, load_cropped, pack_scenes
from model.data_splits import held_out_light_names, split_by_body
from model.light_estimator import (LightEstimator, albedo_colour_error_deg, colour_error_deg, level_error_stops,
                                   light_losses)
from model.train_data import EpochIndexed, EpochShuffleSampler, first_scenes
from model.train_module import lr_factor
from relight.light_estimate import estimator_input


class LightSamples(torch.utils.data.Dataset):
    """(estimator input [4, 64, 64], true light [n, 3]) of each scene's path-traced, not held-out
    lights; `augment` draws the mirror, tint and exposure from (seed, epoch, item)."""

    def __init__(self, scenes, order: int, *, augment: bool, seed: int = 0, light_tint: float = 0.15,
                 exposure_jitter: float = 0.0, flip_prob: float = 0.5):
        self.scenes, self.n = scenes, (order + 1) ** 2
        self.items = [(i, k) for i, s in enumerate(scenes) for k, (img, h) in enumerate(zip(s.images, s.held_out))
                      if img is not None and not h]
        if not self.items:
            raise ValueError("no path-traced training lights in these scenes")
        self.augment, self.seed = augment, seed
        self.light_tint, self.exposure_jitter, self.flip_prob = light_tint, exposure_jitter, flip_prob
        self.signs = mirror_signs(order)
        # each scene's mean albedo over its fully covered pixels (the estimator's second answer)
        self.albedo_means = [mean_albedo(s) for s in scenes]

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, j: int) -> dict:
        return self.item(j, 0)

    def item(self, j: int, epoch: int) -> dict:
        i, k = self.items[j]
        scene = self.scenes[i]
        image = scene.images[k].transpose(1, 2, 0)  # [S, S, 3]
        alpha = scene.alpha[0]
        light = np.asarray(scene.lights[k][: self.n], np.float32)
        if self.augment:
            rng = np.random.default_rng([self.seed, epoch, j])
            if self.light_tint > 0:
                tint = random_light_tint(rng, self.light_tint)
                image, light = image * tint, light * tint
            if self.exposure_jitter > 0:
                gain = np.float32(2.0 ** rng.normal(0.0, self.exposure_jitter))
                image, light = image * gain, light * gain
            if rng.uniform() < self.flip_prob:
                image, alpha, light = image[:, ::-1], alpha[:, ::-1], light * self.signs[:, None]
        x = estimator_input(image, alpha)[0]
        return {"input": torch.from_numpy(x), "light": torch.from_numpy(np.ascontiguousarray(light)),
                "albedo_mean": torch.from_numpy(self.albedo_means[i])}


def mean_albedo(scene) -> np.ndarray:
    """[3] float32: the scene crop's mean albedo over its fully covered pixels (alpha > 0.999),
    over all covered pixels when none is full."""
    alpha = scene.alpha[0]
    w = (alpha > 0.999).astype(np.float32)
    if w.sum() == 0:
        w = alpha
    return ((scene.albedo * w).sum(axis=(1, 2)) / max(float(w.sum()), 1e-6)).astype(np.float32)


class LightModule(L.LightningModule):
    """LightEstimator with light_losses, AdamW and a warm-up + cosine schedule; validation logs
    the colour and level errors."""

    def __init__(self, order: int, width: int, lr: float, weight_decay: float, warmup: int, total_steps: int):
        super().__init__()
        self.save_hyperparameters()
        self.model = LightEstimator(order, width)

    def training_step(self, batch, batch_idx):
        out = self.model(batch["input"])
        terms = light_losses(out["light"], batch["light"], out["albedo_mean"], batch["albedo_mean"])
        self.log_dict({f"train/{k}": v for k, v in terms.items()}, batch_size=batch["input"].shape[0])
        return terms["total"]

    def validation_step(self, batch, batch_idx):
        out = self.model(batch["input"])
        pred, b = out["light"], batch["input"].shape[0]
        self.log("val/colour_deg", colour_error_deg(pred, batch["light"]).mean(), batch_size=b, prog_bar=True)
        self.log("val/level_stops", level_error_stops(pred, batch["light"]).mean(), batch_size=b)
        self.log("val/albedo_colour_deg", albedo_colour_error_deg(out["albedo_mean"], batch["albedo_mean"]).mean(),
                 batch_size=b)
        self.log("val/albedo_level_stops", torch.log2(out["albedo_mean"].mean(-1).clamp(min=1e-6)
                                                      / batch["albedo_mean"].mean(-1)).abs().mean(), batch_size=b)

    def configure_optimizers(self):
        hp = self.hparams
        opt = torch.optim.AdamW(self.model.parameters(), lr=hp.lr, weight_decay=hp.weight_decay)
        sched = torch.optim.lr_scheduler.LambdaLR(
            opt, lambda step: lr_factor(step, hp.total_steps, hp.warmup, "cosine"))
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}


class LightDataModule(L.LightningDataModule):
    """The farm's scenes split by body; the training bodies' crops from `pack` (made when
    missing or stale, the pack model.train makes) or from the scene files."""

    def __init__(self, folders, *, order: int, batch: int, seed: int, size: int = 128,
                 val_fraction: float = 0.1, pack: Path | None = None, augment: dict | None = None):
        super().__init__()
        self.order, self.batch, self.seed, self.size, self.pack = order, batch, seed, size, pack
        self.augment = augment or {}
        self.held_out = held_out_light_names()
        self.train_paths, self.val_paths = split_by_body(first_scenes(folders), val_fraction, seed=seed)

    def _scenes(self, paths, pack):
        if pack is not None:
            try:
                return PackedScenes(pack, paths, self.size, self.order, DEFAULT_PADDING).items
            except (OSError, ValueError, KeyError):  # missing, stale or unreadable: make it again
                pack_scenes(paths, pack, self.size, self.order, DEFAULT_PADDING, self.held_out)
                return PackedScenes(pack, paths, self.size, self.order, DEFAULT_PADDING).items
        cache = SceneCache(paths, lambda p: load_cropped(p, self.size, self.order, DEFAULT_PADDING, self.held_out),
                           capacity=len(paths))
        return [cache(i) for i in range(len(paths))]

    def setup(self, stage: str | None = None) -> None:
        self.train_set = LightSamples(self._scenes(self.train_paths, self.pack), self.order, augment=True,
                                      seed=self.seed, **self.augment)
        self.val_set = LightSamples(self._scenes(self.val_paths, None), self.order, augment=False) \
            if self.val_paths else None

    def train_dataloader(self):
        return torch.utils.data.DataLoader(EpochIndexed(self.train_set), batch_size=self.batch,
                                           sampler=EpochShuffleSampler(len(self.train_set), self.seed),
                                           drop_last=len(self.train_set) >= self.batch)

    def val_dataloader(self):
        return [] if self.val_set is None else torch.utils.data.DataLoader(self.val_set, batch_size=self.batch)


def parse_args(argv=None):
    p = argparse.ArgumentParser(prog="python -m model.train_light", description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True, nargs="+", help="farm output folder(s)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--pack", default=None, metavar="FILE.npz", help="the training crops (model.train's pack)")
    p.add_argument("--steps", type=int, default=1500)
    p.add_argument("--batch", type=int, default=16)
    p.add_argument("--lr", type=float, default=2e-3)
    p.add_argument("--weight-decay", type=float, default=1e-4)
    p.add_argument("--warmup", type=int, default=100)
    p.add_argument("--width", type=int, default=32)
    p.add_argument("--order", type=int, default=4)
    p.add_argument("--light-tint", type=float, default=0.15, metavar="SIGMA")
    p.add_argument("--exposure-jitter", type=float, default=0.0, metavar="SIGMA")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=0)
    p.add_argument("--val-every", type=int, default=500)
    p.add_argument("--quiet", action="store_true")
    args = p.parse_args(argv)
    for name in ("steps", "batch", "width", "val_every"):
        if getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1")
    if not (args.lr > 0 and np.isfinite(args.lr)):
        p.error("--lr must be a positive number")
    return args


def train(args) -> Path:
    warnings.filterwarnings("ignore", ".*does not have many workers.*")
    warnings.filterwarnings("ignore", ".*number of training batches.*")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    L.seed_everything(args.seed, workers=True, verbose=False)
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    data = LightDataModule(args.data, order=args.order, batch=args.batch, seed=args.seed,
                           pack=None if args.pack is None else Path(args.pack),
                           augment={"light_tint": args.light_tint, "exposure_jitter": args.exposure_jitter})
    data.setup("fit")
    module = LightModule(args.order, args.width, args.lr, args.weight_decay, args.warmup, args.steps)
    trainer = L.Trainer(max_steps=args.steps, accelerator="cpu", devices=1, logger=L.pytorch.loggers.CSVLogger(out),
                        enable_checkpointing=False, enable_progress_bar=not args.quiet, enable_model_summary=False,
                        log_every_n_steps=min(10, args.steps), num_sanity_val_steps=0,
                        val_check_interval=args.val_every if data.val_set is not None else None,
                        check_val_every_n_epoch=None, limit_val_batches=1.0 if data.val_set is not None else 0)
    trainer.fit(module, datamodule=data)
    record = {"seed": args.seed, "steps": int(trainer.global_step), "data": [str(d) for d in args.data],
              "train_scenes": len(data.train_paths), "val_scenes": len(data.val_paths),
              "args": {k: v for k, v in vars(args).items()}}
    return save_model(module.model.cpu().eval(), out / "model.safetensors", extra={"training": record})


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        path = train(args)
    except (ValueError, FloatingPointError) as exc:
        print(f"model.train_light: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
