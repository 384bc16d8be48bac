"""Train RelightNet on scene files: `python -m model.train --data DIR --out DIR [options]`.

Lightning on the CPU by default (--device cpu); --device cuda (or --device auto when a
CUDA device is present) trains on the GPU with mixed precision.
AdamW, lr 5e-5 (the paper's). Writes to --out:
  checkpoints/last.ckpt   Lightning state for --resume (loaded with weights_only=True)
  model.safetensors/.json final weights + config (model.training.checkpoint), seed and args recorded
  metrics.csv (CSV logger under logs/)
The LightningModule is model.training.train_module.RelightModule, the LightningDataModule
model.training.train_data.SceneDataModule; this module is the command line.
"""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

import lightning as L
import torch
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.loggers import CSVLogger

from model.training.checkpoint import init_weights, load_model, read_metadata, save_model
from model.samples.data_crops import DEFAULT_PADDING
from model.samples.data_splits import first_maps, training_map_names
from model.networks.geometry import ARCH as GEOMETRY, GEOMETRY_LOSS_WEIGHTS, GEOMETRY_PRESETS
from model.training.losses import LossWeights
from model.networks.network import PRESETS
from model.training.train_data import SceneDataModule
from model.training.train_module import RelightModule


def build_model_config(args) -> dict:
    """Network config: the named --preset layout, --width/--depth when given, the ablation flags.

    geo-* presets build the geometry-first GeometryNet (model.networks.geometry), the
    others RelightNet."""
    lambertian = args.lambertian
    if args.preset in GEOMETRY_PRESETS:
        layout = dict(GEOMETRY_PRESETS[args.preset])
        for name in ("width", "depth"):
            if getattr(args, name) is not None:
                layout[name] = getattr(args, name)
        extra = {"body_prior": True} if args.body_prior else {}
        if args.fit_stride != 1:
            extra["fit_stride"] = args.fit_stride
        if args.front_facing:
            extra["front_facing"] = True
        if args.depth_head:
            extra["depth_head"] = True
        return dict(arch=GEOMETRY, sh_order=args.order, **layout, **extra)
    layout = dict(PRESETS[args.preset])
    for name in ("width", "depth"):
        if getattr(args, name) is not None:
            layout[name] = getattr(args, name)
    return dict(sh_order=args.order, **layout,
                with_residual=not (args.no_residual or lambertian), with_matte=not args.no_matte,
                decomposition=not (args.no_decomposition or lambertian), tstar=args.tstar)


def loss_weights_from_args(args) -> dict:
    """Loss weights by name: the model's defaults (LossWeights for RelightNet,
    model.networks.geometry.GEOMETRY_LOSS_WEIGHTS for the geometry-first model) with each
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


def parse_args(argv=None, check_pack: bool = True):
    """model.train's options, checked; `check_pack` False leaves --from-pack's file unread (it may
    not exist yet: model.campaign compares the options of its runs before it packs)."""
    p = argparse.ArgumentParser(prog="python -m model.train", description=__doc__.splitlines()[0])
    p.add_argument("--data", nargs="+",
                   help="dataset folder(s) of scene_NNNNNN.exr/.json (farm runs with different --first)")
    p.add_argument("--from-pack", nargs="+", default=None, metavar="PACK.npz",
                   help="train from training packs instead of --data, their scenes one after another "
                        "(model.samples.training_pack, or compact ones: no scene "
                        "files, no Blender; --size and --order default to the pack's)")
    p.add_argument("--max-scenes", type=int, default=None, metavar="N",
                   help="use only the first N scenes of --data (folders in order, scenes by index) or of the packs: "
                        "data-size curves without copying data")
    p.add_argument("--out", required=True, help="output folder (checkpoints, final weights, logs)")
    p.add_argument("--steps", type=int, default=10000)
    p.add_argument("--batch", type=int, default=4)
    p.add_argument("--accumulate", type=int, default=1,
                   help="gradient accumulation: effective batch = batch x accumulate (paper: 16)")
    p.add_argument("--size", type=int, default=None, help="training crop size (multiple of 2**depth; default 256)")
    p.add_argument("--preset", choices=tuple(PRESETS) + tuple(GEOMETRY_PRESETS), default="default",
                   help="network layout: model.networks.network.PRESETS (the paper's decomposition) or "
                        "model.networks.geometry.GEOMETRY_PRESETS (geometry-first); --width/--depth override it")
    p.add_argument("--width", type=int, default=None)
    p.add_argument("--depth", type=int, default=None)
    p.add_argument("--order", type=int, default=None, help="SH order N (paper: 4; Kanamori-Endo: 2; default 4)")
    p.add_argument("--lr", type=float, default=5e-5)
    p.add_argument("--lr-schedule", choices=("constant", "cosine"), default="constant",
                   help="cosine: decay to 5%% of --lr over --steps after the warm-up")
    p.add_argument("--warmup", type=int, default=0, help="linear warm-up steps")
    p.add_argument("--schedule-steps", type=int, default=None, metavar="N",
                   help="the learning-rate schedule's length (default --steps): a run stopped early on its schedule")
    p.add_argument("--init", default=None,
                   help="start from these .safetensors weights (same layout), e.g. a lower-resolution run")
    p.add_argument("--frozen-norm", action="store_true",
                   help="BatchNorm keeps its running statistics while training (needed to fine-tune "
                        "weights recovered from an ONNX graph: python -m export.weights_from_onnx)")
    p.add_argument("--weight-decay", type=float, default=1e-2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--val-fraction", type=float, default=0.1, help="fraction of bodies held out for validation")
    p.add_argument("--val-every", type=int, default=500, help="validate every N steps")
    p.add_argument("--ckpt-every", type=int, default=500, help="write checkpoints/last.ckpt every N steps")
    p.add_argument("--log-every", type=int, default=10, help="log the training losses every N steps (metrics.csv)")
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
    p.add_argument("--light-mix", type=float, default=0.0, metavar="P",
                   help="chance that an extra light is two training lights mixed, turned and tilted "
                        "(model.samples.data_augment.random_mixed_light; exact for PRT images; 0: off)")
    p.add_argument("--light-maps", type=int, default=None, metavar="K",
                   help="study: only K of the training HDR maps light the samples (a fixed, nested choice: "
                        "model.samples.data_splits.first_maps); default: all")
    p.add_argument("--exposure-jitter", type=float, default=0.0, metavar="SIGMA",
                   help="scale the input light and image by 2^N(0, SIGMA^2), albedo target unchanged "
                        "(exposure augmentation, exact; 0: off)")
    p.add_argument("--capture", action=argparse.BooleanOptionalAction, default=False,
                   help="photo-like capture of the input (model/samples/capture.py: real backgrounds, white balance, "
                        "exposure, blur, noise, JPEG); off by default, measured in docs/EVALUATION.md")
    p.add_argument("--no-presets", action="store_true", help="extra lights from scene lights only")
    p.add_argument("--fit-stride", type=int, default=1, choices=(1, 2, 3, 4),
                   help="geometry-first model: fit the photo's light on every Nth pixel of each row and "
                        "column (2: a quarter of the pixels, a quarter of the fit's cost)")
    p.add_argument("--front-facing", action="store_true",
                   help="geometry-first model: normals turned toward the camera (y <= 0), as every visible "
                        "surface's is")
    p.add_argument("--body-prior", action="store_true",
                   help="geometry-first model: the unclothed body's normal and coverage as 4 more input "
                        "channels (scenes need the farm's body pass)")
    # default None, not False: a campaign started before the option compares its recorded settings
    # with these (model.campaign.settle_settings), and an absent key reads as None
    p.add_argument("--depth-head", action="store_true", default=None,
                   help="geometry-first model: a depth output trained from the farm's depth pass "
                        "(scale-and-shift-invariant; model.networks.depth_loss)")
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
    if (args.data is None) == (args.from_pack is None):
        p.error("give the scenes as --data DIR [DIR ...] or as --from-pack PACK.npz (one of them)")
    packed = {}
    if args.from_pack is not None and check_pack:
        from model.samples.training_pack import read_manifest

        try:
            packed = read_manifest(args.from_pack[0])
        except ValueError as exc:
            p.error(str(exc))
    if args.from_pack is not None and args.pack is not None:
        p.error("--pack crops --data's scenes; --from-pack is already cropped")
    args.size = args.size if args.size is not None else packed.get("size", 256)
    args.order = args.order if args.order is not None else packed.get("order", 4)
    for name in ("steps", "batch", "accumulate", "size", "width", "depth", "val_every", "ckpt_every",
                 "log_every", "cache_scenes", "schedule_steps"):
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
    if args.depth_head and args.preset not in GEOMETRY_PRESETS:
        p.error("--depth-head needs a geometry-first preset (--preset geo-small, geo-default or geo-large)")
    if not (args.lr > 0 and math.isfinite(args.lr)):
        p.error("--lr must be a positive number")
    return args


def check_checkpoint(path: Path) -> dict:
    """The Lightning checkpoint at `path`, loaded as Lightning will (weights_only=True); a damaged or
    truncated file (a disk that filled, a copy cut short) raises ValueError naming it, so that it
    is never resumed from in part."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises RuntimeError, EOFError, UnpicklingError... on a bad file
        raise ValueError(f"checkpoint {path} is damaged or truncated ({type(exc).__name__}: "
                         f"{str(exc).splitlines()[0] if str(exc) else 'no detail'}); delete it to train "
                         "again from step 0") from None
    if not isinstance(state, dict) or not {"state_dict", "global_step", "optimizer_states"} <= set(state):
        raise ValueError(f"checkpoint {path} is not a training checkpoint of model.train (no weights, step "
                         "or optimizer state); delete it to train again from step 0")
    return state


def train(args) -> Path:
    """Run training; returns the final weights path."""
    warnings.filterwarnings("ignore", ".*does not have many workers.*")
    warnings.filterwarnings("ignore", ".*number of training batches.*")
    warnings.filterwarnings("ignore", ".*LeafSpec.*")  # lightning 2.6 vs torch 2.13 internals
    if args.init and "recovered_from" in read_metadata(args.init) and not args.frozen_norm:
        raise ValueError(f"--init {args.init}: weights recovered from an ONNX graph carry their BatchNorm "
                         "folded into the convolutions; train them with --frozen-norm")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    L.seed_everything(args.seed, workers=True, verbose=False)
    if args.threads > 0:
        torch.set_num_threads(args.threads)

    training_pack = None
    if args.from_pack is not None:
        from model.samples.packs import read_training_packs

        training_pack = read_training_packs(args.from_pack, args.max_scenes)
    weights = loss_weights_from_args(args)
    data = SceneDataModule(
        args.data, training_pack=training_pack, size=args.size, order=args.order, batch=args.batch, seed=args.seed, max_scenes=args.max_scenes,
        val_fraction=args.val_fraction, padding=args.padding, workers=args.workers, cache_scenes=args.cache_scenes,
        pack=args.pack, presets=not args.no_presets,
        augment=dict(extra_light_prob=args.extra_light_prob, mask_prob=args.mask_prob, flip_prob=args.flip_prob,
                     light_tint=args.light_tint, light_mix=args.light_mix, exposure_jitter=args.exposure_jitter,
                     capture=args.capture,
                     lambertian=args.lambertian, body_prior=args.body_prior, depth=bool(args.depth_head),
                     sun_light=weights.get("sun_response", 0.0) > 0))
    if args.light_maps is not None:
        bank = [name for name, _ in data.preset_lights()]
        maps = first_maps(training_map_names(data.train_paths, bank), args.light_maps)
        data.augment["light_maps"] = maps
        print(f"model.train: {len(maps)} training maps: {', '.join(sorted(maps))}", file=sys.stderr)
    # the Trainer's validation settings depend on whether there are validation pairs
    data.prepare_data()
    data.setup("fit")

    module = RelightModule(build_model_config(args), weights, args.lr, args.weight_decay,
                           args.lr_schedule, args.warmup, args.schedule_steps or args.steps,
                           frozen_norm=args.frozen_norm)
    if args.init:  # the same layout, or the depth head added to it (checkpoint.init_weights)
        init_weights(module.model, load_model(args.init), args.init)
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
        enable_model_summary=False, log_every_n_steps=min(args.log_every, args.steps),
        val_check_interval=args.val_every if data.has_validation else None,
        check_val_every_n_epoch=None, num_sanity_val_steps=0, deterministic=False,
        limit_val_batches=1.0 if data.has_validation else 0,
    )
    resume_from = None
    if args.resume:
        last = ckpt_dir / "last.ckpt"
        if not last.is_file():
            raise ValueError(f"--resume: no checkpoint at {last}")
        check_checkpoint(last)
        resume_from = str(last)
        # the loader continues where the batches stopped (train_data.EpochShuffleSampler.resume_at)
        warnings.filterwarnings("ignore", ".*resuming from a checkpoint that ended before the epoch ended.*")
    trainer.fit(module, datamodule=data, ckpt_path=resume_from, weights_only=True)
    trainer.save_checkpoint(ckpt_dir / "last.ckpt", weights_only=False)  # full state, for --resume

    record = {"seed": args.seed, "steps": int(trainer.global_step),
              "loss_weights": weights,
              "data": [str(d) for d in args.data] if args.data else [str(p) for p in args.from_pack],
              "pack_source": training_pack.manifest["source"] if training_pack is not None else None,
              "train_scenes": len(data.train_paths),
              "val_scenes": len(data.val_paths), "lambertian": args.lambertian,
              "init": str(args.init) if args.init else None, "args": {k: v for k, v in vars(args).items()}}
    if data.augment.get("light_maps") is not None:
        record["light_maps"] = sorted(data.augment["light_maps"])
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
