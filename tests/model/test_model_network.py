"""RelightNet: shapes, ranges, gradients, BatchNorm eval determinism, checkpoints, ablations."""

import json

import numpy as np
import pytest
import torch

from model.training.checkpoint import load_model, read_metadata, save_model
from model.training.checkpoint import CONFIG_KEYS
from model.networks.network import ARCH_DEFAULTS, PAPER_CONFIG, PRESETS, RelightNet

TINY = dict(width=4, depth=2)
# the paper's heavy layout (two generators per signed map, wide decoders, two
# full-resolution convs) at TINY size
TINY_PAPER = {**PAPER_CONFIG, **TINY}


pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def _input(b=2, h=16, w=16, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(b, 3, h, w, generator=g) * 2 - 1


@pytest.mark.parametrize("flags", [
    {}, {"with_residual": False}, {"decomposition": False}, {"sh_order": 2},
    {"with_matte": False}, {"tstar": True}, {"separable": True}, {"decoder_width": 2},
    {"shared_parts": False, "decoder_width": None, "full_res_convs": 2},
    {"shared_parts": False, "decoder_width": None, "full_res_convs": 2, "tstar": True},
])
def test_shapes_ranges_and_parts(flags):
    torch.manual_seed(0)
    model = RelightNet(**TINY, **flags).eval()
    n = (model.sh_order + 1) ** 2
    with torch.no_grad():
        out = model(_input(h=16, w=24))
    n_t = 3 * n if flags.get("tstar") else n
    assert out["albedo"].shape == (2, 3, 16, 24)
    assert out["transport"].shape == (2, n_t, 16, 24)
    assert out["residual"].shape == (2, n, 16, 24)
    assert out["light"].shape == (2, n, 3)
    assert out["alpha"].shape == (2, 1, 16, 24)
    for name, value in out.items():
        assert torch.isfinite(value).all(), name
    for name in ("albedo", "alpha"):
        assert out[name].min() >= 0 and out[name].max() <= 1
    # the parts reconstruct the signed maps exactly and are non-negative
    for base in ("transport", "residual", "light"):
        assert out[base + "_pos"].min() >= 0 and out[base + "_neg"].min() >= 0
        torch.testing.assert_close(out[base + "_pos"] - out[base + "_neg"], out[base], rtol=0, atol=0)
    if flags.get("with_residual") is False or flags.get("tstar"):
        assert torch.count_nonzero(out["residual"]) == 0


@pytest.mark.parametrize("shared_parts", [True, False])
def test_gradients_reach_every_head(shared_parts):
    torch.manual_seed(0)
    model = RelightNet(**TINY, shared_parts=shared_parts).train()
    out = model(_input())
    loss = sum(v.float().square().mean() for v in out.values())
    loss.backward()
    parts = (["gen_parts.head"] if shared_parts else ["gen_pos.head", "gen_neg.head"])
    heads = {"albedo_gen.head", "matte_head", "light_decoder.fc", "encoder.stem"}
    heads |= {f"{dec}.{part}" for dec in ("transport_decoder", "residual_decoder") for part in parts}
    grads = {name: p.grad for name, p in model.named_parameters()}
    for head in heads:
        got = [g for name, g in grads.items() if name.startswith(head)]
        assert got, head
        assert all(g is not None and torch.isfinite(g).all() and g.abs().sum() > 0 for g in got), head
    # every parameter of the network receives a gradient
    missing = [name for name, g in grads.items() if g is None or g.abs().sum() == 0]
    assert not missing, missing


def test_eval_output_independent_of_batch_companions():
    """BatchNorm in eval mode: an image's output must not depend on the rest of the batch."""
    torch.manual_seed(0)
    model = RelightNet(**TINY)
    model.train()
    with torch.no_grad():  # move running statistics away from their init
        for i in range(3):
            model(_input(b=4, seed=10 + i))
    model.eval()
    x = _input(b=1, seed=1)
    with torch.no_grad():
        alone = model(x)
        batch = model(torch.cat([x, _input(b=3, seed=2) * 5.0]))
    for name in alone:
        # same arithmetic per sample; only conv algorithm choice may differ: float32 round-off
        torch.testing.assert_close(batch[name][:1], alone[name], rtol=1e-5, atol=1e-5)


def test_size_multiple_and_bad_input():
    model = RelightNet(width=4, depth=3)
    assert model.size_multiple == 8
    with pytest.raises(ValueError, match="multiples of 8"):
        model.check_input(torch.zeros(1, 3, 12, 16))
    with pytest.raises(ValueError, match=r"\[B,3,H,W\]"):
        model.check_input(torch.zeros(1, 4, 16, 16))
    with pytest.raises(ValueError):
        RelightNet(depth=0)


def test_checkpoint_roundtrip(tmp_path):
    torch.manual_seed(0)
    model = RelightNet(**TINY, sh_order=2, with_residual=False).eval()
    path = save_model(model, tmp_path / "net.safetensors", extra={"seed": 7})
    sidecar = json.loads((tmp_path / "net.json").read_text())
    assert sidecar["config"] == model.config() and sidecar["seed"] == 7
    assert read_metadata(path)["config"] == model.config()
    loaded = load_model(path)
    x = _input()
    with torch.no_grad():
        a, b = model(x), loaded(x)
    for name in a:
        torch.testing.assert_close(a[name], b[name], rtol=0, atol=0)
    # no temp files left behind
    assert sorted(p.name for p in tmp_path.iterdir()) == ["net.json", "net.safetensors"]


def test_checkpoint_rejects_garbage(tmp_path):
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="not a safetensors checkpoint"):
        load_model(bad)
    with pytest.raises(ValueError, match="not found"):
        load_model(tmp_path / "missing.safetensors")
    with pytest.raises(ValueError, match=".safetensors"):
        save_model(RelightNet(**TINY), tmp_path / "net.pt")


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # torch's legacy (TorchScript) exporter
def test_onnx_export_matches_torch(tmp_path):
    """Every variant stays exportable at opset 17 (dynamic H, W)."""
    import onnxruntime as ort
    torch.manual_seed(0)
    for flags in ({}, {"decomposition": False, "with_residual": False}, {"tstar": True},
                  {"separable": True}, TINY_PAPER):
        model = RelightNet(**{**TINY, **flags}).eval()
        path = tmp_path / "m.onnx"
        names = list(model(_input(b=1)).keys())
        torch.onnx.export(model, (_input(b=1),), str(path), opset_version=17, input_names=["image"],
                          output_names=names, dynamic_axes={"image": {0: "b", 2: "h", 3: "w"}},
                          dynamo=False)
        x = _input(b=1, h=24, w=32, seed=3)
        got = ort.InferenceSession(str(path)).run(None, {"image": x.numpy()})
        with torch.no_grad():
            ref = model(x)
        for name, value in zip(names, got):
            np.testing.assert_allclose(value, ref[name].numpy(), rtol=1e-4, atol=1e-5)


def test_shared_parts_split_the_head_channels():
    """With shared_parts one generator's 2n-channel head holds T+ (first n) and |T-| (last n)."""
    torch.manual_seed(0)
    model = RelightNet(**TINY).eval()
    assert model.transport_decoder.gen_parts.head.out_channels == 2 * model.n
    x = _input()
    with torch.no_grad():
        out = model(x)
        feats = model.encoder(x)
        dec = model.transport_decoder
        raw = dec.gen_parts(dec.res_block(feats[-1]), feats)
    torch.testing.assert_close(out["transport_pos"], raw[:, : model.n].abs(), rtol=0, atol=0)
    torch.testing.assert_close(out["transport_neg"], raw[:, model.n:].abs(), rtol=0, atol=0)


def test_paper_config_has_the_original_layout():
    """PAPER_CONFIG rebuilds the heavy network: 21,610,334 weights, as before the efficiency
    parameters existed (and the docs' 21.6 M), with one generator per part."""
    model = RelightNet(**PAPER_CONFIG)
    assert sum(p.numel() for p in model.parameters()) == 21_610_334
    assert hasattr(model.transport_decoder, "gen_neg") and len(model.encoder.stem) == 2


def test_config_rebuilds_every_layout_and_records_every_key():
    for config in (*PRESETS.values(), {**TINY, "separable": True}):
        model = RelightNet(**config)
        rebuilt = RelightNet(**model.config())
        shapes = {k: v.shape for k, v in model.state_dict().items()}
        assert {k: v.shape for k, v in rebuilt.state_dict().items()} == shapes
    # every layout key is recorded, and model.training.checkpoint accepts all of them
    assert set(ARCH_DEFAULTS) <= set(RelightNet().config()) <= set(CONFIG_KEYS)
    assert RelightNet(**PRESETS["default"]).config() == RelightNet().config()
    with pytest.raises(ValueError, match="full_res_convs"):
        RelightNet(full_res_convs=3)
    with pytest.raises(ValueError, match="decoder_width"):
        RelightNet(decoder_width=0)


def test_default_model_fits_the_size_and_compute_budget():
    """Ship budget: fp32 ONNX <= 25 MB (4 bytes per weight + a few kB of graph) and 512x512
    decomposition < 400 ms on 2 cores, which onnxruntime reached at about 15 GFLOP
    (docs/benchmarks/model.md). Conv FLOPs scale with the pixel count, so 128x128 costs 1/16
    of 512x512; the light decoder's FC does not scale but is < 1e-5 GFLOP."""
    from torch.utils.flop_counter import FlopCounterMode

    model = RelightNet().eval()
    assert 4 * sum(p.numel() for p in model.parameters()) < 25e6
    with FlopCounterMode(display=False) as counter, torch.no_grad():
        model(torch.zeros(1, 3, 128, 128))
    assert counter.get_total_flops() * 16 / 1e9 < 16.0
