"""model.average: a network between two checkpoints of one config (issue 45's half-way model)."""

import json

import pytest
import torch
from safetensors import safe_open

from model import average
from model.networks.geometry import GeometryNet
from model.training.checkpoint import interpolate_models, load_model, save_model

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def _net(seed: int, width: int = 4) -> GeometryNet:
    torch.manual_seed(seed)
    net = GeometryNet(sh_order=2, width=width, depth=2, decoder_width=4)
    with torch.no_grad():  # BatchNorm's statistics differ too, as two trainings' do
        for name, buf in net.named_buffers():
            if buf.is_floating_point():
                buf.uniform_(0.5, 1.5)
            else:
                buf.fill_(seed + 1)
    return net.eval()


@pytest.fixture()
def pair(tmp_path):
    a, b = tmp_path / "a.safetensors", tmp_path / "b.safetensors"
    save_model(_net(1), a)
    save_model(_net(2), b, {"training": {"steps": 7}})
    return a, b


def test_the_ends_are_the_checkpoints_bit_for_bit(pair):
    a, b = pair
    for weight, path in ((0.0, a), (1.0, b)):
        model, _ = interpolate_models(a, b, weight)
        want = load_model(path).state_dict()
        for name, value in model.state_dict().items():
            if value.is_floating_point():
                assert torch.equal(value, want[name]), (weight, name)


def test_halfway_is_the_mean_of_every_float_and_end_integers(pair):
    a, b = pair
    model, _ = interpolate_models(a, b, 0.5)
    sa, sb = load_model(a).state_dict(), load_model(b).state_dict()
    for name, value in model.state_dict().items():
        if value.is_floating_point():
            # lerp in float32: one rounding of the difference and one of the sum, each half an ulp
            bound = 2 * torch.finfo(torch.float32).eps * torch.maximum(sa[name].abs(), sb[name].abs())
            assert torch.all((value - (sa[name] + sb[name]) / 2).abs() <= bound), name
        else:
            assert torch.equal(value, sb[name]), name  # the batch count: end's (3), not a mean
            assert int(value.max()) == 3


def test_cli_writes_a_loadable_checkpoint_that_names_its_sources(pair, tmp_path, capsys):
    a, b = pair
    out = tmp_path / "mid" / "model.safetensors"
    assert average.main([str(a), str(b), "--weight", "0.25", "--out", str(out)]) == 0
    model = load_model(out)
    x = torch.rand(1, 3, 32, 32) * 2 - 1
    with torch.no_grad():
        outputs = model(x)
    assert all(torch.isfinite(v).all() for v in outputs.values() if torch.is_tensor(v))
    with safe_open(str(out), "pt") as f:
        meta = json.loads(f.metadata()["relightnet"])
    assert meta["training"] == {"steps": 7}  # end's metadata carried on
    source = meta["interpolated"]
    assert source["end_weight"] == 0.25 and len(source["start_sha256"]) == 64 != source["start_sha256"].count("0")
    assert source["start_sha256"] != source["end_sha256"]
    assert json.loads(out.with_suffix(".json").read_text())["interpolated"] == source


def test_refusals_name_the_files(pair, tmp_path, capsys):
    a, _ = pair
    wide = tmp_path / "wide.safetensors"
    save_model(_net(3, width=8), wide)
    out = tmp_path / "never.safetensors"
    assert average.main([str(a), str(wide), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "different configs" in err and str(wide) in err and not out.exists()
    assert average.main([str(a), str(a), "--weight", "1.5", "--out", str(out)]) == 1
    assert "[0, 1]" in capsys.readouterr().err and not out.exists()
    missing = tmp_path / "missing.safetensors"
    assert average.main([str(missing), str(a), "--out", str(out)]) == 1
    assert str(missing) in capsys.readouterr().err and not out.exists()
