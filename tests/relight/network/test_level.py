"""The level prior (relight.network.level): its regression, its bounds, what applying it changes and
what it keeps, and the runtime and model.evaluate's predictor applying a model's prior."""

from __future__ import annotations

import math

import numpy as np
import pytest
from refine_support import lobe_light, synthetic

from relight.network import level
from relight.imaging.colour import LUMINANCE_WEIGHTS
from relight.network.level import LevelPrior

PRIOR = LevelPrior(((0.3, 0.6, -0.4), (0.2, 0.4, 0.2), (0.25, 0.3, 0.0)), pairs=10)


def test_metadata_round_trip_and_refusals():
    assert LevelPrior.from_metadata(PRIOR.to_metadata()) == PRIOR
    assert LevelPrior.from_metadata(None) is None
    for bad in ("not json", "{}", '{"rows": [[0, 0, 0]]}', '{"rows": [[0, 0, "x"], [0, 0, 0], [0, 0, 0]]}',
                '{"rows": [[NaN, 0, 0], [0, 0, 0], [0, 0, 0]]}', '{"rows": 3}'):
        with pytest.raises(ValueError, match="malformed"):
            LevelPrior.from_metadata(bad)
    for rows in (((0, 2.0, 0),) * 3, ((0, 0, -1.5),) * 3, ((9.0, 0, 0),) * 3, ((math.inf, 0, 0),) * 3):
        with pytest.raises(ValueError, match="slopes|finite"):
            LevelPrior(rows)


def test_features_and_gains_on_a_known_shading():
    d, _, transport, disk = synthetic(lobe_light([0.3, -1.0, 0.5], [1.0, 0.8, 0.6], 0.4),
                                      lobe_light([0.3, -1.0, 0.5], [1.0, 0.8, 0.6], 0.4))
    weight = disk.astype(np.float64)
    mean = np.einsum("hw,hwc->c", weight, transport.astype(np.float64) @ d.light.astype(np.float64)) / weight.sum()
    lum = float(mean @ np.asarray(LUMINANCE_WEIGHTS))
    l, x = level.features(d.transport, d.light, weight)
    assert l == pytest.approx(math.log2(lum), abs=1e-9)
    np.testing.assert_allclose(x, np.log2(mean) - math.log2(lum), atol=1e-9)
    expected = [2.0 ** (a + b * math.log2(lum) + k * xc) for (a, b, k), xc in zip(PRIOR.rows, x)]
    np.testing.assert_allclose(PRIOR.gains(d.transport, d.light, weight), expected, rtol=1e-9)


def test_gains_are_bounded_and_finite_without_light_or_person():
    d, _, transport, disk = synthetic(lobe_light([0, -1, 0], [1, 1, 1], 0.3), lobe_light([0, -1, 0], [1, 1, 1], 0.3))
    steep = LevelPrior(((8.0, 1.5, 1.5),) * 3)
    for light, weight in ((np.zeros_like(d.light), disk), (d.light, np.zeros_like(disk, dtype=float)),
                          (d.light * 1e30, disk), (np.full_like(d.light, np.nan), disk)):
        g = steep.gains(transport, light, weight)
        assert np.all(np.isfinite(g)) and np.all(g <= 2.0 ** level.MAX_STOPS) and np.all(g >= 2.0 ** -level.MAX_STOPS)


def test_fit_is_the_ridge_regression_and_recovers_the_prior_where_features_vary():
    """Per channel the slopes solve the ridge least squares of the centred features (an
    augmented system, solved independently here), the intercept is the mean residual; where a
    feature varies far more than the ridge (var >> SLOPE_RIDGE) the generating prior comes back
    to within the ridge's shrink var / (var + ridge); a feature that hardly varies gets almost
    no slope from noise."""
    rng = np.random.default_rng(7)
    lums = rng.normal(-0.5, 0.6, 400)
    colours = rng.normal(0.0, 0.3, (400, 3))
    colours[:, 1] *= 0.03  # green's colour hardly varies, as in the calibration data
    gains = np.stack([a + b * lums + k * colours[:, c] for c, (a, b, k) in enumerate(PRIOR.rows)], axis=1)
    noisy = gains + rng.normal(0.0, 0.05, gains.shape)
    fitted = level.fit_prior(lums, colours, noisy)
    assert fitted.pairs == 400
    for c, (a, b, k) in enumerate(fitted.rows):
        centred = np.stack([lums - lums.mean(), colours[:, c] - colours[:, c].mean()], axis=1)
        augmented = np.vstack([centred, np.sqrt(level.SLOPE_RIDGE * 400) * np.eye(2)])
        target = np.r_[noisy[:, c] - noisy[:, c].mean(), 0.0, 0.0]
        np.testing.assert_allclose((b, k), np.linalg.lstsq(augmented, target, rcond=None)[0], atol=1e-9)
        assert a == pytest.approx(np.mean(noisy[:, c] - b * lums - k * colours[:, c]), abs=1e-9)
    # red and blue: var 0.36 and 0.09 against a ridge of 0.002: within 3% (+ the noise's 0.01)
    for c in (0, 2):
        np.testing.assert_allclose(fitted.rows[c][1:], PRIOR.rows[c][1:], atol=0.03 * 0.6 + 0.01)
    assert abs(fitted.rows[1][2]) < 0.5 * abs(PRIOR.rows[1][2])  # green: var 8e-5, shrunk
    # a slope past the bound is clipped and the intercept refitted to the mean
    clipped = level.fit_prior(lums, colours, np.stack([3.0 * lums] * 3, axis=1))
    assert all(row[1] == level.MAX_SLOPE for row in clipped.rows)
    a, b, k = clipped.rows[0]
    assert a == pytest.approx(np.mean(3.0 * lums - level.MAX_SLOPE * lums - k * colours[:, 0]), abs=1e-9)
    with pytest.raises(ValueError, match="at least 4"):
        level.fit_prior(lums[:3], colours[:3], gains[:3])
    with pytest.raises(ValueError, match="finite"):
        level.fit_prior(np.r_[lums[:9], np.nan], colours[:10], gains[:10])


def test_apply_keeps_the_photo_and_scales_the_relit_person():
    """The light divided by the gains and the albedo re-derived: albedo x (T . L) is the photo
    where the albedo rule neither clips nor floors, and the relit person is the gains times
    what it was."""
    light = lobe_light([0.2, -1.0, 0.4], [1.0, 0.85, 0.7], 0.5)
    d, _, transport, disk = synthetic(light, light)
    out, gains = level.apply(d, PRIOR)
    np.testing.assert_allclose(out.light, d.light / gains[None, :], rtol=1e-6)
    shading_before, shading_after = transport @ d.light, transport @ out.light
    free = disk & np.all(d.albedo * gains < 0.999, axis=-1) & np.all(d.albedo > 1e-3, axis=-1)
    free &= np.all(shading_after > 0.25 * shading_after[disk].mean(), axis=-1)
    assert free.sum() > 0.5 * disk.sum()
    np.testing.assert_allclose((out.albedo * shading_after)[free], (d.albedo * shading_before)[free], rtol=1e-4)
    target = lobe_light([-0.5, -0.6, 0.3], [0.7, 0.8, 1.0], 0.2)
    np.testing.assert_allclose((out.albedo * (transport @ target))[free],
                               (d.albedo * gains * (transport @ target))[free], rtol=1e-4)
    assert level.apply(d, None) == (d, None)


def test_the_runtime_and_the_predictor_apply_a_models_prior(tmp_path):
    """A model whose metadata carries a prior: Relighter.decompose divides its light by the
    prior's gains (recorded in choices) unless asked not to; model.evaluate's Predictor does
    the same to the raw outputs; a model without one is untouched."""
    import onnx

    import torch

    from export.onnx_export import export_onnx, read_metadata, save_atomic, set_metadata
    from model.networks.geometry import GeometryNet
    from model.scoring.predictor import Predictor
    from relight.network.prt import to_network_input
    from relight.network.runtime import Relighter

    torch.manual_seed(3)
    path, _ = export_onnx(GeometryNet(sh_order=4, width=4, depth=2, decoder_width=4).eval(), tmp_path / "tiny.onnx")
    photo = np.random.default_rng(1).uniform(0.05, 0.6, (48, 40, 3)).astype(np.float32)
    mask = np.zeros((48, 40), np.float32)
    mask[6:42, 8:32] = 1.0
    plain = Relighter(path).decompose(photo, mask=mask, working_size=32)
    assert plain.choices["level"] == "off (the model has no level prior)"

    model = onnx.load(str(path))
    set_metadata(model, {**read_metadata(model), level.METADATA_KEY: PRIOR.to_metadata()})
    save_atomic(model, path)
    relighter = Relighter(path)
    assert relighter.level_prior == PRIOR
    with_prior = relighter.decompose(photo, mask=mask, working_size=32)
    gains = PRIOR.gains(plain.transport, plain.light, plain.alpha)
    np.testing.assert_allclose(with_prior.light, plain.light / gains[None, :], rtol=1e-5)
    np.testing.assert_allclose(with_prior.choices["level"]["gains"], gains, rtol=1e-3)
    off = relighter.decompose(photo, mask=mask, working_size=32, level=False)
    np.testing.assert_array_equal(off.light, plain.light)
    assert off.choices["level"] == "off"

    x = to_network_input(photo[:32, :32], mask[:32, :32]).transpose(2, 0, 1)[None].astype(np.float32)
    raw = Predictor(path).session.run(x)
    out = Predictor(path)(x)
    gains = PRIOR.gains(raw["transport"][0].transpose(1, 2, 0), raw["light"][0], raw["alpha"][0, 0])
    np.testing.assert_allclose(out["light"][0], raw["light"][0] / gains[None, :], rtol=1e-5)
    np.testing.assert_array_equal(out["transport"], raw["transport"])


def test_calibration_command_fits_writes_and_checks(tmp_path, capsys, one_thread):
    """python -m export.level_prior on analytic scenes: the prior is fitted on every pair, written
    into the model's metadata with its SHA-256 updated (the runtime opens it, hash-checked, and
    finds the same prior), and --check prints both PSNRs; a folder without pairs is one error."""
    import re

    import torch

    from export import level_prior
    from export.onnx_export import export_onnx
    from model.networks.geometry import GeometryNet
    from model.samples.synthetic import write_analytic_dataset
    from relight.network.runtime import Relighter

    data = tmp_path / "scenes"
    write_analytic_dataset(data, n_scenes=3, size=32, order=4, lights=("studio", "city", "venice"))
    torch.manual_seed(5)
    path, digest = export_onnx(GeometryNet(sh_order=4, width=4, depth=2, decoder_width=4).eval(), tmp_path / "m.onnx")
    assert level_prior.main([str(path), "--data", str(data), "--write", "--check", str(data), "--threads", "1"]) == 0
    out = capsys.readouterr().out
    fitted = LevelPrior.from_metadata(re.search(r"calibrated on \d+ pairs: (\{.*\})", out).group(1))
    assert fitted.pairs == 3 * 4  # 3 scenes, 4 ordered pairs each (max_pairs_per_scene) of their 3 lights
    new_digest = re.search(r"sha256 ([0-9a-f]{64})", out).group(1)
    assert new_digest != digest and (tmp_path / "m.onnx.sha256").read_text().startswith(new_digest)
    assert Relighter(path).level_prior == fitted
    psnrs = re.search(r"relit PSNR ([\d.]+) dB without the prior, ([\d.]+) with it", out)
    assert psnrs and all(math.isfinite(float(v)) for v in psnrs.groups())
    # under mixed training lights (PRT pairs): two per scene, a prior of their own
    assert level_prior.main([str(path), "--data", str(data), "--mixed-lights", "--threads", "1"]) == 0
    mixed = re.search(r"calibrated on (\d+) pairs: (\{.*\})", capsys.readouterr().out)
    assert int(mixed.group(1)) == 3 * 2 and LevelPrior.from_metadata(mixed.group(2)) != fitted
    empty = tmp_path / "empty"
    empty.mkdir()
    assert level_prior.main([str(path), "--data", str(empty), "--threads", "1"]) == 1
    assert "export.level_prior: error:" in capsys.readouterr().err
