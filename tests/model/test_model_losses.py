"""Every loss term against a value computed by hand on a 2-pixel, order-0 example."""

import itertools
import math

import pytest
import torch

from model.training.losses import LossWeights, log_loss, masked_l1, relight_losses

# masked means divide by sum(alpha) * C + 1e-8 with sum(alpha) * C >= 1 here, so the
# computed values differ from the exact ones by at most ~1e-8 relative (+ float32 round-off ~1e-7)
APPROX = dict(rel=1e-6, abs=1e-6)


def _t(values):
    return torch.tensor(values, dtype=torch.float32)


def _example():
    """B=1, n=1, H=1, W=2; pixel 0 is the person (alpha 1), pixel 1 background (alpha 0)."""
    pred = {
        "albedo": _t([[[[0.25, 1.0]], [[0.5, 1.0]], [[1.0, 1.0]]]]),
        "transport_pos": _t([[[[0.1, 5.0]]]]), "transport_neg": _t([[[[0.3, 0.0]]]]),
        "residual_pos": _t([[[[0.1, 2.0]]]]), "residual_neg": _t([[[[0.0, 0.0]]]]),
        "light_pos": _t([[[2.0, 1.5, 1.0]]]), "light_neg": _t([[[0.0, 0.5, 0.5]]]),
        "alpha": _t([[[[0.75, 0.5]]]]),
    }
    for base in ("transport", "residual", "light"):
        pred[base] = pred[base + "_pos"] - pred[base + "_neg"]
    batch = {
        "albedo": _t([[[[0.5, 0.0]], [[0.5, 0.0]], [[0.5, 0.0]]]]),
        "transport": _t([[[[0.4, 0.0]]]]),
        "light": _t([[[1.0, 2.0, -1.0]]]),
        "alpha": _t([[[[1.0, 0.0]]]]),
        "image": _t([[[[0.3, 9.0]], [[0.5, 9.0]], [[0.1, 9.0]]]]),
        "target_light": _t([[[0.5, 0.5, 0.5]]]),
        "target_image": _t([[[[0.2, 9.0]], [[0.2, 9.0]], [[0.2, 9.0]]]]),
    }
    return pred, batch


def f(x):
    return math.log(1.0 + abs(x))


def _mean(xs):
    return sum(xs) / len(xs)


# the example's person pixel, as plain numbers
RHO_P, RHO_G = [0.25, 0.5, 1.0], [0.5, 0.5, 0.5]
T_P, T_G, E_P = -0.2, 0.4, 0.1
L_P, L_G, L_B = [2.0, 1.0, 0.5], [1.0, 2.0, -1.0], [0.5, 0.5, 0.5]
LP_POS, LP_NEG = [2.0, 1.5, 1.0], [0.0, 0.5, 0.5]
IMG_G, TARGET = [0.3, 0.5, 0.1], [0.2, 0.2, 0.2]


def expected_terms():
    e = {}
    e["albedo"] = _mean([abs(p - g) for p, g in zip(RHO_P, RHO_G)])  # 0.25
    # signed, positive part (0.1 vs relu(0.4)), negative part (0.3 vs relu(-0.4) = 0)
    e["transport"] = abs(T_P - T_G) + abs(0.1 - 0.4) + abs(0.3 - 0.0)  # 1.2
    gpos, gneg = [max(x, 0) for x in L_G], [max(-x, 0) for x in L_G]
    e["light"] = (_mean([abs(p - g) for p, g in zip(L_P, L_G)])
                  + _mean([abs(p - g) for p, g in zip(LP_POS, gpos)])
                  + _mean([abs(p - g) for p, g in zip(LP_NEG, gneg)]))  # 7/3
    e["log"] = ((f(T_P) - f(T_G)) ** 2 + (f(0.1) - f(0.4)) ** 2 + (f(0.3) - f(0.0)) ** 2
                + _mean([(f(p) - f(g)) ** 2 for p, g in zip(L_P, L_G)])
                + _mean([(f(p) - f(g)) ** 2 for p, g in zip(LP_POS, gpos)])
                + _mean([(f(p) - f(g)) ** 2 for p, g in zip(LP_NEG, gneg)]))
    s_gt = [T_G * l for l in L_G]
    e["shading"] = sum(_mean([abs(t * l - s) for l, s in zip(L, s_gt)])
                       for t, L in ((T_P, L_P), (T_P, L_G), (T_G, L_P)))  # 0.7 + 0.8 + 1.4/3
    e["image"] = sum(_mean([abs(r * t * l + E_P * l - g) for r, l, g in zip(rho, L, IMG_G)])
                     for rho, t, L in itertools.product((RHO_P, RHO_G), (T_P, T_G), (L_P, L_G)))
    e["matte"] = (abs(0.75 - 1.0) + abs(0.5 - 0.0)) / 2  # every pixel, 0.375
    e["relight"] = _mean([abs(r * T_P * l + E_P * l - g) for r, l, g in zip(RHO_P, L_B, TARGET)])  # 0.625/3
    return e


def test_every_term_equals_hand_computed_value():
    pred, batch = _example()
    terms = relight_losses(pred, batch, LossWeights())
    expected = expected_terms()
    assert expected["shading"] == pytest.approx(0.7 + 0.8 + 1.4 / 3)  # the arithmetic in the docstring
    for name, value in expected.items():
        assert float(terms[name]) == pytest.approx(value, **APPROX), name
    assert float(terms["total"]) == pytest.approx(sum(expected.values()), **APPROX)


def test_weights_scale_terms_and_ablations_drop_parts():
    pred, batch = _example()
    expected = expected_terms()
    weights = LossWeights(image=0.5, log=0.0, relight=2.0)
    total = float(relight_losses(pred, batch, weights)["total"])
    want = sum(expected.values()) - 0.5 * expected["image"] - expected["log"] + expected["relight"]
    assert total == pytest.approx(want, **APPROX)
    # without the decomposition only the signed maps are supervised
    terms = relight_losses(pred, batch, LossWeights(), decomposition=False)
    assert float(terms["transport"]) == pytest.approx(abs(T_P - T_G), **APPROX)
    assert float(terms["light"]) == pytest.approx(_mean([abs(p - g) for p, g in zip(L_P, L_G)]), **APPROX)
    with pytest.raises(ValueError, match="unknown loss weights"):
        LossWeights.from_dict({"albedo": 1.0, "typo": 2.0})


def test_tstar_terms():
    """T* = rho * T per channel; its image under L is T*.L (no E, no albedo term)."""
    pred, batch = _example()
    tstar_p = [0.3, -0.1, 0.2]  # per-channel T* of the person pixel (n = 1)
    pred["transport"] = _t([[[[v, 0.0]] for v in tstar_p]])
    pred["transport_pos"], pred["transport_neg"] = pred["transport"].relu(), (-pred["transport"]).relu()
    terms = relight_losses(pred, batch, LossWeights(), decomposition=False, tstar=True)
    tstar_g = [r * T_G for r in RHO_G]
    assert float(terms["albedo"]) == 0.0 and float(terms["shading"]) == 0.0
    assert float(terms["transport"]) == pytest.approx(_mean([abs(p - g) for p, g in zip(tstar_p, tstar_g)]), **APPROX)
    want_image = sum(_mean([abs(t * l - g) for t, l, g in zip(T, L, IMG_G)])
                     for T, L in itertools.product((tstar_p, tstar_g), (L_P, L_G)))
    assert float(terms["image"]) == pytest.approx(want_image, **APPROX)
    assert float(terms["relight"]) == pytest.approx(_mean([abs(t * l - g) for t, l, g in zip(tstar_p, L_B, TARGET)]), **APPROX)


def test_log_loss_finite_for_zeros_and_huge_values_with_finite_gradients():
    x = torch.tensor([0.0, -0.0, 1e30, -3e38, 5.0], requires_grad=True)
    y = torch.tensor([0.0, 1e30, 0.0, 3e38, -5.0])
    loss = log_loss(x[None, :, None, None], y[None, :, None, None])
    loss.backward()
    assert torch.isfinite(loss) and torch.isfinite(x.grad).all()
    # log1p(1e30) = 30 ln 10 = 69.08; (0 - 69.08)^2 twice, the rest 0 -> mean over 5
    assert float(loss.detach()) == pytest.approx(2 * (30 * math.log(10)) ** 2 / 5, rel=1e-5)


def test_masked_l1_with_empty_mask_is_zero_not_nan():
    value = masked_l1(torch.ones(1, 3, 2, 2), torch.zeros(1, 3, 2, 2), torch.zeros(1, 1, 2, 2))
    assert float(value) == 0.0
