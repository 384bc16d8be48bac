"""RelightNet (or, with arch="geometry", GeometryNet) with seeded random weights, exported: for
tests and benchmarks. Not a model anyone should relight with."""

from __future__ import annotations

import os
from pathlib import Path

import torch

from export.onnx_export import export_onnx


def random_relightnet(seed: int = 0, **config):
    """A RelightNet(**config) whose weights and BatchNorm statistics are seeded random
    (non-trivial running stats, so BatchNorm folding is exercised); config["arch"] == "geometry":
    a GeometryNet of the rest of config (e.g. depth_head=True, issue 45) instead."""
    from model.networks.network import RelightNet

    torch.manual_seed(seed)
    if config.get("arch") == "geometry":
        from model.networks.geometry import GeometryNet

        return random_norm_statistics(GeometryNet(**{k: v for k, v in config.items() if k != "arch"}))
    return random_norm_statistics(RelightNet(**config))


def random_norm_statistics(net: torch.nn.Module) -> torch.nn.Module:
    """`net` in eval mode with every BatchNorm's statistics and affine terms drawn at random (from
    torch's generator), as training leaves them: what folding them into the convolutions must keep."""
    with torch.no_grad():
        for module in net.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.running_mean.uniform_(-0.2, 0.2)
                module.running_var.uniform_(0.5, 2.0)
                module.weight.uniform_(0.5, 1.5)
                module.bias.uniform_(-0.2, 0.2)
    return net.eval()


def export_random_model(out: str | os.PathLike, seed: int = 0, **config) -> tuple[Path, str, torch.nn.Module]:
    """Export random_relightnet(seed, **config) to `out` (+ .sha256); returns (path, sha256, net)."""
    net = random_relightnet(seed, **config)
    path, digest = export_onnx(net, out, training_data="none: seeded random weights (tests/benchmarks)")
    return path, digest, net
