"""One decomposition per photo (issue 39): the photo's light changes in one place in the
runtime and the albedo follows from it once, by the one rule (and constants) the exported
graph runs too; a model without a residual E sends no residual array to copy or scan."""

from __future__ import annotations

import numpy as np
import pytest

from relight.network import prt, refine


def test_the_graph_and_the_runtime_share_one_albedo_rule_and_its_constants():
    torch = pytest.importorskip("torch")
    from model.networks import physics

    rng = np.random.default_rng(0)
    photo = rng.uniform(0.0, 1.0, (2, 3, 9, 7))
    shading = rng.uniform(-0.1, 1.5, (2, 3, 9, 7))
    shading[1] *= 1e-3  # a near-black fit: its mean is taken as ALBEDO_MIN_MEAN
    weight = rng.uniform(0.0, 1.0, (2, 1, 9, 7))
    graph = physics.photo_consistent_albedo(*(torch.from_numpy(a) for a in (photo, shading, weight))).numpy()
    for b in range(2):
        runtime = prt.photo_consistent_albedo(*(np.moveaxis(a[b], 0, -1) for a in (photo, shading, weight)))
        np.testing.assert_allclose(np.moveaxis(runtime, -1, 0), graph[b], rtol=1e-12, atol=0)
    assert refine.RELIABLE is prt.ALBEDO_RELIABLE and refine.MIN_MEAN is prt.ALBEDO_MIN_MEAN
    defaults = physics.photo_consistent_albedo.__defaults__
    assert defaults == (prt.ALBEDO_RELIABLE, prt.ALBEDO_MIN_MEAN)


def test_a_geometry_model_decomposes_a_photo_once_and_its_albedo_follows_from_the_final_light(tmp_path,
                                                                                             monkeypatch):
    torch = pytest.importorskip("torch")
    import onnx

    from export.onnx_export import export_onnx, read_metadata, save_atomic, set_metadata
    from model.networks.geometry import GeometryNet
    from relight.network import level, tta
    from relight.network.decomposition import Decomposition
    from relight.network.runtime import Relighter

    torch.manual_seed(3)
    path, _ = export_onnx(GeometryNet(sh_order=4, width=4, depth=2, decoder_width=4).eval(), tmp_path / "tiny.onnx")
    model = onnx.load(str(path))
    prior = level.LevelPrior(((0.3, 0.6, -0.4), (0.2, 0.4, 0.2), (0.25, 0.3, 0.0)))
    set_metadata(model, {**read_metadata(model), level.METADATA_KEY: prior.to_metadata()})
    save_atomic(model, path)
    relighter = Relighter(path)
    assert relighter.residual_is_zero
    photo = np.random.default_rng(1).uniform(0.05, 0.6, (48, 40, 3)).astype(np.float32)
    mask = np.zeros((48, 40), np.float32)
    mask[6:42, 8:32] = 1.0

    built = []
    real = Decomposition.__post_init__
    monkeypatch.setattr(Decomposition, "__post_init__", lambda self: built.append(1) or real(self))
    d = relighter.decompose(photo, mask=mask, working_size=32, augment=tta.AUGMENTATIONS[:2], refine=2)
    assert len(built) == 1  # built once; with_light changed its light (and so its albedo) in one step
    assert d.choices["level"]["gains"] and d.choices["augment"] == [[1.0, True], [1.25, False]]
    assert not d.has_residual and d.residual.shape == d.transport.shape and not np.any(d.residual)
    assert d.residual.strides == (0, 0, 0)  # zeros that hold no memory: the graph's output was not copied
    np.testing.assert_array_equal(d.albedo, refine.consistent_albedo(d, d.transport, d.light))
    relit = d.relight(d.light)
    assert np.all(np.isfinite(relit)) and d.last_stats.residual is False


def test_with_light_keeps_the_decomposition_and_changes_only_light_and_albedo():
    from refine_support import lobe_light, synthetic

    light = lobe_light([0.2, -1.0, 0.4], [1.0, 0.85, 0.7], 0.5)
    d, _, transport, _ = synthetic(light, light)
    other = (light * np.array([1.2, 0.9, 1.0])).astype(np.float32)
    new = d.with_light(other)
    assert new is not d and np.array_equal(d.light, light.astype(np.float32))  # d itself unchanged
    np.testing.assert_array_equal(new.light, other)
    np.testing.assert_array_equal(new.albedo, refine.consistent_albedo(d, transport, other))
    assert new._matte is d._matte and new._up is d._up  # the matte and resamplers kept, not rebuilt
    assert new.choices is not d.choices and new.last_stats is None
