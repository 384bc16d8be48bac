"""model.networks.physics: the torch physics of the geometry-first model (SH lobe transport,
visibility, light fit, photo-consistent albedo) against the core's numpy maths and
the farm's ray-cast bake."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from farm.rendering import bake
from farm.synthesis.meshops import vertex_normals
from model.networks import physics
from relight.imaging import colour
from relight.network import prt
from relight.lighting import sh

trimesh = pytest.importorskip("trimesh")


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@pytest.mark.parametrize("order", [1, 2, 4, 6])
def test_sh_basis_equals_the_core_basis(order):
    dirs = _unit(np.random.default_rng(order).normal(size=(500, 3)))
    ours = physics.sh_basis(torch.tensor(dirs), order, dim=-1).numpy()
    # float64 in, float64 out: the same recurrences give the same values to rounding
    assert np.abs(ours - sh.sh_basis(dirs, order)).max() < 1e-12


def test_lobe_transport_equals_lambert_transport_times_visibility():
    rng = np.random.default_rng(1)
    normals = _unit(rng.normal(size=(2, 5, 7, 3)))
    vis = rng.uniform(0, 1, size=(2, 5, 7, 1))
    t = physics.lobe_transport(torch.tensor(normals).permute(0, 3, 1, 2), torch.tensor(vis).permute(0, 3, 1, 2), 4)
    expected = prt.lambert_transport(normals, 4) * vis
    assert np.abs(t.permute(0, 2, 3, 1).numpy() - expected).max() < 1e-12
    # and the inverse maps recover what went in
    assert np.abs(physics.visibility_from_transport(t).numpy() - vis.transpose(0, 3, 1, 2)).max() < 1e-12
    from model.scoring.geometry_diagnostics import transport_normal  # the evaluation reads normals off any model's T so

    back = np.stack([transport_normal(t[i].numpy()) for i in range(2)])
    assert np.abs(back - normals).max() < 1e-6


def icosphere(subdivisions, radius=1.0, centre=(0.0, 0.0, 0.0)):
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    v = np.asarray(m.vertices, dtype=np.float64) + np.asarray(centre)
    f = np.asarray(m.faces, dtype=np.int64)
    return v, f, vertex_normals(v, f)


def test_parametric_transport_from_true_normal_and_visibility_matches_the_bake():
    """The lobe v * A_l/pi * Y_lm(n) against a ray-cast bake with an occluder.

    With v = integral of V cos / pi (the bake's DC ratio) the difference per
    coefficient is integral of (1 - V) cos Y_lm / pi - (1 - v) integral of
    cos Y_lm / pi, so |T - T_lobe| <= 2 Ymax (1 - v), plus the bake's
    quadrature error (8 pi Ymax / S, tests/farm/test_transport_bake.py) on both
    terms: exact where nothing is occluded, bounded where something is.
    """
    order, directions = 4, 1024
    sv, sf, sn = icosphere(3, radius=0.5)
    bv, bf, bn = icosphere(2, radius=0.35, centre=(0.8, 0.0, 0.1))
    v = np.concatenate([sv, bv])
    f = np.concatenate([sf, bf + len(sv)])
    n = np.concatenate([sn, bn])
    baked = bake.bake_transport(v, f, n, order, directions, rng=np.random.default_rng(0)).transport[: len(sv)]
    ymax = float(np.abs(sh.sh_basis(bake.fibonacci_directions(4096), order)).max())
    quad = 8.0 * math.pi * ymax / directions
    vis = np.clip(baked[:, 0] / physics.UNOCCLUDED_DC, 0.0, 1.0)
    lobe = prt.lambert_transport(sn, order) * vis[:, None]
    err = np.abs(baked - lobe).max(axis=1)
    bound = 2.0 * ymax * (1.0 - vis) + 2.0 * quad
    assert np.all(err <= bound), float((err - bound).max())
    occluded = vis < 0.9
    assert occluded.sum() > 20  # the occluder really shadows part of the sphere
    free = vis > 1.0 - quad
    assert free.sum() > 100 and err[free].max() < 3.0 * quad


def test_solve_spd_matches_numpy_and_exports_only_elementwise_ops():
    rng = np.random.default_rng(2)
    a = rng.normal(size=(4, 3, 25, 40))
    m = a @ a.swapaxes(-1, -2) + 0.1 * np.eye(25)
    rhs = rng.normal(size=(4, 3, 25, 1))
    x = physics.solve_spd(torch.tensor(m), torch.tensor(rhs)).numpy()
    assert np.abs(x - np.linalg.solve(m, rhs)).max() < 1e-8 * np.abs(x).max()


def _scene(rng, size=24, order=4):
    normals = _unit(rng.normal(size=(1, size, size, 3)) + np.array([0.0, -1.5, 0.0]))
    vis = rng.uniform(0.5, 1.0, size=(1, size, size, 1))
    albedo = rng.uniform(0.1, 0.9, size=(1, size, size, 3))
    T = prt.lambert_transport(normals, order) * vis
    to_t = lambda x: torch.tensor(x).permute(0, 3, 1, 2)
    return to_t(normals), to_t(vis), to_t(albedo), to_t(T)


def test_fit_light_recovers_the_true_light_in_the_directions_the_pixels_see():
    rng = np.random.default_rng(3)
    _, _, albedo, T = _scene(rng)
    light = torch.tensor(sh.normalize_reference(rng.normal(size=(25, 3)) * 0.3 + np.eye(25, 3) * 3, 0.8)[0])[None]
    photo = albedo * torch.einsum("bnhw,bnc->bchw", T, light)
    weight = torch.ones_like(photo[:, :1])
    ridge = 1e-6
    fitted = physics.fit_light(T, albedo, photo, weight, torch.zeros_like(light), ridge=ridge)
    residual = albedo * torch.einsum("bnhw,bnc->bchw", T, fitted) - photo
    # The ridge optimum costs no more than the true light does: |A x - b|^2 <= lam |L_c|^2
    # (the prior is 0), with lam = ridge * trace(A^T A) / n (model.networks.physics.fit_light).
    design = (T[:, None] * albedo[:, :, None]).reshape(3, 25, -1)          # [3, n, P]
    lam = ridge * (design ** 2).sum(dim=(1, 2)) / 25
    bound = torch.sqrt(lam * (light[0] ** 2).sum(dim=0))
    assert torch.all(residual.reshape(3, -1).norm(dim=1) <= bound * (1 + 1e-9))
    assert float(residual.abs().max()) < 1e-3 * float(photo.max())
    # a big ridge keeps the prior instead
    stuck = physics.fit_light(T, albedo, photo, weight, light * 0.5, ridge=1e6)
    assert (stuck - light * 0.5).abs().max() < 1e-4 * light.abs().max()


def test_photo_consistent_albedo_is_photo_over_shading_with_the_shading_floored_in_shadow():
    photo = torch.tensor([0.4, 0.002, 0.3]).reshape(1, 3, 1, 1).expand(1, 3, 2, 2).clone()
    shading = torch.ones(1, 3, 2, 2)
    shading[..., 0, 0] = 0.01   # deep shadow: below reliable * mean
    w = torch.ones(1, 1, 2, 2)
    out = physics.photo_consistent_albedo(photo, shading, w, reliable=0.25)
    assert torch.allclose(out[..., 1, 1], photo[..., 1, 1])   # lit: photo / 1
    mean = (3 * 1.0 + 0.01) / 4                                # the weighted mean shading
    # (the code's 1e-4 guard in the mean's denominator moves it by 2.5e-5 relative)
    assert torch.allclose(out[..., 0, 0], (photo[..., 0, 0] / (0.25 * mean)).clamp(0, 1), rtol=1e-4)
    assert float(out.min()) >= 0.0 and float(out.max()) <= 1.0
    # a black fit does not make every pixel's floor ~0: the mean is at least min_mean
    dark = physics.photo_consistent_albedo(photo, shading * 1e-6, w, reliable=0.25, min_mean=0.08)
    assert torch.allclose(dark, (photo / (0.25 * 0.08)).clamp(0, 1), rtol=1e-4)


def test_srgb_decode_inverts_the_network_encoding():
    lin = np.random.default_rng(4).uniform(0, 1, size=(1, 3, 8, 8))
    enc = colour.srgb_encode(lin) * 2 - 1
    back = physics.linear_from_network_input(torch.tensor(enc)).numpy()
    assert np.abs(back - lin).max() < 1e-12
