"""Train RelightNet on scene files: `python -m model.train --data DIR --out DIR [options]`.

Lightning on the CPU by default (--device cpu); --device cuda (or --device auto when a
CUDA device is present) trains on the GPU with mixed precision.
AdamW, lr 5e-5 (the paper's). Writes to --out:
  checkpoints/last.ckpt   Lightning state for --resume (loaded with weights_only=True)
  model.safetensors/.json final weights + config (model.checkpoint), seed and args recorded
  metrics.csv (CSV logger under logs/)
"""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

import numpy as np
import torch

from model.checkpoint import build_network, load_model, save_model
from model.geometry import ARCH as GEOMETRY, GEOMETRY_LOSS_WEIGHTS, GEOMETRY_PRESETS, geometry_losses
from model.data import EvaluationPairs, TrainingScenes
from model.data_augment import preset_training_lights
from model.data_crops import DEFAULT_PADDING, PackedScenes, pack_scenes
from model.data_splits import find_scenes, held_out_light_names, split_by_body
from model.losses import LossWeights, relight_losses
from model.network import PRESETS, RelightNet
from model import sh_torch


class EpochShuffleSampler(torch.utils.data.Sampler):
    """Shuffles per epoch and yields epoch * N + i, so each item's augmentation seed is
    fixed by (seed, epoch, i) whatever the number of workers or a resume in between."""

    def __init__(self, n: int, seed: int):
        self.n, self.seed, self.epoch = n, seed, 0

    def set_epoch(self, epoch: int) -> None:  # Lightning calls this at every epoch start
        self.epoch = epoch

    def __len__(self) -> int:
        return self.n

    def __iter__(self):
        order = np.random.default_rng([self.seed, self.epoch]).permutation(self.n)
        return iter((self.epoch * self.n + order).tolist())


class EpochIndexed(torch.utils.data.Dataset):
    """Maps the sampler's epoch * N + i back to item i with augmentation epoch `epoch`."""

    def __init__(self, dataset: TrainingScenes):
        self.dataset = dataset

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, k: int) -> dict:
        n = len(self.dataset)
        return self.dataset.item(k % n, epoch=k // n)


def build_model_config(args) -> dict:
    """Network config: the named --preset layout, --width/--depth when given, the ablation flags.

    geo-* presets build the geometry-first GeometryNet (model.geometry), the
    others RelightNet."""
    lambertian = args.lambertian
    if args.preset in GEOMETRY_PRESETS:
        layout = dict(GEOMETRY_PRESETS[args.preset])
        for name in ("width", "depth"):
            if getattr(args, name) is not None:
                layout[name] = getattr(args, name)
        return dict(arch=GEOMETRY, sh_order=args.order, **layout)
    layout = dict(PRESETS[args.preset])
    for name in ("width", "depth"):
        if getattr(args, name) is not None:
            layout[name] = getattr(args, name)
    return dict(sh_order=args.order, **layout,
                with_residual=not (args.no_residual or lambertian), with_matte=not args.no_matte,
                decomposition=not (args.no_decomposition or lambertian), tstar=args.tstar)


def lr_factor(step: int, total: int, warmup: int, schedule: str, floor: float = 0.05) -> float:
    """Multiplier of the base learning rate at `step`: linear warm-up, then constant or cosine to `floor`.

    A short CPU budget needs a decaying rate: the last steps at a small rate are
    where the loss settles (constant AdamW rates plateau at the noise level).
    """
    if warmup > 0 and step < warmup:
        return (step + 1) / warmup
    if schedule == "constant":
        return 1.0
    span = max(1, total - warmup)
    t = min(1.0, (step - warmup) / span)
    return floor + (1.0 - floor) * 0.5 * (1.0 + math.cos(math.pi * t))


def loss_weights_from_args(args) -> dict:
    """Loss weights by name: the model's defaults (LossWeights for RelightNet,
    model.geometry.GEOMETRY_LOSS_WEIGHTS for the geometry-first model) with each
    --loss-weight NAME=VALUE applied; --no-log-loss sets RelightNet's log term to 0."""
    geometry = args.preset in GEOMETRY_PRESETS
    weights = dict(GEOMETRY_LOSS_WEIGHTS) if geometry else LossWeights().to_dict()
    for item in args.loss_weight or []:
        name, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"--loss-weight expects NAME=VALUE, got {item!r}")
        try:
            number = float(value)
        except ValueError:
            raise ValueError(f"--loss-weight {name}: {value!r} is not a number") from None
        if name not in weights:
            raise ValueError(f"--loss-weight: unknown term {name!r} (known: {', '.join(weights)})")
        if not math.isfinite(number) or number < 0:
            raise ValueError(f"--loss-weight {name}: must be finite and >= 0")
        weights[name] = number
    if args.no_log_loss and not geometry:
        weights["log"] = 0.0
    return weights


def make_lightning_module(model_config: dict, weights: dict, lr: float, weight_decay: float,
                          schedule: str = "constant", warmup: int = 0, total_steps: int = 1):
    import lightning as L

    class RelightModule(L.LightningModule):
        def __init__(self, model_config: dict, weights: dict, lr: float, weight_decay: float,
                     schedule: str = "constant", warmup: int = 0, total_steps: int = 1):
            super().__init__()
            self.save_hyperparameters()  # plain dicts and floats: loadable with weights_only=True
            self.model = build_network(model_config)
            self.geometry = model_config.get("arch") == GEOMETRY
            self.weights = dict(weights) if self.geometry else LossWeights.from_dict(weights)

        def forward(self, image):
            return self.model(image)

        def _losses(self, batch):
            pred = self.model(batch["input"])
            pred = {k: v.float() for k, v in pred.items()}
            # under AMP, autocast would run the rendering einsums in float16: keep losses in float32
            with torch.autocast(device_type=self.device.type, enabled=False):
                if self.geometry:
                    return pred, geometry_losses(pred, batch, self.weights)
                return pred, relight_losses(pred, batch, self.weights, decomposition=self.model.decomposition,
                                            tstar=self.model.tstar)

        def training_step(self, batch, batch_idx):
            _, terms = self._losses(batch)
            if not torch.isfinite(terms["total"]):
                if str(self.trainer.precision).startswith("16"):
                    return None  # an fp16 overflow: skip this batch (Lightning skips the step)
                raise FloatingPointError(f"non-finite training loss at step {self.global_step}: "
                                         + ", ".join(f"{k}={float(v):.3g}" for k, v in terms.items()))
            self.log_dict({f"train/{k}": v for k, v in terms.items()}, batch_size=batch["input"].shape[0])
            self.log("loss", terms["total"], prog_bar=True, logger=False, batch_size=batch["input"].shape[0])
            return terms["total"]

        def validation_step(self, batch, batch_idx):
            pred, terms = self._losses(batch)
            b = batch["input"].shape[0]
            self.log_dict({f"val/{k}": v for k, v in terms.items()}, batch_size=b)
            w = batch["alpha"]
            recon = render_prediction(pred, pred["light"], self.model.tstar)
            relit = render_prediction(pred, batch["target_light"], self.model.tstar)
            for name, img, gt in (("psnr_image", recon, batch["image"]), ("psnr_relight", relit, batch["target_image"])):
                mse = ((img - gt) ** 2 * w).sum() / (w.sum() * 3).clamp_min(1e-8)
                self.log(f"val/{name}", -10.0 * torch.log10(mse.clamp_min(1e-10)), batch_size=b,
                         prog_bar=name == "psnr_relight")

        def configure_optimizers(self):
            opt = torch.optim.AdamW(self.model.parameters(), lr=self.hparams.lr,
                                    weight_decay=self.hparams.weight_decay)
            hp = self.hparams
            sched = torch.optim.lr_scheduler.LambdaLR(
                opt, lambda step: lr_factor(step, hp.total_steps, hp.warmup, hp.schedule))
            return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}

    return RelightModule(model_config, weights, lr, weight_decay, schedule, warmup, total_steps)


def render_prediction(pred: dict, light: torch.Tensor, tstar: bool) -> torch.Tensor:
    """albedo * (T . L) + E . L, or T* . L for the T* ablation."""
    if tstar:
        return sh_torch.shading_tstar(pred["transport"], light)
    return sh_torch.render(pred["albedo"], pred["transport"], pred["residual"], light)


def parse_args(argv=None):
    p = argparse.ArgumentParser(prog="python -m model.train", description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True, nargs="+",
                   help="dataset folder(s) of scene_NNNNNN.exr/.json (farm runs with different --first)")
    p.add_argument("--max-scenes", type=int, default=None, metavar="N",
                   help="use only the first N scenes of --data (folders in order, scenes by index): "
                        "data-size curves without copying data")
    p.add_argument("--out", required=True, help="output folder (checkpoints, final weights, logs)")
    p.add_argument("--steps", type=int, default=10000)
    p.add_argument("--batch", type=int, default=4)
    p.add_argument("--accumulate", type=int, default=1,
                   help="gradient accumulation: effective batch = batch x accumulate (paper: 16)")
    p.add_argument("--size", type=int, default=256, help="training crop size (multiple of 2**depth)")
    p.add_argument("--preset", choices=tuple(PRESETS) + tuple(GEOMETRY_PRESETS), default="default",
                   help="network layout: model.network.PRESETS (the paper's decomposition) or "
                        "model.geometry.GEOMETRY_PRESETS (geometry-first); --width/--depth override it")
    p.add_argument("--width", type=int, default=None)
    p.add_argument("--depth", type=int, default=None)
    p.add_argument("--order", type=int, default=4, help="SH order N (paper: 4; Kanamori-Endo: 2)")
    p.add_argument("--lr", type=float, default=5e-5)
    p.add_argument("--lr-schedule", choices=("constant", "cosine"), default="constant",
                   help="cosine: decay to 5%% of --lr over --steps after the warm-up")
    p.add_argument("--warmup", type=int, default=0, help="linear warm-up steps")
    p.add_argument("--init", default=None,
                   help="start from these .safetensors weights (same layout), e.g. a lower-resolution run")
    p.add_argument("--weight-decay", type=float, default=1e-2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--val-fraction", type=float, default=0.1, help="fraction of bodies held out for validation")
    p.add_argument("--val-every", type=int, default=500, help="validate every N steps")
    p.add_argument("--ckpt-every", type=int, default=500, help="write checkpoints/last.ckpt every N steps")
    p.add_argument("--workers", type=int, default=0)
    p.add_argument("--threads", type=int, default=0,
                   help="torch CPU threads (0: torch's default; 1 is far faster on a busy machine)")
    p.add_argument("--padding", type=int, default=DEFAULT_PADDING)
    p.add_argument("--cache-scenes", type=int, default=64,
                   help="cropped scenes kept in memory (reading an EXR costs more than a step)")
    p.add_argument("--pack", default=None, metavar="FILE.npz",
                   help="crop the training scenes once into this file (made when missing or stale) "
                        "and train from memory")
    p.add_argument("--extra-light-prob", type=float, default=0.5)
    p.add_argument("--mask-prob", type=float, default=0.5)
    p.add_argument("--flip-prob", type=float, default=0.5, help="horizontal mirror (exact for T and L)")
    p.add_argument("--light-tint", type=float, default=0.0, metavar="SIGMA",
                   help="tint each light and its image by exp(N(0, SIGMA^2)) per channel, luminance kept "
                        "(exact augmentation; 0: off)")
    p.add_argument("--exposure-jitter", type=float, default=0.0, metavar="SIGMA",
                   help="scale the input light and image by 2^N(0, SIGMA^2), albedo target unchanged "
                        "(exposure augmentation, exact; 0: off)")
    p.add_argument("--capture", action=argparse.BooleanOptionalAction, default=False,
                   help="photo-like capture of the input (model/capture.py: real backgrounds, white balance, "
                        "exposure, blur, noise, JPEG); off by default, measured in docs/EVALUATION.md")
    p.add_argument("--no-presets", action="store_true", help="extra lights from scene lights only")
    p.add_argument("--loss-weight", action="append", metavar="NAME=VALUE")
    p.add_argument("--no-residual", action="store_true", help="ablation: without E")
    p.add_argument("--no-decomposition", action="store_true", help="ablation: without PRT +/- decomposition")
    p.add_argument("--no-log-loss", action="store_true", help="ablation: without the log loss")
    p.add_argument("--no-matte", action="store_true", help="no alpha head")
    p.add_argument("--tstar", action="store_true", help="ablation: T* = albedo*T + E")
    p.add_argument("--lambertian", action="store_true",
                   help="Kanamori-Endo-style baseline: PRT images only, no E, no decomposition")
    p.add_argument("--resume", action="store_true", help="continue from OUT/checkpoints/last.ckpt")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="cpu")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    args = p.parse_args(argv)
    for name in ("steps", "batch", "accumulate", "size", "width", "depth", "val_every", "ckpt_every",
                 "cache_scenes"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1")
    if args.order < 0:
        p.error("--order must be >= 0")
    depth = args.depth if args.depth is not None else {**PRESETS, **GEOMETRY_PRESETS}[args.preset]["depth"]
    if args.size % (2 ** depth):
        p.error(f"--size {args.size} must be a multiple of 2**depth = {2 ** depth}")
    if args.warmup < 0:
        p.error("--warmup must be >= 0")
    if args.init and args.resume:
        p.error("--init and --resume exclude each other")
    if not (args.lr > 0 and math.isfinite(args.lr)):
        p.error("--lr must be a positive number")
    return args


def first_scenes(folders, limit: int | None = None) -> list[Path]:
    """Finished scenes of `folders` in order (each folder's by index), the first `limit` of them."""
    scenes = [path for folder in folders for path in find_scenes(folder)]
    if limit is None:
        return scenes
    if not 1 <= limit <= len(scenes):
        raise ValueError(f"--max-scenes {limit}: the data has {len(scenes)} finished scenes")
    return scenes[:limit]


def train(args) -> Path:
    """Run training; returns the final weights path."""
    import lightning as L
    from lightning.pytorch.callbacks import ModelCheckpoint
    from lightning.pytorch.loggers import CSVLogger

    warnings.filterwarnings("ignore", ".*does not have many workers.*")
    warnings.filterwarnings("ignore", ".*number of training batches.*")
    warnings.filterwarnings("ignore", ".*LeafSpec.*")  # lightning 2.6 vs torch 2.13 internals
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    L.seed_everything(args.seed, workers=True, verbose=False)
    if args.threads > 0:
        torch.set_num_threads(args.threads)

    scenes = first_scenes(args.data, args.max_scenes)
    train_paths, val_paths = split_by_body(scenes, args.val_fraction, seed=args.seed)
    held_out = held_out_light_names()
    extra = [] if args.no_presets else preset_training_lights(args.order)
    pack = None
    if args.pack:
        pack = Path(args.pack)
        try:
            PackedScenes(pack, train_paths, args.size, args.order, args.padding)
        except (OSError, ValueError, KeyError):  # missing, stale or unreadable: make it again
            pack_scenes(train_paths, pack, args.size, args.order, args.padding, held_out)
    train_set = TrainingScenes(train_paths, args.size, args.order, padding=args.padding, extra_lights=extra, pack=pack,
                               extra_light_prob=args.extra_light_prob, mask_prob=args.mask_prob,
                               flip_prob=args.flip_prob, light_tint=args.light_tint,
                               exposure_jitter=args.exposure_jitter, capture=args.capture,
                               lambertian=args.lambertian, seed=args.seed, held_out=held_out,
                               cache_size=args.cache_scenes)
    loader_kw = dict(num_workers=args.workers, persistent_workers=args.workers > 0)
    train_loader = torch.utils.data.DataLoader(EpochIndexed(train_set), batch_size=args.batch,
                                               sampler=EpochShuffleSampler(len(train_set), args.seed),
                                               drop_last=len(train_set) >= args.batch, **loader_kw)
    val_loader = None
    if val_paths:
        try:
            val_set = EvaluationPairs(val_paths, args.size, args.order, padding=args.padding, held_out=held_out)
            val_loader = torch.utils.data.DataLoader(val_set, batch_size=args.batch, shuffle=False, **loader_kw)
        except ValueError as exc:  # validation scenes without two path-traced lights
            print(f"model.train: no validation ({exc})", file=sys.stderr)

    weights = loss_weights_from_args(args)
    model_config = build_model_config(args)
    module = make_lightning_module(model_config, weights, args.lr, args.weight_decay,
                                   args.lr_schedule, args.warmup, args.steps)
    if args.init:
        start = load_model(args.init)
        if start.config() != module.model.config():
            raise ValueError(f"--init {args.init}: its layout {start.config()} differs from this run's "
                             f"{module.model.config()}")
        module.model.load_state_dict(start.state_dict())
    cuda = args.device == "cuda" or (args.device == "auto" and torch.cuda.is_available())
    if args.device == "cuda" and not torch.cuda.is_available():
        raise ValueError("--device cuda: no CUDA device available")
    ckpt_dir = out / "checkpoints"
    checkpoint = ModelCheckpoint(dirpath=ckpt_dir, save_last=True, save_top_k=0,
                                 every_n_train_steps=args.ckpt_every)
    trainer = L.Trainer(
        max_steps=args.steps, accumulate_grad_batches=args.accumulate,
        accelerator="gpu" if cuda else "cpu", devices=1,
        precision="16-mixed" if cuda else "32-true", callbacks=[checkpoint],
        logger=CSVLogger(out, name="logs"), enable_progress_bar=not args.quiet,
        enable_model_summary=False, log_every_n_steps=min(10, args.steps),
        val_check_interval=args.val_every if val_loader is not None else None,
        check_val_every_n_epoch=None, num_sanity_val_steps=0, deterministic=False,
        limit_val_batches=1.0 if val_loader is not None else 0,
    )
    resume_from = None
    if args.resume:
        last = ckpt_dir / "last.ckpt"
        if not last.is_file():
            raise ValueError(f"--resume: no checkpoint at {last}")
        resume_from = str(last)
    trainer.fit(module, train_loader, val_loader, ckpt_path=resume_from, weights_only=True)
    trainer.save_checkpoint(ckpt_dir / "last.ckpt", weights_only=False)  # full state, for --resume

    record = {"seed": args.seed, "steps": int(trainer.global_step),
              "loss_weights": weights,
              "data": [str(d) for d in args.data], "train_scenes": len(train_paths), "val_scenes": len(val_paths), "lambertian": args.lambertian,
              "init": str(args.init) if args.init else None, "args": {k: v for k, v in vars(args).items()}}
    return save_model(module.model.cpu().eval(), out / "model.safetensors", extra={"training": record})


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        path = train(args)
    except (ValueError, FloatingPointError) as exc:
        print(f"model.train: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
