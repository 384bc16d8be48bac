"""ONNX export: checker, dynamic shapes, fp32 parity, fp16 error, metadata, hashes, CLI."""

from __future__ import annotations

import json

import numpy as np
import onnx
import pytest
import torch

from export.fp16 import export_fp16
from export.onnx_export import (export_onnx, max_abs_diff, onnx_outputs, read_metadata,
                                torch_outputs)
from export.random_model import export_random_model, random_relightnet
from relight import models
from relight.models import METADATA_KEYS, OUTPUT_NAMES

CONFIG = dict(sh_order=4, width=4, depth=2)  # tiny: fast to trace and run

# fp32 parity: both sides sum the same products in float32 but in different
# orders (im2col/BLAS vs MLAS, folded BatchNorm). Each output goes through ~20
# layers of <= 9*64 = 576-term sums of O(1) values: a rounding-error random walk
# of sqrt(576)*6e-8 ~ 1.4e-6 per layer, < 1e-4 over 20 layers even if all add.
FP32_TOL = 1e-4
# fp16: unit roundoff 2^-11 = 4.9e-4 relative per operation; over ~20 layers
# errors add to <= ~20 * 4.9e-4 ~ 1e-2 of the output's scale.
FP16_REL_TOL = 1e-2


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    folder = tmp_path_factory.mktemp("export")
    path, digest, net = export_random_model(folder / "tiny.onnx", seed=3, **CONFIG)
    path16, digest16 = export_fp16(path, folder / "tiny.fp16.onnx")
    return dict(path=path, digest=digest, net=net, path16=path16, digest16=digest16)


def _realish(h: int, w: int, batch: int = 1) -> np.ndarray:
    """A smooth, photo-like input: a shaded disc over a gradient, in [-1, 1]."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((x - w / 2) / (w / 3)) ** 2 + ((y - h / 2) / (h / 3)) ** 2
    disc = np.clip(1 - r2, 0, 1) ** 0.5
    img = np.stack([0.2 + 0.6 * disc, 0.1 + 0.3 * y / h + 0.5 * disc, 0.4 * x / w + 0.2 * disc])
    return np.repeat((img * 2 - 1)[None], batch, axis=0).astype(np.float32)


def test_graph_passes_checker_with_exactly_five_dynamic_outputs(exported):
    model = onnx.load(str(exported["path"]))
    onnx.checker.check_model(model, full_check=True)
    assert max(o.version for o in model.opset_import if o.domain in ("", "ai.onnx")) >= 17
    assert [o.name for o in model.graph.output] == list(OUTPUT_NAMES)
    (inp,) = model.graph.input
    dims = [d.dim_param or d.dim_value for d in inp.type.tensor_type.shape.dim]
    assert dims == ["batch", 3, "height", "width"]
    assert inp.type.tensor_type.elem_type == onnx.TensorProto.FLOAT


@pytest.mark.parametrize("shape", [(1, 3, 32, 24), (2, 3, 16, 40)])
def test_fp32_parity_on_random_and_realish_inputs_at_two_sizes(exported, shape):
    rng = np.random.default_rng(shape[2])
    for x in (rng.uniform(-1, 1, shape).astype(np.float32), _realish(*shape[2:], batch=shape[0])):
        ref = torch_outputs(exported["net"], x)
        got = onnx_outputs(exported["path"], x)
        n = (CONFIG["sh_order"] + 1) ** 2
        assert got["transport"].shape == (shape[0], n, *shape[2:])
        assert got["light"].shape == (shape[0], n, 3)
        diff = max_abs_diff(ref, got)
        assert max(diff.values()) <= FP32_TOL, diff


def test_fp16_keeps_fp32_io_and_its_error_is_bounded(exported):
    model = onnx.load(str(exported["path16"]))
    onnx.checker.check_model(model, full_check=True)
    assert model.graph.input[0].type.tensor_type.elem_type == onnx.TensorProto.FLOAT
    assert all(o.type.tensor_type.elem_type == onnx.TensorProto.FLOAT for o in model.graph.output)
    conv_weights = {n.input[1] for n in model.graph.node if n.op_type == "Conv"}
    types = {i.data_type for i in model.graph.initializer if i.name in conv_weights}
    assert types == {onnx.TensorProto.FLOAT16}
    x = _realish(32, 24)
    ref = onnx_outputs(exported["path"], x)
    half = onnx_outputs(exported["path16"], x)
    diff = max_abs_diff(ref, half)
    for k, d in diff.items():
        scale = max(1.0, float(np.abs(ref[k]).max()))
        assert d <= FP16_REL_TOL * scale, (k, d)
    assert max(diff.values()) > 0  # really computed in half precision
    assert read_metadata(model)["relight.precision"] == "fp16"


def test_metadata_round_trip(exported):
    meta = read_metadata(exported["path"])
    assert set(METADATA_KEYS) <= set(meta)
    assert int(meta["relight.sh_order"]) == CONFIG["sh_order"]
    assert int(meta["relight.size_multiple"]) == 2 ** CONFIG["depth"]
    assert meta["relight.conventions"] == models.CONVENTION_VERSION
    assert json.loads(meta["relight.network_config"]) == exported["net"].config()
    assert json.loads(meta["relight.input_spec"])["height_width_multiple_of"] == 4
    assert "random" in meta["relight.training_data"]
    assert meta["relight.precision"] == "fp32"


def test_sha256_sidecar_and_registry(exported, tmp_path):
    path = exported["path"]
    assert models.read_sidecar(path) == exported["digest"] == models.file_sha256(path)
    assert models.sidecar_path(path).read_text().split() == [exported["digest"], path.name]
    # registering needs the model beside the registry file
    reg = tmp_path / "models.json"
    copy = tmp_path / "m.onnx"
    copy.write_bytes(path.read_bytes())
    models.register_model("tiny", copy, exported["digest"], read_metadata(copy), registry_path=reg)
    data = json.loads(reg.read_text())
    assert data["default"] == "tiny" and data["models"]["tiny"]["sha256"] == exported["digest"]
    assert models.default_model_path(reg) == copy
    assert models.verify_model_file(copy, reg) == exported["digest"]
    with pytest.raises(ValueError, match="beside"):
        models.register_model("x", path, exported["digest"], {}, registry_path=reg)
    copy.write_bytes(path.read_bytes() + b"\0")
    with pytest.raises(ValueError, match="SHA-256 mismatch"):
        models.verify_model_file(copy, reg)


def test_empty_registry_names_the_fix(tmp_path):
    with pytest.raises(ValueError, match="--model"):
        models.default_model_path(tmp_path / "models.json")
    (tmp_path / "models.json").write_text("{not json")
    with pytest.raises(ValueError, match="registry"):
        models.load_registry(tmp_path / "models.json")


def test_export_of_a_net_in_training_mode_matches_eval_torch(tmp_path):
    net = random_relightnet(seed=5, **CONFIG).train()
    stats = {k: v.clone() for k, v in net.state_dict().items()}
    path, _ = export_onnx(net, tmp_path / "t.onnx")
    for k, v in net.state_dict().items():  # tracing must not touch BatchNorm statistics
        assert torch.equal(v, stats[k]), k
    x = _realish(16, 16)
    assert max(max_abs_diff(torch_outputs(net, x), onnx_outputs(path, x)).values()) <= FP32_TOL


def test_export_command(tmp_path, capsys):
    from export.__main__ import main
    from model.training.checkpoint import save_model

    weights = save_model(random_relightnet(seed=1, **CONFIG), tmp_path / "w.safetensors")
    out = tmp_path / "m.onnx"
    assert main([str(weights), "--out", str(out), "--fp16"]) == 0
    printed = capsys.readouterr().out
    assert "fp32 parity" in printed and "fp16 vs fp32" in printed
    assert models.read_sidecar(out) == models.file_sha256(out)
    fp16 = tmp_path / "m.fp16.onnx"
    assert models.read_sidecar(fp16) == models.file_sha256(fp16)
    assert main([str(weights), "--out", str(tmp_path / "m.txt")]) == 2
    assert main([str(tmp_path / "missing.safetensors"), "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("export: error:") for line in err)


def test_parity_counts_each_output_in_units_of_its_size_and_a_failed_export_leaves_nothing(
        tmp_path, monkeypatch, capsys):
    """fp32_parity divides an output's difference by max(1, its largest |value|): a light of 8 may
    differ by 8x what an albedo may. An export that fails it leaves neither the file nor its hash."""
    import export.__main__ as export_main
    from export import onnx_export
    from model.training.checkpoint import save_model

    net = random_relightnet(seed=1, **CONFIG)
    ours = {"albedo": np.zeros((1, 1)), "light": np.full((1, 1), 8.0)}
    theirs = {"albedo": np.full((1, 1), 2e-5), "light": np.full((1, 1), 8.0 + 4e-4)}
    monkeypatch.setattr(onnx_export, "parity_inputs", lambda m: [None])
    monkeypatch.setattr(onnx_export, "torch_outputs", lambda n, x: ours)
    monkeypatch.setattr(onnx_export, "onnx_outputs", lambda p, x: theirs)
    assert onnx_export.fp32_parity(net, "unused.onnx") == pytest.approx(4e-4 / 8.0, rel=1e-9)
    monkeypatch.undo()

    weights = save_model(net, tmp_path / "w.safetensors")
    out = tmp_path / "m.onnx"
    monkeypatch.setattr(onnx_export, "fp32_parity", lambda n, p: 1.0)
    assert export_main.main([str(weights), "--out", str(out)]) == 1
    assert not out.exists() and not models.sidecar_path(out).exists()
    assert "removed the file and its .sha256" in capsys.readouterr().err


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_cli_registers_fp32_and_fp16_and_sets_the_default(tmp_path, monkeypatch, capsys):
    from export.__main__ import main
    from model.training.checkpoint import save_model

    reg = tmp_path / "models" / "models.json"
    reg.parent.mkdir()
    real_register = models.register_model
    monkeypatch.setattr(models, "register_model",
                        lambda *a, **kw: real_register(*a, registry_path=reg, **kw))
    weights = save_model(random_relightnet(4, sh_order=2, width=4, depth=2), tmp_path / "w.safetensors")
    for name, extra in (("first", []), ("second", ["--default"])):
        assert main([str(weights), "--out", str(reg.parent / f"{name}.onnx"), "--fp16",
                     "--register", name, *extra]) == 0, capsys.readouterr().err
    data = json.loads(reg.read_text())
    assert set(data["models"]) == {"first", "first-fp16", "second", "second-fp16"}
    assert data["default"] == "second"  # --default moves it; the first registered was the default before
    for name, entry in data["models"].items():
        path = reg.parent / entry["file"]
        assert models.file_sha256(path) == entry["sha256"], name
        assert entry["metadata"]["relight.precision"] == ("fp16" if name.endswith("fp16") else "fp32")
