"""The sun-response loss (issue 45): blind to the relit level, exact for a scaled log change, finite
over black, and its suns drawn where they light what the camera sees; the training draws them only
when the loss is on, from their own stream."""

import math

import numpy as np
import pytest
import torch

from model.networks.geometry import GeometryNet, geometry_losses
from model.networks.response_loss import FLOOR, sun_response_loss
from model.samples import data
from model.samples.data_augment import SUN_ELEVATION_DEG, SUN_MAX_OFF_AXIS_DEG, random_sun_light
from relight.lighting.key_light import key_direction

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def _grey(lum: torch.Tensor) -> torch.Tensor:
    """[B, 1, H, W] luminance -> a grey [B, 3, H, W] image of that luminance."""
    return lum.expand(-1, 3, -1, -1).clone()


def _truth(seed=0, shape=(2, 1, 9, 7)):
    rng = np.random.default_rng(seed)
    lum = torch.from_numpy(rng.uniform(0.05, 1.0, shape))
    weight = torch.from_numpy((rng.uniform(size=shape) > 0.3).astype(np.float64))
    return lum, weight


def _expected(lum, weight, s):
    """|s - 1| x the weighted mean of |log t - mean_w log t| (per image, pooled by weight): the loss of
    a relit whose log change is s times the truth's."""
    log_t = torch.log(lum)
    total = weight.sum((1, 2, 3), keepdim=True)
    centred = log_t - (log_t * weight).sum((1, 2, 3), keepdim=True) / total
    return abs(s - 1.0) * float((centred.abs() * weight).sum() / weight.sum())


def test_the_level_does_not_count_and_a_scaled_log_change_costs_its_shortfall():
    lum, weight = _truth()
    truth = _grey(lum)
    assert float(sun_response_loss(truth, truth, weight)) == pytest.approx(0.0, abs=1e-12)
    for k in (0.01, 0.5, 7.0):  # any exposure of the truth: the pattern is the same
        assert float(sun_response_loss(k * truth, truth, weight)) == pytest.approx(0.0, abs=1e-12)
    # lum in [0.05, 1] and lum^s lie above their floors (1 % of a mean <= 1), so the loss is exact: |s - 1| x the
    # truth's centred |log| (a relit lum^s is the photo's change scaled by s, as light_response's slope)
    for s in (0.0, 0.3, 1.0, 1.6):
        assert float(sun_response_loss(_grey(lum ** s), truth, weight)) == pytest.approx(
            _expected(lum, weight, s), rel=1e-9, abs=1e-12)


def test_black_truth_and_empty_images_stay_finite_and_count_for_nothing():
    lum, weight = _truth(1)
    lum[0, 0, 2:5, 2:5] = 0.0  # a cast shadow: the truth is black there
    truth = _grey(lum)
    relit = _grey(torch.from_numpy(np.random.default_rng(2).uniform(0.0, 1.0, lum.shape))).requires_grad_()
    loss = sun_response_loss(relit, truth, weight)
    loss.backward()
    assert math.isfinite(float(loss.detach())) and torch.isfinite(relit.grad).all()
    # below its floor (FLOOR x its own weighted mean) a relit pixel gets no gradient
    total = weight[0].sum()
    floor = FLOOR * float((relit.detach()[0, 0] * weight[0, 0]).sum() / total)
    dark = (relit.detach()[0, 0] < floor) & (weight[0, 0] > 0)
    assert float(relit.grad[0, :, dark].abs().sum()) == 0.0
    # pixels and images of weight 0 count for nothing
    wild = torch.where(weight > 0, truth, torch.full_like(truth, 1e6))
    assert float(sun_response_loss(wild, truth, weight)) == pytest.approx(0.0, abs=1e-12)
    empty = weight.clone()
    empty[1] = 0
    noisy = truth * torch.exp(0.2 * torch.from_numpy(np.random.default_rng(3).normal(size=truth.shape)))
    assert float(sun_response_loss(noisy, truth, empty)) == pytest.approx(
        float(sun_response_loss(noisy[:1], truth[:1], weight[:1])), rel=1e-12)


def test_suns_light_what_the_camera_sees_and_repeat_with_their_seed():
    rng = np.random.default_rng(0)
    draws = [random_sun_light(rng, 4) for _ in range(300)]
    # key_direction recovers a sun's direction to 1e-6 degrees (checked against sun_light's own angles)
    directions = np.array([key_direction(d) for d in draws])
    off_axis = np.degrees(np.arccos(np.clip(-directions[:, 1], -1, 1)))
    elevation = np.degrees(np.arcsin(np.clip(directions[:, 2], -1, 1)))
    assert off_axis.max() <= SUN_MAX_OFF_AXIS_DEG + 1e-3
    assert SUN_ELEVATION_DEG[0] - 1e-3 <= elevation.min() and elevation.max() <= SUN_ELEVATION_DEG[1] + 1e-3
    # drawn by the stated law (azimuth uniform, elevation uniform in its range, past the off-axis
    # limit redrawn): the share of side suns (40-140 degrees, the guard's) is that law's p ~ 0.81,
    # here from 400,000 draws of it, and 300 draws lie within 4 binomial standard deviations of it
    law = np.random.default_rng(1)
    az, el = np.radians(law.uniform(-180, 180, 400_000)), np.radians(law.uniform(*SUN_ELEVATION_DEG, 400_000))
    off = np.degrees(np.arccos(np.cos(az) * np.cos(el)))
    off = off[off <= SUN_MAX_OFF_AXIS_DEG]
    p = np.mean((off >= 40) & (off <= 140))
    side = np.mean((off_axis >= 40) & (off_axis <= 140))
    assert abs(side - p) <= 4 * math.sqrt(p * (1 - p) / len(draws))
    again = random_sun_light(np.random.default_rng(0), 4)
    np.testing.assert_array_equal(again, draws[0])


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    from model.samples.synthetic import write_analytic_dataset

    return write_analytic_dataset(tmp_path_factory.mktemp("analytic"), n_scenes=2, size=32, order=4,
                                  lights=("studio", "city"))


def test_training_draws_suns_only_when_asked_and_leaves_the_other_draws_alone(scenes):
    plain = data.TrainingScenes(scenes, 32, 4, seed=5)
    sunny = data.TrainingScenes(scenes, 32, 4, seed=5, sun_light=True)
    for i in range(len(plain)):
        a, b = plain.item(i, 1), sunny.item(i, 1)
        assert "sun_light" not in a and b["sun_light"].shape == b["light"].shape
        for key, value in a.items():
            if isinstance(value, torch.Tensor):
                assert torch.equal(value, b[key]), key
    # the loss on a batch with suns: finite, positive, and it asks for them when they are missing
    net = GeometryNet(sh_order=4, width=4, depth=2, decoder_width=4)
    batch = {k: torch.stack([sunny.item(i, 0)[k] for i in range(len(sunny))])
             for k, v in sunny.item(0, 0).items() if isinstance(v, torch.Tensor)}
    with torch.no_grad():
        terms = geometry_losses(net(batch["input"]), batch, {"sun_response": 1.0})
    assert math.isfinite(float(terms["sun_response"])) and float(terms["sun_response"]) > 0
    del batch["sun_light"]
    with pytest.raises(ValueError, match="sun_light"), torch.no_grad():
        geometry_losses(net(batch["input"]), batch, {"sun_response": 1.0})
