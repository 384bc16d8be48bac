"""The LightningModule of `python -m model.train`: the network, its losses (RelightNet's
or the geometry-first model's), validation PSNR, AdamW with a warm-up and an optional
cosine decay (lr_factor)."""

from __future__ import annotations

import math

import lightning as L
import torch

from model.networks import sh_torch
from model.training.checkpoint import build_network
from model.networks.geometry import ARCH as GEOMETRY, geometry_losses
from model.training.losses import LossWeights, relight_losses


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


def render_prediction(pred: dict, light: torch.Tensor, tstar: bool) -> torch.Tensor:
    """albedo * (T . L) + E . L, or T* . L for the T* ablation."""
    if tstar:
        return sh_torch.shading_tstar(pred["transport"], light)
    return sh_torch.render(pred["albedo"], pred["transport"], pred["residual"], light)


class RelightModule(L.LightningModule):
    """`model_config` builds the network (model.training.checkpoint.build_network); `weights` are the loss
    weights by name (model.train.loss_weights_from_args)."""

    def __init__(self, model_config: dict, weights: dict, lr: float, weight_decay: float,
                 schedule: str = "constant", warmup: int = 0, total_steps: int = 1,
                 frozen_norm: bool = False):
        super().__init__()
        self.save_hyperparameters()  # plain dicts and floats: loadable with weights_only=True
        self.model = build_network(model_config)
        self.geometry = model_config.get("arch") == GEOMETRY
        self.weights = dict(weights) if self.geometry else LossWeights.from_dict(weights)

    def train(self, mode: bool = True):
        """With `frozen_norm`, BatchNorm keeps its running statistics in training too (weights
        recovered from an ONNX graph carry their statistics folded into the convolutions:
        export.weights_from_onnx); its scale and shift still learn."""
        super().train(mode)
        if self.hparams.get("frozen_norm"):
            for m in self.model.modules():
                if isinstance(m, torch.nn.modules.batchnorm._BatchNorm):
                    m.eval()
        return self

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
