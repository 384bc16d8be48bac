"""Fuzzing the SH projection and the map recipe (relight.lighting.light.sh_light of a map) (Hypothesis; profile in fuzz_support).

Property: any array (any real dtype, shape, values including NaN, Inf,
negatives, subnormals and values near float32's maximum) gives finite
coefficients [(order+1)^2, 3] that match the float64 projection, or a
one-line ValueError; never NaN, another exception, or an overflow.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import example, given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from fuzz_support import accepted_share, fuzz_settings, new_case, run_case
from relight.lighting import envmap, light, sh, sh_projection

F32_MAX = float(np.finfo(np.float32).max)

_HUGE = [3e38, F32_MAX, 1e-45, 0.0]
_values = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, 1.0, -1.0, 1e-45, 3e38, F32_MAX, -F32_MAX, 1e39]),
    st.floats(0, 1e3),
)


@st.composite
def maps(draw):
    dtype = draw(st.sampled_from([np.float16, np.float32, np.float64, np.int32, np.uint8, np.int64]))
    shape = (draw(st.integers(1, 10)), draw(st.integers(1, 20)), draw(st.sampled_from([1, 3, 4])))
    shape = draw(st.sampled_from([shape, (shape[0], 2 * shape[0], shape[2]), shape[:2]]))
    if np.issubdtype(dtype, np.integer):
        info = np.iinfo(dtype)
        return draw(hnp.arrays(dtype, shape, elements=st.integers(int(info.min), int(info.max))))
    # half the maps finite (to reach the arithmetic), half with anything in them
    elements = _values if draw(st.booleans()) else st.one_of(st.floats(-1.0, 1e3), st.sampled_from(_HUGE))
    with np.errstate(over="ignore"):  # beyond float16/32: Inf, which the projection must refuse
        return draw(hnp.arrays(np.float64, shape, elements=elements)).astype(dtype)


def test_fuzz_projection():
    # maps() makes NaN, Inf, odd shapes and overflowing dtypes on purpose, with no branch
    # valid by construction: the floor is "some accepted"
    with accepted_share("sh_projection.project_equirect", 0.0):
        projection_case()


@given(maps(), st.integers(0, 8), st.sampled_from(["float32", "float64"]))
@fuzz_settings()
def projection_case(img, order, precision):
    new_case("test_fuzz_projection")
    coeffs = run_case("sh_projection.project_equirect",
                      lambda: sh_projection.project_equirect(img, order, precision=precision))
    if coeffs is None:
        return
    assert coeffs.shape == ((order + 1) ** 2, 3) and coeffs.dtype == np.float64
    assert np.all(np.isfinite(coeffs))
    # against float64 throughout: a float32 sum of W terms errs by at most ~W * 2^-24 of the
    # sum of |terms|, and rounding a texel to float32 by 2^-24 of it or half the smallest
    # subnormal (7e-46); both weighted by at most 4 pi max|Y|, max|Y| <= sqrt((2N+1) / (4 pi))
    exact = sh_projection.project_equirect(img, order, precision="float64")
    largest = float(np.max(np.maximum(np.asarray(img[..., :3], dtype=np.float64), 0)))
    weight = 4 * np.pi * math.sqrt((2 * order + 1) / (4 * np.pi))
    np.testing.assert_allclose(coeffs, exact, rtol=0, atol=weight * (1e-5 * largest + 7e-46) + 1e-300)


def test_fuzz_map_light():
    with accepted_share("light.map_light", 0.0):  # maps() as above: "some accepted"
        map_light_case()


@given(maps(), st.integers(0, 6), st.floats(-1e6, 1e6), st.booleans(),
       st.floats(1e-6, 1e6))
@example(np.linspace(0.1, 2.0, 4 * 8 * 3).reshape(4, 8, 3), 2, 30.0, True, 0.8)  # an ordinary map: accepted
@example(np.zeros((1, 3), np.float16), 0, 0.0, True, 0.8)  # issue 40: a black SH light "normalized" to black
@example(np.array([[0.3, 0.2, 0.1], [0.0, 1e30, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]), 1, 0.0, True, 1e6)
@fuzz_settings()
def map_light_case(img, order, rotation, normalize, target):
    new_case("test_fuzz_map_light")
    coeffs = run_case("light.map_light", lambda: light.sh_light(img, order, rotation_deg=rotation,
                                                                normalize=normalize, target=target))
    if coeffs is None:
        return
    assert coeffs.shape == ((order + 1) ** 2, 3) and np.all(np.isfinite(coeffs))
    if normalize:  # scaled to the target mean luminance, whatever the map's level
        np.testing.assert_allclose(sh.mean_luminance(coeffs), target, rtol=1e-9)
    else:  # a rotation about Z keeps each band's energy
        if np.ndim(img) == 2:  # [m, 3]: SH coefficients, light already: fitted to the order, not projected
            base = light.fit_order(img, (order + 1) ** 2)
        else:
            base = sh_projection.project_equirect(envmap.validate_equirect(img).pixels, order)
        for l in range(order + 1):
            band = slice(l * l, (l + 1) * (l + 1))
            np.testing.assert_allclose(np.linalg.norm(coeffs[band], axis=0), np.linalg.norm(base[band], axis=0),
                                       rtol=1e-9, atol=1e-12 * np.abs(base).max())


def test_sh_light_scales_sh_coefficients_only_when_asked_and_refuses_a_black_light():
    """Issue 40: normalize=True on a light given as SH was dropped without a word (a one-row
    black array came back black). Asked for, it is done or refused; not asked, SH is as it is."""
    L = np.random.default_rng(5).normal(0, 0.3, (9, 3))
    L[0] = [1.0, 0.9, 0.8]
    np.testing.assert_array_equal(light.sh_light(L, 2), L)  # default: light already, as it is
    np.testing.assert_array_equal(light.sh_light(L, 2, normalize=False), L)
    scaled = light.sh_light(L, 2, normalize=True, target=0.5)
    np.testing.assert_allclose(sh.mean_luminance(scaled), 0.5, rtol=1e-9)
    np.testing.assert_allclose(scaled / L, np.full_like(L, scaled[0, 0] / L[0, 0]), rtol=1e-9)
    for black in (np.zeros((1, 3), np.float16), np.zeros((4, 3))):
        try:
            light.sh_light(black, 0, normalize=True)
        except ValueError as exc:
            assert "cannot normalize" in str(exc)
        else:
            raise AssertionError("a black SH light was 'normalized' without an error")
