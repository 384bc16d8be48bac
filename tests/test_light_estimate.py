"""The light estimator (issue 25): its network and losses, its input, the training command,
the ONNX export and how the runtime gives the photo's light its colour and level."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from model.light_estimator import LightEstimator, colour_error_deg, level_error_stops, light_losses
from relight import light_estimate
from relight.colour import LUMINANCE_WEIGHTS

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py
MODELS = Path(__file__).resolve().parents[1] / "relight" / "models"


def test_the_network_answers_a_positive_dc_and_bands_in_units_of_its_luminance():
    torch.manual_seed(0)
    net = LightEstimator(order=2, width=8).eval()
    x = torch.rand(3, 4, 64, 64) * 2 - 1
    with torch.no_grad():
        out = net(x)
        head = net.head(net.features(x))
    light, raw = out["light"], head[:, :27].view(3, 9, 3)
    assert light.shape == (3, 9, 3) and bool((light[:, 0] > 0).all())
    torch.testing.assert_close(out["albedo_mean"], torch.sigmoid(head[:, 27:]))
    torch.testing.assert_close(light[:, 0], torch.exp(raw[:, 0]))
    level = (light[:, 0] * torch.tensor(LUMINANCE_WEIGHTS, dtype=torch.float32)).sum(-1)
    torch.testing.assert_close(light[:, 1:], raw[:, 1:] * level[:, None, None])


def test_losses_and_errors_are_exact_on_known_answers():
    true = torch.tensor([[[1.0, 0.5, 0.25], [0.1, -0.2, 0.3], [0.0, 0.0, 0.0], [0.2, 0.2, 0.2]]])
    zero = light_losses(true, true)
    assert float(zero["total"]) == 0.0
    twice = light_losses(true * 2, true)
    # log DC off by ln 2 in every channel; the shape term is the band error over the DC's luminance
    assert float(twice["log_dc"]) == pytest.approx(math.log(2.0), rel=1e-6)
    level = float(true[0, 0] @ torch.tensor(LUMINANCE_WEIGHTS, dtype=torch.float32))
    assert float(twice["shape"]) == pytest.approx(float(true[0, 1:].abs().mean()) / level, rel=1e-6)
    assert float(level_error_stops(true * 4, true)[0]) == pytest.approx(2.0, rel=1e-6)
    # float32: cos = 1 - O(6e-8) before arccos, which is sqrt(2 * 6e-8) rad = 0.02 deg
    assert float(colour_error_deg(true * 3, true)[0]) == pytest.approx(0.0, abs=0.05)
    grey, red = torch.ones(1, 4, 3), torch.tensor([[[1.0, 0.0, 0.0]] * 4])
    assert float(colour_error_deg(red, grey)[0]) == pytest.approx(math.degrees(math.acos(1 / math.sqrt(3))), rel=1e-5)
    black = light_losses(torch.zeros(1, 4, 3, requires_grad=True), torch.zeros(1, 4, 3))
    black["total"].backward()
    assert math.isfinite(float(black["total"]))


def test_input_is_the_masked_crop_squared_and_shrunk():
    rng = np.random.default_rng(0)
    crop = rng.uniform(0, 1, (40, 20, 3)).astype(np.float32)
    matte = np.zeros((40, 20), np.float32)
    matte[5:35, 4:16] = 1.0
    x = light_estimate.estimator_input(crop, matte)
    assert x.shape == (1, 4, 64, 64) and x.dtype == np.float32
    # the crop is centred in a square: columns outside it are black and out of the matte
    assert np.all(x[0, :3, :, :14] == 0) and np.all(x[0, 3, :, :14] == -1)
    assert -1 <= x.min() and x.max() <= 1
    with pytest.raises(ValueError, match="crop"):
        light_estimate.estimator_input(crop, matte[:10])


def _photo_and_mask():
    from model.synthetic import _spheres

    alpha, normal, _ = _spheres(96, np.random.default_rng(3))
    from relight.light import sh_light
    from relight.prt import lambert_transport, shading

    light = sh_light("studio", 4)
    photo = (0.5 * shading(lambert_transport(np.where(alpha[..., None] > 0, normal, [0, -1, 0]), 4), light)
             * alpha[..., None] + 0.2 * (1 - alpha[..., None])).astype(np.float32)
    return photo, alpha.astype(np.float32)


def test_recolouring_keeps_the_lights_shape_and_the_photo():
    from relight.runtime import Relighter

    photo, alpha = _photo_and_mask()
    d = Relighter(threads=1).decompose(photo, mask=alpha, working_size=64)
    est = d.light * np.array([1.5, 1.0, 0.5], np.float32)
    est[1:] = 0.0  # only its DC may matter
    new = light_estimate.with_light_colour(d, est)
    np.testing.assert_allclose(new.light[0], est[0], rtol=1e-6)
    np.testing.assert_allclose(new.light[1:] / new.light[0], d.light[1:] / d.light[0], rtol=1e-5, atol=1e-7)
    # quotient relighting: the photo under its own (recoloured) light is the photo where not floored or clipped
    inside = new.alpha > 0.999
    shade_d, shade_new = (d.transport @ d.light)[inside], (new.transport @ new.light)[inside]
    before, after = d.albedo[inside] * shade_d, new.albedo[inside] * shade_new

    def unfloored(shade):  # the rule floors shading at 0.25 of its mean: keep a margin above it
        return shade > 0.3 * shade.mean(axis=-1).mean()
    both = ((d.albedo[inside] < 0.999) & (new.albedo[inside] < 0.999) & (d.albedo[inside] > 0.01)
            & unfloored(shade_d) & unfloored(shade_new))
    np.testing.assert_allclose(after[both], before[both], rtol=2e-3, atol=1e-5)


def test_albedo_level_sets_the_mean_albedo_and_keeps_the_lights_shape():
    from relight.runtime import Relighter

    photo, alpha = _photo_and_mask()
    d = Relighter(threads=1).decompose(photo, mask=alpha, working_size=64)
    full = d.alpha >= light_estimate.INTERIOR
    own = d.albedo[full].mean(axis=0)
    target = own * np.array([0.8, 1.0, 1.2])
    new = light_estimate.with_albedo_level(d, target)
    # every band of channel c is scaled by own_c / target_c: the shape per channel is kept
    np.testing.assert_allclose(new.light, d.light * (own / target)[None, :], rtol=1e-5, atol=1e-7)
    # the albedo is divided by the same gains wherever the rule neither clips it at 1 nor
    # floors the shading (at 0.25 of its mean luminance: keep a margin)
    shade_d, shade_new = (d.transport @ d.light)[full], (new.transport @ new.light)[full]

    def unfloored(shade):
        return shade > 0.3 * shade.mean(axis=-1).mean()
    free = (d.albedo[full] < 0.999) & (new.albedo[full] < 0.999) & unfloored(shade_d) & unfloored(shade_new)
    assert free.mean() > 0.8
    np.testing.assert_allclose(new.albedo[full][free], (d.albedo[full] * (target / own))[free], rtol=1e-4)


def test_train_export_and_the_runtime_use_the_estimator(tmp_path):
    """Three training steps on the analytic scenes, the ONNX export with its parity check and
    registration, then Relighter.decompose(light_estimate=True) in a registry that holds it:
    the photo's light takes the estimator's DC and the choice is recorded; a registry
    without it says so and keeps the network's light."""
    from export.__main__ import main as export_main
    from model import train_light
    from model.synthetic import write_analytic_dataset
    from relight.runtime import Relighter

    data = tmp_path / "data"
    write_analytic_dataset(data, n_scenes=4, size=64, order=4, lights=("studio", "city", "sunset"))
    run = tmp_path / "run"
    assert train_light.main(["--data", str(data), "--out", str(run), "--steps", "3", "--batch", "2",
                             "--width", "8", "--val-every", "3", "--quiet"]) == 0
    registry = tmp_path / "models"
    registry.mkdir()
    shutil.copy(MODELS / "geometry.onnx", registry / "geometry.onnx")
    entries = json.loads((MODELS / "models.json").read_text())
    entries["models"] = {"geometry": entries["models"]["geometry"]}
    (registry / "models.json").write_text(json.dumps(entries))
    out = registry / light_estimate.MODEL_FILE
    assert export_main([str(run / "model.safetensors"), "--out", str(out)]) == 0
    photo, alpha = _photo_and_mask()
    plain = Relighter(registry / "geometry.onnx", threads=1, registry_path=registry / "models.json")
    d0 = plain.decompose(photo, mask=alpha, working_size=64, light_estimate=True)
    assert d0.choices["light"] == "network (no light estimator installed)"
    from relight.models import register_model
    from export.onnx_export import read_metadata

    register_model(light_estimate.MODEL_NAME, out, (out.parent / (out.name + ".sha256")).read_text().split()[0],
                   read_metadata(out), registry_path=registry / "models.json")
    r = Relighter(registry / "geometry.onnx", threads=1, registry_path=registry / "models.json")
    d = r.decompose(photo, mask=alpha, working_size=64, light_estimate=True)
    assert d.choices["light"] == "network's light, scaled to the estimator's mean albedo"
    import onnxruntime as ort

    x = light_estimate.estimator_input(d.photo_working, d.alpha)
    albedo_mean = ort.InferenceSession(str(out)).run(["albedo_mean"], {"x": x})[0][0]
    plain = r.decompose(photo, mask=alpha, working_size=64)
    want = light_estimate.with_albedo_level(plain, albedo_mean)
    np.testing.assert_allclose(d.light, want.light, rtol=1e-6)
    assert r.decompose(photo, mask=alpha, working_size=64).choices["light"] == "network"
