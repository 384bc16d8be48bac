"""Save and load RelightNet weights as safetensors + a JSON config (no pickle).

The config travels twice: inside the safetensors header metadata (so one file
is enough) and as a `<stem>.json` sidecar for people and tools to read.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import torch
from safetensors import safe_open
from safetensors.torch import save_file

from model.networks.network import RelightNet
from relight.files.fileio import atomic_path, atomic_write_text, file_sha256

FORMAT = "relightnet/1"
CONFIG_KEYS = ("sh_order", "width", "depth", "with_residual", "with_matte", "decomposition", "tstar",
               "decoder_width", "full_res_convs", "shared_parts", "separable")


def save_model(model: RelightNet, path: str | os.PathLike, extra: dict | None = None) -> Path:
    """Write `path` (.safetensors) and its `.json` sidecar atomically; return the weights path."""
    path = Path(path)
    if path.suffix != ".safetensors":
        raise ValueError(f"save_model: path must end in .safetensors, got {path}")
    meta = {"format": FORMAT, "config": model.config(), **(extra or {})}
    tensors = {k: v.detach().to("cpu").contiguous() for k, v in model.state_dict().items()}
    header = {"relightnet": json.dumps(meta, sort_keys=True)}
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path, ".safetensors") as tmp:
        save_file(tensors, str(tmp), metadata=header)
    sidecar = path.with_suffix(".json")
    text = json.dumps(meta, indent=2, sort_keys=True) + "\n"
    atomic_write_text(sidecar, text)
    return path


def read_metadata(path: str | os.PathLike) -> dict:
    """The JSON metadata stored in a checkpoint's safetensors header."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"checkpoint not found: {path}")
    try:
        with safe_open(str(path), framework="pt") as f:
            header = f.metadata() or {}
    except Exception as exc:  # safetensors raises its own error types on corrupt files
        raise ValueError(f"not a safetensors checkpoint: {path} ({exc})") from None
    if "relightnet" not in header:
        raise ValueError(f"{path}: safetensors file has no RelightNet config")
    meta = json.loads(header["relightnet"])
    if meta.get("format") != FORMAT:
        raise ValueError(f"{path}: unknown checkpoint format {meta.get('format')!r}")
    return meta


def build_network(config: dict) -> torch.nn.Module:
    """The network a checkpoint config describes: GeometryNet when config["arch"] is
    "geometry", else RelightNet (checkpoints from before the geometry-first model
    have no "arch")."""
    from model.networks.geometry import ARCH as GEOMETRY, GeometryNet

    config = dict(config)
    if config.pop("arch", None) == GEOMETRY:
        return GeometryNet(**config)
    unknown = set(config) - set(CONFIG_KEYS)
    if unknown:
        raise ValueError(f"unknown config keys {sorted(unknown)}")
    return RelightNet(**config)


def load_model(path: str | os.PathLike, device: str | torch.device = "cpu") -> torch.nn.Module:
    """Rebuild the network from a checkpoint written by save_model, in eval mode."""
    meta = read_metadata(path)
    try:
        model = build_network(meta["config"])
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: {exc}") from None
    from safetensors.torch import load_file

    state = load_file(str(path), device=str(device))
    missing, unexpected = model.load_state_dict(state, strict=False)
    if missing or unexpected:
        raise ValueError(f"{path}: weights do not match config (missing {missing[:3]}, "
                         f"unexpected {unexpected[:3]})")
    return model.to(device).eval()


def init_weights(model: torch.nn.Module, start: torch.nn.Module, where) -> None:
    """`model` given `start`'s weights (model.train --init): the same layout, or a geometry-first
    layout that adds the depth head to `start`'s (issue 45: the head trained onto a shipped model);
    then the geometry head's first five output channels come from `start` and the depth channel
    keeps its fresh initialisation. Any other difference raises ValueError naming `where`."""
    ours, theirs = model.config(), start.config()
    if ours == theirs:
        model.load_state_dict(start.state_dict())
        return
    if {**theirs, "depth_head": True} != ours:
        raise ValueError(f"--init {where}: its layout {theirs} differs from this run's {ours}")
    state = model.state_dict()
    for name, value in start.state_dict().items():
        if name.startswith("geometry_gen.head.") and value.shape[0] == state[name].shape[0] - 1:
            state[name] = state[name].clone()
            state[name][:-1] = value
        else:
            state[name] = value
    model.load_state_dict(state)


def interpolate_models(start_path, end_path, weight: float) -> tuple[torch.nn.Module, dict]:
    """The network whose every float weight and BatchNorm statistic is (1 - weight) * start's +
    weight * end's (integer buffers, BatchNorm's batch count, end's), with the metadata to save it
    under: end's, plus where it came from. Both checkpoints must have one config (a fine-tune and
    the weights it started from: issue 45's warm restarts lie on a path along which the relit
    error changes smoothly, docs/EVALUATION.md). ValueError naming the files otherwise."""
    weight = float(weight)
    if not 0.0 <= weight <= 1.0:
        raise ValueError(f"the weight of {end_path} must be in [0, 1], got {weight}")
    start, end = load_model(start_path), load_model(end_path)
    if start.config() != end.config():
        raise ValueError(f"{start_path} and {end_path} have different configs: {start.config()} against "
                         f"{end.config()}")
    ends = end.state_dict()
    mixed = {name: (torch.lerp(value, ends[name], weight) if value.is_floating_point() else ends[name])
             for name, value in start.state_dict().items()}
    end.load_state_dict(mixed)
    meta = read_metadata(end_path)
    meta.pop("format", None)
    meta.pop("config", None)
    meta["interpolated"] = {"start": str(start_path), "end": str(end_path), "end_weight": weight,
                            "start_sha256": file_sha256(start_path), "end_sha256": file_sha256(end_path)}
    return end.eval(), meta
