"""Per-photo refinement of the light (relight.network.refine) and test-time augmentation (relight.network.tta)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from relight.network import refine as rf
from relight.lighting import sh, sh_rotation
from relight.network import tta

from refine_support import ORDER, lobe_light, synthetic


def test_mirror_signs_are_the_parity_of_each_basis_function_in_x():
    signs = tta.mirror_x(ORDER)
    rng = np.random.default_rng(1)
    dirs = rng.normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    np.testing.assert_allclose(sh.sh_basis(dirs * [-1, 1, 1], ORDER), sh.sh_basis(dirs, ORDER) * signs, atol=1e-12)
    # band 1 is (y, z, x) up to constants: only the x function is odd
    assert signs[:4].tolist() == [1, 1, 1, -1]
    # a light from camera-right mirrored comes from camera-left
    right = lobe_light([1, 0, 0], [1, 1, 1], 0.0)
    np.testing.assert_allclose(right * signs[:, None], lobe_light([-1, 0, 0], [1, 1, 1], 0.0), atol=1e-12)


def test_refinement_lowers_the_photo_residual_monotonically_and_recovers_the_light():
    light_true = lobe_light([0.8, -1.0, 0.6], [1.0, 0.85, 0.7], 0.3)
    # the estimate: the same light turned 50 degrees about Z (DC, the colour and level, right)
    light_start = sh_rotation.rotate(light_true, sh_rotation.z_rotation(50.0))
    d, albedo, transport, disk = synthetic(light_true, light_start)
    # exact transport: a weak pull toward the start lets the photo decide
    refined, report = rf.refine(d, 12, ridge=0.03)
    assert report.iterations >= 2
    residuals = np.array(report.residuals)
    assert np.all(np.diff(residuals) <= 0), residuals
    assert residuals[-1] < 0.5 * residuals[0]
    # the person's mean shading per channel (the albedo's level and colour) is kept: log-gradients
    # cannot see it (float32 light: relative rounding ~1e-7 per term of the 25-term mean)
    w = d.alpha.reshape(-1, 1).astype(np.float64)
    t = transport.reshape(-1, transport.shape[-1]).astype(np.float64)

    def mean_shading(light):
        return (w * (t @ np.asarray(light, np.float64))).sum(axis=0) / w.sum()

    np.testing.assert_allclose(mean_shading(refined.light), mean_shading(light_start), rtol=1e-5)
    # the seen bands (0-2: the Lambertian lobe filters band 3 out, band 4 to 1/16), each light
    # brought to the true mean shading (the level and colour the gradients cannot see), move
    # toward the truth
    seen = slice(1, 9)

    def pattern(light):
        return np.asarray(light, np.float64) * (mean_shading(light_true) / mean_shading(light))

    before = np.linalg.norm(pattern(light_start)[seen] - light_true[seen])
    after = np.linalg.norm(pattern(refined.light)[seen] - light_true[seen])
    assert after < 0.25 * before, (before, after)
    # and relighting to another light gets closer to the truth
    light_b = lobe_light([-1.0, -0.3, 0.2], [0.7, 0.8, 1.0], 0.2)
    truth = albedo * np.maximum(transport @ light_b, 0.0)
    inside = disk & (d.alpha > 0)

    def error(decomposition):
        return float(np.mean((decomposition.relit_at_working_size(light_b) - truth)[inside] ** 2))

    assert error(refined) < 0.5 * error(d)


def test_refinement_off_and_bad_iterations():
    light = lobe_light([0, -1, 0], [1, 1, 1], 0.2)
    d, *_ = synthetic(light, light)
    same, report = rf.refine(d, 0)
    assert same is d and report.stopped == "off" and report.as_dict()["iterations"] == 0
    for bad in (-1, 1.5, "3", None):
        with pytest.raises(ValueError, match="iterations"):
            rf.refine_light(d.transport, d.photo_working, d.alpha, d.light, bad)


def test_refinement_keeps_a_right_light():
    """Started at the truth, the fit has nothing to correct: only the albedo edge, which the
    Cauchy loss all but ignores, pulls at it, so the light moves by under 2% of the error of
    a light turned 50 degrees, and the objective does not rise."""
    light = lobe_light([0.5, -1, 0.4], [1, 0.9, 0.8], 0.3)
    d, *_ = synthetic(light, light)
    refined, report = rf.refine(d, 8)
    assert report.residuals[-1] <= report.residuals[0]
    seen = slice(1, 9)
    turned = np.linalg.norm(sh_rotation.rotate(light, sh_rotation.z_rotation(50.0))[seen] - light[seen])
    assert np.linalg.norm(refined.light[seen] - light[seen]) < 0.02 * turned


@pytest.mark.parametrize("kind", ["black", "white", "single colour", "backlit", "tiny matte"])
def test_refinement_and_augmentation_stay_finite_on_extreme_photos(kind):
    light = lobe_light([0.2, -1, 0.3], [1, 1, 1], 0.3)
    d, albedo, transport, disk = synthetic(light, light)
    photo = d.photo_working.copy()
    alpha = d.alpha
    if kind == "black":
        photo[:] = 0.0
    elif kind == "white":
        photo[:] = 1.0
    elif kind == "single colour":
        photo[:] = [0.4, 0.1, 0.05]
    elif kind == "backlit":  # the light behind the person: the seen side is lit only by the ambient
        back = lobe_light([0, 1, 0], [1, 1, 1], 0.01)
        photo = (albedo * np.maximum(transport @ back, 0.0) * disk[..., None]).astype(np.float32)
    elif kind == "tiny matte":
        alpha = np.zeros_like(alpha)
        alpha[30:33, 30:33] = 1.0
    d = dataclasses.replace(d, photo=photo, photo_working=photo, alpha=alpha, network_alpha=alpha)
    refined, report = rf.refine(d, 8)
    assert np.all(np.isfinite(refined.light)) and np.all(np.isfinite(refined.albedo))
    assert np.all(np.isfinite(report.residuals))
    assert all(b <= a for a, b in zip(report.residuals, report.residuals[1:]))
    relit = refined.relight(lobe_light([1, -1, 0], [1, 1, 1], 0.2))
    assert np.all(np.isfinite(relit)) and relit.min() >= 0.0
    if kind == "tiny matte":
        assert report.stopped == "no pixels" and refined is d


def test_average_of_a_run_with_its_own_mirror_image_is_mirror_symmetric():
    """Averaging a decomposition with its mirrored twin (as the network would answer a
    mirrored photo if it were equivariant) gives back the same transport and light: the
    flip back and the coefficient signs are right."""
    light = lobe_light([0.6, -1, 0.2], [1, 0.9, 0.8], 0.3)
    d, *_ = synthetic(light, light)
    signs = tta.mirror_x(ORDER)
    twin = tta._Run(np.ascontiguousarray(d.transport[:, ::-1] * signs), d.light * signs[:, None], ORDER,
                    d.working_size)
    averaged = tta.average(d, [(twin, True)])
    np.testing.assert_allclose(averaged.transport, d.transport, atol=1e-6)
    np.testing.assert_allclose(averaged.light, d.light, atol=1e-6)
    # a twin made without the signs is not the same photo: the average would differ
    wrong = tta._Run(np.ascontiguousarray(d.transport[:, ::-1]), d.light, ORDER, d.working_size)
    assert np.abs(tta.average(d, [(wrong, True)]).light - d.light).max() > 1e-2


def test_augment_refuses_bad_augmentations():
    light = lobe_light([0, -1, 0], [1, 1, 1], 0.2)
    d, *_ = synthetic(light, light)
    for bad in ([(1.0,)], [(0.1, True)], [(1.0, "yes")], [("1", True)], [1.0]):
        with pytest.raises(ValueError, match="augmentations"):
            tta.augment(None, d, bad)


class _Answers:
    """A stand-in network for relight.network.tta.augment: every run answers the same transport (on
    its own grid, flipped for a mirrored crop so that it is the same scene) and `light`."""

    def __init__(self, d, light):
        self.d, self.light, self.calls = d, light, 0

    def run_crop(self, crop, matte):
        self.calls += 1
        from relight.imaging.resample import resize_linear

        h, w = crop.shape[:2]
        t = self.d.transport if (h, w) == self.d.working_size else resize_linear(self.d.transport, h, w)
        mirrored = not np.array_equal(crop, self.d.photo_working) and (h, w) == self.d.working_size
        signs = tta.mirror_x(ORDER)
        return {"transport": t[:, ::-1] * signs if mirrored else t,
                "light": self.light * signs[:, None] if mirrored else self.light}


def test_augmentation_stops_after_the_first_run_only_when_it_agrees():
    """Only what the photo needs: with stop_when_agreed the runs after the first are skipped
    when the first's shading is within that of the network's own (relative RMS over the
    matte, tta.disagreement), and all run when it is not."""
    light = lobe_light([0, -1, 0], [1, 1, 1], 0.2)
    d, *_ = synthetic(light, light)
    assert tta.disagreement(d, d.transport, d.light) == 0.0
    # twice the light: the shading doubles everywhere, a relative change of exactly 1
    assert tta.disagreement(d, d.transport, d.light * 2) == pytest.approx(1.0, rel=1e-6)
    same = _Answers(d, d.light)
    out, runs = tta.augment(same, d, tta.AUGMENTATIONS, stop_when_agreed=tta.AGREED)
    assert runs == 1 and same.calls == 1
    np.testing.assert_allclose(out.light, d.light, rtol=1e-6, atol=1e-7)
    other = _Answers(d, d.light * 1.5)  # the mirror says half as much light again: 0.5 > AGREED
    out, runs = tta.augment(other, d, tta.AUGMENTATIONS, stop_when_agreed=tta.AGREED)
    assert runs == len(tta.AUGMENTATIONS) and other.calls == len(tta.AUGMENTATIONS)
    # all six averaged: the first run's light and five at 1.5x
    np.testing.assert_allclose(out.light, d.light * (1 + 5 * 1.5) / 6, rtol=1e-5, atol=1e-7)
    _, runs = tta.augment(_Answers(d, d.light), d, tta.AUGMENTATIONS)  # no early stop asked
    assert runs == len(tta.AUGMENTATIONS)


def test_consistent_albedo_along_the_soft_matte_edge_is_the_photo_over_its_shading():
    """A dark person on a background of the same colour, its matte fading over 16 columns: the
    albedo along the edge is photo / shading like inside (the crop is taken unmasked), not
    the masked network input's fade toward sRGB 0.5 grey that drew a pale ring (issue 26)."""
    from types import SimpleNamespace

    h, w = 8, 32
    colour = np.array([0.05, 0.04, 0.03], np.float32)
    photo = np.broadcast_to(colour, (h, w, 3)).copy()
    alpha = np.broadcast_to(np.clip(np.arange(w, dtype=np.float32) / 16.0, 0.0, 1.0), (h, w)).copy()
    transport = np.zeros((h, w, sh.num_coeffs(ORDER)), np.float32)
    transport[..., 0] = 1.0
    light = np.zeros((sh.num_coeffs(ORDER), 3), np.float32)
    light[0] = 0.5  # shading 0.5 everywhere: above the floor (0.25 x its mean)
    d = SimpleNamespace(photo_working=photo, alpha=alpha, network_alpha=alpha)
    albedo = rf.consistent_albedo(d, transport, light)
    edge = (alpha > 0) & (alpha < 1)
    # float32 sRGB encode and decode: a few ulps of the value
    np.testing.assert_allclose(albedo[edge], np.broadcast_to(colour / 0.5, albedo[edge].shape), rtol=1e-5)
    # the masked input's rule is far off there: at alpha 0.5 it sees about (0.5 sRGB of the
    # colour + 0.25) decoded, 0.07 against 0.05 in linear red
    from relight.network.prt import to_network_input

    masked = rf.albedo_from_input(to_network_input(photo, alpha), alpha, transport, light)
    half = alpha == 0.5
    assert np.all(masked[half] > 1.3 * albedo[half])
