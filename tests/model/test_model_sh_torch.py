"""model.networks.sh_torch equals relight's numpy rendering layer and SH ops."""

import numpy as np
import pytest
import torch

from model.networks import sh_torch
from relight.network import prt
from relight.lighting import sh, sh_rotation

# float32 torch vs float64 numpy: products of O(1) values summed over n <= 25 terms;
# float32 relative round-off ~6e-8 per op, so 1e-5 relative / 1e-5 absolute is ample
TOL = dict(rtol=1e-5, atol=1e-5)


def _random(order=4, h=5, w=7, seed=0):
    rng = np.random.default_rng(seed)
    n = sh.num_coeffs(order)
    T = rng.normal(size=(h, w, n)) * 0.3
    E = rng.normal(size=(h, w, n)) * 0.05
    L = rng.normal(size=(n, 3))
    albedo = rng.uniform(size=(h, w, 3))
    return albedo, T, E, L


def _chw(x):
    return torch.from_numpy(np.moveaxis(x, -1, 0)[None].astype(np.float32))


def test_shading_and_render_equal_numpy():
    albedo, T, E, L = _random()
    Lt = torch.from_numpy(L[None].astype(np.float32))
    got_s = sh_torch.shading(_chw(T), Lt)[0].permute(1, 2, 0).numpy()
    np.testing.assert_allclose(got_s, prt.shading(T, L), **TOL)
    got_r = sh_torch.render(_chw(albedo), _chw(T), _chw(E), Lt)[0].permute(1, 2, 0).numpy()
    np.testing.assert_allclose(got_r, prt.render(albedo, T, E, L), **TOL)
    got_r0 = sh_torch.render(_chw(albedo), _chw(T), None, Lt)[0].permute(1, 2, 0).numpy()
    np.testing.assert_allclose(got_r0, prt.render(albedo, T, None, L), **TOL)


def test_shading_rejects_mismatched_orders():
    with pytest.raises(ValueError, match="coefficients"):
        sh_torch.shading(torch.zeros(1, 9, 2, 2), torch.zeros(1, 25, 3))


def test_tstar_shading_equals_per_channel_render():
    """T* = albedo_c * T + E per channel gives back render(albedo, T, E, L)."""
    albedo, T, E, L = _random(order=2)
    n = T.shape[-1]
    tstar = albedo[..., :, None] * T[..., None, :] + E[..., None, :]  # [H, W, 3, n]
    tstar_chw = torch.from_numpy(tstar.reshape(*tstar.shape[:2], 3 * n).transpose(2, 0, 1)[None].astype(np.float32))
    got = sh_torch.shading_tstar(tstar_chw, torch.from_numpy(L[None].astype(np.float32)))
    np.testing.assert_allclose(got[0].permute(1, 2, 0).numpy(), prt.render(albedo, T, E, L), **TOL)


def test_rotation_equals_numpy_and_preserves_shading_of_rotated_transport():
    _, T, _, L = _random()
    R = sh_rotation.z_rotation(73.0)
    M = sh_torch.rotation_matrix(R, 4)
    got = sh_torch.rotate_light(torch.from_numpy(L[None].astype(np.float32)), M[None])[0].numpy()
    np.testing.assert_allclose(got, sh_rotation.rotate(L, R), **TOL)
    # rotating both light and transport by the same R leaves T . L unchanged (M is orthogonal)
    Mn = sh_rotation.rotation_matrix(R, 4)
    np.testing.assert_allclose(prt.shading(T @ Mn.T, Mn @ L), prt.shading(T, L), rtol=1e-10, atol=1e-10)


def test_network_input_equals_numpy():
    rng = np.random.default_rng(1)
    image = rng.uniform(-0.2, 1.5, size=(6, 4, 3))  # out-of-range values are clipped by both
    mask = rng.uniform(size=(6, 4))
    got = sh_torch.to_network_input(_chw(image), torch.from_numpy(mask[None, None].astype(np.float32)))
    np.testing.assert_allclose(got[0].permute(1, 2, 0).numpy(), prt.to_network_input(image, mask), **TOL)
    got_nomask = sh_torch.to_network_input(_chw(image))[0].permute(1, 2, 0).numpy()
    np.testing.assert_allclose(got_nomask, prt.to_network_input(image), **TOL)


def test_mean_luminance_equals_numpy():
    _, _, _, L = _random()
    got = sh_torch.mean_luminance(torch.from_numpy(L[None]))
    assert float(got[0]) == pytest.approx(sh.mean_luminance(L), rel=1e-12)
