"""Adaptive SH order (relight.lighting.sh_adaptive): the smallest order whose irradiance energy holds 99%."""

import math

import numpy as np
import pytest

from relight.lighting import sh, sh_adaptive, sh_projection


def _coeffs_with_bands(order, band_values):
    c = np.zeros((sh.num_coeffs(order), 3))
    for l, value in band_values.items():
        c[l * l + l] = value  # the zonal (m = 0) coefficient of band l
    return c


def test_constant_light_needs_order_zero():
    c = _coeffs_with_bands(8, {0: 1.0})
    assert sh_adaptive.required_order(c) == 0


def test_energy_is_clamped_cosine_weighted():
    c = _coeffs_with_bands(8, {0: 1.0, 1: 1.0, 2: 1.0})
    e = sh_adaptive.band_irradiance_energy(c)
    # three channels of value 1: 3 A_l^2 for l = 0, 1, 2 and nothing above
    expected = 3 * np.array([math.pi, 2 * math.pi / 3, math.pi / 4]) ** 2
    np.testing.assert_allclose(e[:3], expected, rtol=1e-12)
    assert np.all(e[3:] == 0)


def test_odd_bands_above_one_add_nothing():
    # A_3 = A_5 = 0: band-3 and band-5 content, however large, gives no irradiance, so a
    # light of band 0 plus such content needs order 0, as the constant light alone does.
    c = _coeffs_with_bands(8, {0: 1.0, 3: 100.0, 5: 100.0})
    e = sh_adaptive.band_irradiance_energy(c)
    assert e[3] == 0.0 and e[5] == 0.0 and e[0] == pytest.approx(3 * math.pi**2, rel=1e-12)
    assert sh_adaptive.required_order(c, 1.0) == 0


def test_threshold_picks_the_first_order_reaching_it():
    # band energies per channel: pi^2, (2pi/3)^2, (pi/4)^2, 0, (pi/24)^2 -> bands 0..2
    # hold 1 - (pi/24)^2 / 14.89 = 99.885% of the total; band 4 holds the rest.
    c = _coeffs_with_bands(8, {0: 1.0, 1: 1.0, 2: 1.0, 4: 1.0})
    e = sh_adaptive.band_irradiance_energy(c)
    frac = np.cumsum(e) / e.sum()
    np.testing.assert_allclose(frac[2], 1 - (math.pi / 24) ** 2 / e[:5].sum() * 3, rtol=1e-12)
    assert sh_adaptive.required_order(c, 0.99) == 2
    assert sh_adaptive.required_order(c, 0.9995) == 4
    assert sh_adaptive.required_order(c, frac[1]) == 1
    assert sh_adaptive.required_order(c, 1.0) == 4


def test_real_map_order_is_the_smallest_that_reaches_the_fraction():
    """On a real map each chosen order holds the fraction and the one below it does not;
    the whole energy needs band 8 (A_8 != 0 and the map has band-8 content)."""
    from relight.lighting import envmap, presets

    env = envmap.load_equirect(presets.preset_path("sunset"))
    c = sh_projection.project_equirect(env.pixels, 8)
    e = sh_adaptive.band_irradiance_energy(c)
    captured = np.cumsum(e) / e.sum()
    fractions = (0.9, 0.99, 0.999, 0.9999, 1.0)
    orders = [sh_adaptive.required_order(c, f) for f in fractions]
    for f, n in zip(fractions, orders):
        assert captured[n] >= f - 1e-12, (f, n)
        assert n == 0 or captured[n - 1] < f - 1e-12, (f, n)
    assert orders == sorted(orders) and orders[-1] == 8 and e[8] > 0


@pytest.mark.parametrize("bad", [0.0, -0.1, 1.5, float("nan"), "0.9"])
def test_bad_fraction_is_rejected(bad):
    with pytest.raises(ValueError, match="fraction"):
        sh_adaptive.required_order(np.ones((25, 3)), bad)


def test_black_light_needs_nothing():
    assert sh_adaptive.required_order(np.zeros((81, 3))) == 0
