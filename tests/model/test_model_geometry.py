"""The geometry-first model (model.networks.geometry): outputs derived by physics, training on
the analytic dataset, checkpoint and ONNX round trips, the runtime unchanged, the
training pack, and the geometry rows of the evaluation."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from model.samples import data, data_crops, data_splits
from model.scoring import geometry_diagnostics, pair_metrics
from model.networks import physics
from model import train
from model.training.checkpoint import load_model, save_model
from model.networks.geometry import GEOMETRY_LOSS_WEIGHTS, GeometryNet, geometry_losses, mean_luminance
from model.samples.synthetic import write_analytic_dataset
from relight.lighting import presets
from relight.lighting.light import sh_light

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    folder = tmp_path_factory.mktemp("analytic")
    write_analytic_dataset(folder, n_scenes=4, size=32, order=4, lights=("studio", "city", "venice"))
    return folder


def _net(seed=0, **kw):
    torch.manual_seed(seed)
    return GeometryNet(sh_order=4, width=4, depth=2, decoder_width=4, **kw).eval()


def test_outputs_are_the_physics_of_the_predicted_geometry():
    net = _net()
    x = torch.rand(2, 3, 32, 48) * 2 - 1
    with torch.no_grad():
        out = net(x)
    assert out["transport"].shape == (2, 25, 32, 48) and out["light"].shape == (2, 25, 3)
    assert out["albedo"].shape == (2, 3, 32, 48) and out["alpha"].shape == (2, 1, 32, 48)
    assert torch.all(out["residual"] == 0)
    # T is exactly the visibility-scaled Lambert lobe of the predicted unit normal
    n = out["normal"]
    assert torch.allclose((n * n).sum(1), torch.ones(2, 32, 48), atol=1e-5)
    assert torch.allclose(out["transport"], physics.lobe_transport(n, out["visibility"], 4), atol=1e-7)
    assert float(out["albedo"].min()) >= 0.0 and float(out["albedo"].max()) <= 1.0
    # with fixed_level the photo's light sits at the reference radiance
    fixed = _net(fixed_level=True)
    with torch.no_grad():
        light = fixed(x)["light"]
    assert torch.allclose(mean_luminance(light), torch.full((2,), 0.8), atol=1e-5)


def test_a_batch_item_does_not_depend_on_the_others():
    net = _net(1)
    x = torch.rand(3, 3, 32, 32) * 2 - 1
    with torch.no_grad():
        alone = net(x[:1])
        together = net(x)
    for k in ("albedo", "transport", "light", "alpha"):
        assert torch.allclose(alone[k][0], together[k][0], atol=1e-5), k


def test_loss_falls_on_one_batch_and_every_geometry_term_learns(dataset):
    """200 Adam steps on two analytic samples: normals, visibility, albedo and the
    relit image each at least halve (measured: total 2.6 -> 0.25)."""
    ds = data.TrainingScenes(data_splits.find_scenes(dataset), 16, 4, padding=1, extra_lights=[],
                             held_out=frozenset(presets.HELD_OUT))
    batch = torch.utils.data.default_collate([ds.item(0, 0), ds.item(1, 0)])
    batch = {k: v for k, v in batch.items() if isinstance(v, torch.Tensor)}
    torch.manual_seed(0)
    net = GeometryNet(sh_order=4, width=8, depth=2, decoder_width=8).train()
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    first = None
    for _ in range(200):
        terms = geometry_losses(net(batch["input"]), batch)
        if first is None:
            first = {k: float(v.detach()) for k, v in terms.items()}
        opt.zero_grad()
        terms["total"].backward()
        opt.step()
    last = {k: float(v.detach()) for k, v in terms.items()}
    for name in ("total", "normal", "albedo", "relight", "alpha"):
        assert last[name] < 0.5 * first[name], (name, first[name], last[name])


def test_checkpoint_round_trip_and_train_cli(dataset, tmp_path):
    out = tmp_path / "run"
    argv = ["--data", str(dataset), "--out", str(out), "--steps", "2", "--batch", "2", "--size", "32",
            "--preset", "geo-small", "--width", "4", "--depth", "2", "--val-every", "2", "--padding", "2",
            "--val-fraction", "0.25", "--no-presets", "--quiet", "--pack", str(tmp_path / "pack.npz")]
    assert train.main(argv) == 0
    record = json.loads((out / "model.json").read_text())
    assert record["config"]["arch"] == "geometry" and record["config"]["width"] == 4
    net = load_model(out / "model.safetensors")
    assert isinstance(net, GeometryNet) and not net.training
    again = load_model(save_model(net, tmp_path / "copy.safetensors"))
    x = torch.rand(1, 3, 32, 32) * 2 - 1
    with torch.no_grad():
        assert torch.equal(net(x)["albedo"], again(x)["albedo"])
    # the pack is reused as it is when it matches, and rebuilt when it does not
    assert (tmp_path / "pack.npz").is_file()
    assert train.main(argv[:3] + [str(tmp_path / "run2")] + argv[4:]) == 0


def test_body_prior_feeds_only_the_encoder_and_round_trips(tmp_path):
    """With body_prior the network takes 7 channels; the photo's physics reads the first three
    (the light fit and the photo-consistent albedo), so changing the prior changes the outputs
    only through the encoder, and a photo alone is refused with the channel count."""
    net = _net(2, body_prior=True)
    x = torch.rand(2, 7, 32, 32) * 2 - 1
    with torch.no_grad():
        out = net(x)
        other = net(torch.cat([x[:, :3], -x[:, 3:]], dim=1))
    assert out["albedo"].shape == (2, 3, 32, 32)
    assert not torch.allclose(out["normal"], other["normal"])  # the prior reaches the geometry
    with pytest.raises(ValueError, match=r"\[B,7,H,W\]"):
        net.check_input(x[:, :3])
    assert net.config()["body_prior"] is True and "body_prior" not in _net().config()
    again = load_model(save_model(net, tmp_path / "body.safetensors"))
    with torch.no_grad():
        assert torch.equal(again(x)["transport"], out["transport"])


def test_pack_holds_the_same_crops_as_the_scene_files(dataset, tmp_path):
    paths = data_splits.find_scenes(dataset)
    held = frozenset(presets.HELD_OUT)
    pack = data_crops.pack_scenes(paths, tmp_path / "p.npz", 16, 4, padding=1, held_out=held)
    packed = data_crops.PackedScenes(pack, paths, 16, 4, padding=1)
    for i, path in enumerate(paths):
        direct = data_crops.load_cropped(path, 16, 4, 1, held)
        got = packed(i)
        # float16 storage: relative error <= 2^-11 of each value
        for name in ("alpha", "albedo", "transport", "normal"):
            a, b = getattr(direct, name), getattr(got, name)
            assert np.all(np.abs(a - b) <= np.abs(a) * 2.0 ** -11 + 1e-7), name
        assert [np.asarray(l).tolist() for l in got.lights] == [np.asarray(l).tolist() for l in direct.lights]
        assert got.light_names == direct.light_names and got.held_out == direct.held_out
    with pytest.raises(ValueError, match="other scenes or crop settings"):
        data_crops.PackedScenes(pack, paths, 32, 4, padding=1)


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_onnx_export_matches_torch_and_the_runtime_relights_with_it(tmp_path):
    from export.onnx_export import export_onnx, max_abs_diff, onnx_outputs, torch_outputs
    from relight.network.runtime import Relighter

    net = _net(2)
    path, digest = export_onnx(net, tmp_path / "geo.onnx")
    x = (np.random.default_rng(0).uniform(-1, 1, (1, 3, 32, 48))).astype(np.float32)
    diff = max_abs_diff(torch_outputs(net, x), onnx_outputs(path, x))
    # float32 network, float64 light fit in both: only the network's own rounding is left
    assert max(diff.values()) < 1e-4, diff
    photo = np.random.default_rng(1).uniform(0.05, 0.9, (40, 30, 3)).astype(np.float32)
    mask = np.zeros((40, 30), np.float32)
    mask[5:35, 8:22] = 1.0
    d = Relighter(path, threads=1, working_size=32).decompose(photo, mask=mask)
    relit = d.relight(sh_light("studio", d.sh_order))
    assert relit.shape == photo.shape and np.all(np.isfinite(relit))
    assert np.array_equal(relit[mask == 0], photo[mask == 0])


def test_strided_light_fit_exports_and_trains_in_float32():
    """fit_stride 2 fits the light on a quarter of the pixels, in the ONNX graph as in torch;
    training mode fits in float32 and lands within float32 rounding of the double fit."""
    from export.onnx_export import max_abs_diff, onnx_outputs, torch_outputs

    net = _net(4, fit_stride=2)
    assert net.config()["fit_stride"] == 2 and "fit_stride" not in _net().config()
    x = torch.rand(2, 3, 32, 48) * 2 - 1
    import copy

    with torch.no_grad():
        double = net(x)["light"]
        single = copy.deepcopy(net).train()(x)["light"]  # a copy: train mode moves BatchNorm's statistics
    # BatchNorm in train mode uses the batch's statistics: compare the fit alone on eval features
    with torch.no_grad():
        out = net(x)
        photo = physics.linear_from_network_input(x)
        w = out["alpha"] * 1.0
        args = (out["transport"][..., ::2, ::2], out["albedo_prior"][..., ::2, ::2], photo[..., ::2, ::2],
                w[..., ::2, ::2], out["light_prior"], net.ridge)
        f64 = physics.fit_light(*args)
        f32 = physics.fit_light(*args, precision=torch.float32)
    assert torch.allclose(out["light"], double)
    assert float((f32 - f64).abs().max() / f64.abs().max()) < 1e-4
    assert not torch.equal(single, double)  # train mode is another path (BatchNorm, float32)
    import tempfile
    from pathlib import Path

    from export.onnx_export import export_onnx

    with tempfile.TemporaryDirectory() as tmp:
        path, _ = export_onnx(net, Path(tmp) / "strided.onnx")
        xs = x[:1].numpy()
        diff = max_abs_diff(torch_outputs(net, xs), onnx_outputs(path, xs))
    assert max(diff.values()) < 1e-4, diff


def test_front_facing_normals_never_turn_away_from_the_camera(tmp_path):
    """front_facing mirrors a normal's y onto the camera's side (y <= 0), as every visible
    surface's is; elsewhere the outputs are the unconstrained network's."""
    from export.onnx_export import export_onnx, max_abs_diff, onnx_outputs, torch_outputs

    free = _net(5)
    front = _net(5, front_facing=True)
    front.load_state_dict(free.state_dict())
    x = torch.rand(2, 3, 32, 32) * 2 - 1
    with torch.no_grad():
        a, b = free(x)["normal"], front(x)["normal"]
    assert bool((a[:, 1] > 0).any())  # the untrained network turns some away
    assert float(b[:, 1].max()) <= 0.0
    torch.testing.assert_close(b[:, 1], -a[:, 1].abs())
    torch.testing.assert_close(b[:, ::2], a[:, ::2])
    assert front.config()["front_facing"] is True and "front_facing" not in free.config()
    path, _ = export_onnx(front, tmp_path / "front.onnx")
    diff = max_abs_diff(torch_outputs(front, x[:1].numpy()), onnx_outputs(path, x[:1].numpy()))
    assert max(diff.values()) < 1e-4, diff


def test_geometry_metrics_are_zero_for_the_truth_and_measure_a_turned_normal(dataset):
    """Perfect transport and light: no normal, visibility or light error; a turned one: large."""
    pairs = data.EvaluationPairs(data_splits.find_scenes(dataset), 32, 4, padding=2,
                                 held_out=frozenset(presets.HELD_OUT))
    sample = pair_metrics.with_metric_weight({k: (v.numpy() if isinstance(v, torch.Tensor) else v)
                                          for k, v in pairs[0].items()}, "interior")
    truth = {"transport": sample["transport"], "light": sample["light"], "albedo": sample["albedo"]}
    m = geometry_diagnostics.geometry_metrics(truth, sample)
    # a light turned half way round moves over the spheres, and the truth moves it as the GT does
    assert m["light_motion"] == m["light_motion_gt"] > 0.2
    # the analytic scenes' T is the unoccluded lobe of their normal: band 1 gives it back, to
    # float32 storage (arccos(1 - 2^-23) = sqrt(2 * 2^-23) rad = 0.028 deg)
    assert m["normal_median_deg"] < 0.05 and m["visibility_l1"] < 1e-6 and m["light_rel_l2"] == 0.0
    # a transport turned 90 degrees about Z reads as normals 90 degrees off where they
    # are horizontal; every angle is within [0, 180]
    from relight.lighting import sh_rotation

    turn = sh_rotation.rotation_matrix(sh_rotation.z_rotation(90.0), 4)
    turned = np.einsum("kn,nhw->khw", turn, sample["transport"])
    m90 = geometry_diagnostics.geometry_metrics({"transport": turned, "light": sample["light"] * 2,
                                     "albedo": sample["albedo"]}, sample)
    assert 20.0 < m90["normal_mean_deg"] <= 180.0
    assert m90["light_rel_l2"] == pytest.approx(1.0)


def test_loss_weights_are_the_geometry_terms_for_a_geometry_preset():
    args = train.parse_args(["--data", "d", "--out", "o", "--preset", "geo-small", "--size", "32",
                             "--loss-weight", "normal=2"])
    weights = train.loss_weights_from_args(args)
    assert weights == {**GEOMETRY_LOSS_WEIGHTS, "normal": 2.0}
    bad = train.parse_args(["--data", "d", "--out", "o", "--preset", "geo-small", "--size", "32",
                            "--loss-weight", "log=1"])  # a RelightNet term, not a geometry one
    with pytest.raises(ValueError, match="unknown term 'log'"):
        train.loss_weights_from_args(bad)
