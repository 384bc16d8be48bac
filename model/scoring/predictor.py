"""A model under evaluation: a torch checkpoint or an ONNX file, run on [B, 3, H, W] float32
inputs, with the outputs of docs/ARCHITECTURE.md ("Network I/O")."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

OUTPUTS = ("albedo", "transport", "residual", "light", "alpha")


class Predictor:
    """Runs a checkpoint (torch, eval mode) or an ONNX file on [B,3,H,W] float32 inputs.

    An ONNX file opens through relight.models.session.ModelSession, as in the runtime: its
    SHA-256 (registry or .sha256 file beside it), metadata and graph names are checked."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if not self.path.is_file():
            raise ValueError(f"model not found: {self.path}")
        if self.path.suffix == ".onnx":
            from relight.models.session import ModelSession
            from relight.lighting.sh import num_coeffs

            self.session = ModelSession(self.path)
            self.n_coeffs = num_coeffs(self.session.sh_order)
            from relight.network.level import METADATA_KEY, LevelPrior

            # the model's level prior (relight.network.level) is part of what it answers, as in the runtime
            self.level_prior = LevelPrior.from_metadata(self.session.metadata.get(METADATA_KEY))
            t = self.session.output_channels("transport")
            # the T* ablation exports 3n transport channels (docs/model.md)
            self.tstar = self.n_coeffs > 1 and t == 3 * self.n_coeffs
            self.model = None
        elif self.path.suffix == ".safetensors":
            from model.training.checkpoint import load_model

            self.model = load_model(self.path)
            self.tstar = self.model.tstar
            self.n_coeffs = self.model.n
            self.level_prior = None  # a checkpoint has none: it is calibrated on the exported model
        else:
            raise ValueError(f"model must be a .safetensors checkpoint or an .onnx file, got {self.path.name}")

    @property
    def body_prior(self) -> bool:
        """Whether the model takes the body prior's channels after the photo's (model.samples.data.body_input)."""
        return bool(getattr(self.model, "body_prior", False))

    @property
    def has_depth(self) -> bool:
        """Whether the model has the depth head (issue 45): its answers then carry "depth" [B, 1, H, W]."""
        if self.model is not None:
            return bool(getattr(self.model, "depth_head", False))
        return "depth" in self.session.outputs

    @property
    def order(self) -> int | None:
        return None if self.n_coeffs is None else int(round(self.n_coeffs ** 0.5)) - 1

    def __call__(self, image: np.ndarray) -> dict[str, np.ndarray]:
        if not self.body_prior:
            image = image[:, :3]  # inputs may carry a body prior that this model does not take
        if self.model is not None:
            x = torch.from_numpy(image)
            self.model.check_input(x)
            with torch.no_grad():
                out = self.model(x)
            return {k: out[k].numpy() for k in OUTPUTS + (("depth",) if self.has_depth else ())}
        try:
            out = self.session.run(image)
        except Exception as exc:  # onnxruntime raises its own types (e.g. a size the graph rejects)
            raise ValueError(f"{self.path.name} failed on an input of shape {image.shape}: {exc}") from None
        out = {k: out[k] for k in OUTPUTS + (("depth",) if self.has_depth else ())}
        if self.level_prior is not None and not np.any(out["residual"]):
            out = _with_level_prior(self.level_prior, image, out)
        return out


def _with_level_prior(prior, image: np.ndarray, out: dict) -> dict:
    """The outputs with each image's light divided by the prior's gains and its albedo
    re-derived (relight.network.level.apply on the runtime's Decomposition does the same)."""
    from relight.network.refine import albedo_from_input

    light, albedo = out["light"].copy(), out["albedo"].copy()
    for b in range(image.shape[0]):
        transport = out["transport"][b].transpose(1, 2, 0)
        alpha = out["alpha"][b, 0]
        gains = prior.gains(transport, light[b], alpha)
        light[b] = light[b] / gains[None, :]
        albedo[b] = albedo_from_input(image[b].transpose(1, 2, 0), alpha, transport, light[b]).transpose(2, 0, 1)
    return {**out, "light": light, "albedo": albedo}
