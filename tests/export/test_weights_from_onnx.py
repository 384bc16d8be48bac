"""export.weights_from_onnx: a graph's weights back into torch (BatchNorm folded), and
model.train --frozen-norm, which fine-tunes them without undoing the folding."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from export.onnx_export import export_onnx, max_abs_diff, onnx_outputs, torch_outputs
from export.random_model import random_norm_statistics
from export.weights_from_onnx import PARITY_TOLERANCE, main, network_from_onnx
from model.networks.geometry import GeometryNet
from model.training.checkpoint import load_model, read_metadata
from model.training.train_module import RelightModule

CONFIG = dict(sh_order=2, width=4, depth=2, decoder_width=4, fit_stride=2, front_facing=True)


def _trained_looking(seed: int) -> GeometryNet:
    """A GeometryNet whose BatchNorms have non-trivial statistics and affine terms, so the folding
    (and recovering through it) is exercised."""
    torch.manual_seed(seed)
    return random_norm_statistics(GeometryNet(**CONFIG))


@pytest.fixture(scope="module")
def graph(tmp_path_factory):
    net = _trained_looking(5)
    path, _ = export_onnx(net, tmp_path_factory.mktemp("from_onnx") / "geo.onnx")
    return path, net


def _input(h=32, w=48, seed=0):
    return np.random.default_rng(seed).uniform(-1, 1, (1, 3, h, w)).astype(np.float32)


def test_recovered_network_computes_what_the_graph_computes(graph):
    path, original = graph
    net = network_from_onnx(path)
    assert net.config() == original.config()
    for image in (_input(), _input(48, 32, seed=1)):
        # both sides are float32 sums in different orders: export's own parity bound (tests/export/test_export.py)
        diff = max_abs_diff(torch_outputs(net, image), onnx_outputs(path, image))
        assert max(diff.values()) < PARITY_TOLERANCE, diff
        # and the original torch network, whose BatchNorm was not folded, agrees to the same bound
        diff = max_abs_diff(torch_outputs(net, image), torch_outputs(original, image))
        assert max(diff.values()) < PARITY_TOLERANCE, diff


def test_recovered_batchnorms_are_identities_carrying_the_folded_shift(graph):
    net = network_from_onnx(graph[0])
    norms = [m for m in net.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    assert norms
    for bn in norms:
        assert torch.all(bn.running_mean == 0) and torch.all(bn.weight == 1)
        assert torch.allclose(bn.running_var + bn.eps, torch.ones_like(bn.running_var))
    assert any(bn.bias.abs().max() > 0.01 for bn in norms)  # the shifts came from the graph


def test_the_command_writes_a_checkpoint_that_model_train_reads(graph, tmp_path, capsys):
    out = tmp_path / "recovered.safetensors"
    assert main([str(graph[0]), "--out", str(out)]) == 0
    assert "max |torch - onnx|" in capsys.readouterr().out
    meta = read_metadata(out)
    assert meta["recovered_from"]["max_abs_diff"] < PARITY_TOLERANCE
    image = _input()
    diff = max_abs_diff(torch_outputs(load_model(out), image), onnx_outputs(graph[0], image))
    assert max(diff.values()) < PARITY_TOLERANCE


def test_a_graph_of_another_layout_is_refused(tmp_path, capsys):
    bad = tmp_path / "not_relight.onnx"
    bad.write_bytes(b"not an onnx file")
    assert main([str(bad), "--out", str(tmp_path / "w.safetensors")]) == 2
    assert "export.weights_from_onnx: error" in capsys.readouterr().err
    assert not (tmp_path / "w.safetensors").exists()


def test_frozen_norm_keeps_running_statistics_in_training(graph):
    net = network_from_onnx(graph[0])
    for frozen in (False, True):
        module = RelightModule({**net.config()}, {}, 1e-3, 0.0, frozen_norm=frozen)
        module.model.load_state_dict(net.state_dict())
        module.train()
        norms = [m for m in module.model.modules() if isinstance(m, torch.nn.BatchNorm2d)]
        assert all(m.training != frozen for m in norms)
        assert module.model.encoder.training  # everything else trains
        with torch.no_grad():
            out = module.model(torch.from_numpy(_input()))["albedo"].numpy()
        reference = torch_outputs(net, _input())["albedo"]
        if frozen:  # a forward pass in training mode is the eval network's
            assert np.max(np.abs(out - reference)) < PARITY_TOLERANCE
        else:  # batch statistics replace the folded ones: a different network
            assert np.max(np.abs(out - reference)) > 10 * PARITY_TOLERANCE
        assert torch.all(norms[0].running_mean == 0) == frozen


def test_model_train_refuses_recovered_weights_without_frozen_norm(graph, tmp_path, capsys):
    from model.train import main as train_main

    weights = tmp_path / "recovered.safetensors"
    assert main([str(graph[0]), "--out", str(weights)]) == 0
    code = train_main(["--data", str(tmp_path / "none"), "--out", str(tmp_path / "run"), "--preset", "geo-small",
                       "--init", str(weights), "--steps", "1"])
    assert code == 2
    assert "--frozen-norm" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()  # refused before anything was written
