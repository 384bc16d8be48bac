"""python -m export.weights_from_onnx MODEL.onnx --out WEIGHTS.safetensors

The inverse of export: a shipped graph's weights back into the torch network its metadata
describes, so a release can be fine-tuned when only its ONNX file is kept (the registry ships
graphs, not checkpoints).

The exporter folds each BatchNorm into the convolution before it, so the statistics are gone;
the recovered network carries the folded weights in the convolution and an identity BatchNorm
(mean 0, variance 1 - eps, scale 1) whose shift is the folded bias. In eval mode it computes
what the graph computes; train it with `model.train --frozen-norm`, which keeps those
statistics (batch statistics would undo the folding).

Which graph tensor is which parameter is found, not assumed: the same network with distinct
random values is exported by the same code and its initializers are paired with the shipped
graph's by position in the node list, then with the torch tensors by value.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import numpy_helper

from export.onnx_export import PARITY_TOLERANCE, export_onnx, fp32_parity, read_metadata


def _initializer_uses(model: onnx.ModelProto) -> list[tuple[str, int, str]]:
    """(op type, input slot, initializer name) for every initializer input, in node order."""
    names = {t.name for t in model.graph.initializer}
    return [(node.op_type, slot, name) for node in model.graph.node
            for slot, name in enumerate(node.input) if name in names]


def _identity_norms(net: torch.nn.Module) -> list[torch.nn.BatchNorm2d]:
    norms = [m for m in net.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    with torch.no_grad():
        for bn in norms:
            bn.running_mean.zero_()
            bn.running_var.fill_(1.0 - bn.eps)
            bn.weight.fill_(1.0)
    return norms


def network_from_onnx(path: str | Path) -> torch.nn.Module:
    """The torch network of the graph at `path`, in eval mode, computing what the graph computes."""
    from model.training.checkpoint import build_network

    try:
        shipped = onnx.load(str(path))
    except Exception as exc:  # protobuf's DecodeError and friends: not an ONNX file
        raise ValueError(f"{path}: not a readable ONNX graph ({type(exc).__name__})") from None
    meta = read_metadata(shipped)
    if "relight.network_config" not in meta:
        raise ValueError(f"{path}: no relight.network_config in its metadata (not a relight model)")
    config = json.loads(meta["relight.network_config"])
    torch.manual_seed(0)
    net = build_network(config).eval()
    norms = _identity_norms(net)
    with torch.no_grad():  # distinct shifts, so a folded bias (the BatchNorm's shift) is found by value
        for bn in norms:
            bn.bias.uniform_(-1.0, 1.0)
    with tempfile.TemporaryDirectory() as tmp:
        probe = onnx.load(str(export_onnx(net, Path(tmp) / "probe.onnx")[0]))
    ours, theirs = _initializer_uses(probe), _initializer_uses(shipped)
    if [(op, slot) for op, slot, _ in ours] != [(op, slot) for op, slot, _ in theirs]:
        raise ValueError(f"{path}: its graph differs from the one this code exports for {config}")
    probe_values = {t.name: numpy_helper.to_array(t) for t in probe.graph.initializer}
    shipped_values = {t.name: numpy_helper.to_array(t) for t in shipped.graph.initializer}
    tensors = {**dict(net.named_parameters()), **{k: v for k, v in net.named_buffers() if v.is_floating_point()}}
    assigned: dict[str, np.ndarray] = {}
    for (_, _, mine), (_, _, given) in zip(ours, theirs):
        value, target = probe_values[mine], shipped_values[given]
        if value.shape != target.shape:
            raise ValueError(f"{path}: initializer {given} is {target.shape}, this code's is {value.shape}")
        if value.dtype.kind != "f" or value.size < 2:
            continue  # shape constants and scalars: not weights
        match = [k for k, t in tensors.items() if tuple(t.shape) == value.shape
                 and np.allclose(t.detach().numpy(), value, rtol=1e-5, atol=1e-7)]
        if len(match) != 1:
            raise ValueError(f"{path}: initializer {given} matches {len(match)} network tensors")
        assigned[match[0]] = target
    with torch.no_grad():
        for name, value in assigned.items():
            tensors[name].copy_(torch.from_numpy(np.array(value, dtype=np.float32)))
    scales = {id(bn.weight) for bn in norms}  # 1 after folding: not in the graph
    missing = [k for k, t in net.named_parameters() if k not in assigned and id(t) not in scales]
    if missing:
        raise ValueError(f"{path}: no graph tensor for {missing[:4]}")
    return net.eval()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m export.weights_from_onnx", description=__doc__.splitlines()[0])
    parser.add_argument("model", help="a relight ONNX graph (relight/models/*.onnx)")
    parser.add_argument("--out", required=True, help="output .safetensors (model.train --init, with --frozen-norm)")
    args = parser.parse_args(argv)
    try:
        from model.training.checkpoint import save_model

        net = network_from_onnx(args.model)
        worst = fp32_parity(net, args.model)
        if not worst <= PARITY_TOLERANCE:
            raise ValueError(f"recovered network differs from the graph by {worst:.3g} (> {PARITY_TOLERANCE})")
        from relight.models import file_sha256

        out = save_model(net, args.out, extra={"recovered_from": {"onnx": str(args.model),
                                                                  "sha256": file_sha256(args.model),
                                                                  "max_abs_diff": worst}})
    except (OSError, ValueError) as exc:
        print(f"export.weights_from_onnx: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {out} (max |torch - onnx| {worst:.2e})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
