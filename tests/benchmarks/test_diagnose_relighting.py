"""benchmarks/diagnose_relighting.py: each way of relighting is exact when its inputs are."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from model.scoring import metrics

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("diagnose_relighting", ROOT / "benchmarks" / "diagnose_relighting.py")
dr = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(dr)


def _scene(seed=0, n=9, h=6, w=5):
    """Positive shading (DC-dominated T and L) so that the photo-consistent albedo is defined everywhere."""
    rng = np.random.default_rng(seed)
    albedo = rng.uniform(0.1, 0.9, (3, h, w))
    transport = rng.normal(0, 0.05, (n, h, w))
    transport[0] += 0.8
    residual = 0.02 * rng.normal(size=(n, h, w))
    light, target = rng.normal(0, 0.1, (2, n, 3))
    light[0], target[0] = [2.0, 2.5, 3.0], [1.0, 4.0, 1.5]
    render = lambda L: np.moveaxis(albedo, 0, -1) * dr.shading(transport, L) + dr.shading(residual, L)
    sample = {"albedo": albedo, "transport": transport, "light": light, "target_light": target,
              "image": np.moveaxis(render(light), -1, 0), "target_image": np.moveaxis(render(target), -1, 0)}
    pred = {"albedo": albedo, "transport": transport, "residual": residual, "light": light}
    return sample, pred


def test_every_variant_is_exact_for_a_perfect_decomposition():
    sample, pred = _scene()
    out = dr.variants(pred, sample)
    target = np.moveaxis(sample["target_image"], 0, -1)
    for name, relit in out.items():
        if name.startswith("identity") or "at 0.8" in name or "GT T, no E" in name:
            continue  # not the true decomposition by construction
        np.testing.assert_allclose(relit, target, rtol=1e-10, atol=1e-12, err_msg=name)
    # without E, GT transport misses exactly E . L_b
    np.testing.assert_allclose(out["predicted albedo, GT T, no E (bound)"],
                               target - dr.shading(pred["residual"], sample["target_light"]), atol=1e-12)


def test_photo_consistent_albedo_absorbs_an_albedo_error_but_not_a_light_error():
    sample, pred = _scene(1)
    target = np.moveaxis(sample["target_image"], 0, -1)
    wrong_albedo = dict(pred, albedo=pred["albedo"] * np.array([1.5, 0.7, 1.2])[:, None, None])
    out = dr.variants(wrong_albedo, sample)
    assert metrics.psnr(out["direct"], target) < 30
    # the photo fixes the albedo: the photo-consistent relight stays exact
    np.testing.assert_allclose(out["photo-consistent albedo, predicted light"], target, rtol=1e-10)
    # a light twice too bright halves the photo-consistent albedo: the relit image is off by 2x minus E's share
    bright = dict(pred, light=2.0 * pred["light"])
    relit = dr.variants(bright, sample)["photo-consistent albedo, predicted light"]
    assert metrics.psnr(relit, target) < 20
    np.testing.assert_allclose(dr.variants(bright, sample)["photo-consistent albedo, true light a (bound)"], target,
                               rtol=1e-10)


def test_exposure_matched_identity_matches_model_evaluate():
    from model.scoring import pair_metrics

    sample, pred = _scene(2)
    sample["alpha"] = np.ones((1, 6, 5))
    sample["input_linear"] = sample["image"]
    mine = dr.variants(pred, sample)["identity, exposure-matched"]
    theirs = pair_metrics.baseline_identity(sample, exposure_matched=True)["relighting/image"]
    assert metrics.psnr(mine, np.moveaxis(sample["target_image"], 0, -1)) == pytest.approx(theirs["psnr"], abs=1e-9)


def test_cli_on_the_analytic_dataset(tmp_path, capsys, one_thread):
    from export.random_model import random_relightnet
    from model.training.checkpoint import save_model
    from model.samples.synthetic import write_analytic_dataset

    write_analytic_dataset(tmp_path / "data", n_scenes=2, size=32, order=4, lights=("studio", "city", "venice"))
    model = save_model(random_relightnet(1, sh_order=4, width=4, depth=2), tmp_path / "m" / "model.safetensors")
    assert dr.main([str(model), "--data", str(tmp_path / "data"), "--size", "32", "--max-pairs", "3"]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| ") and "PSNR" not in line]
    assert len(rows) == 8 and all(np.isfinite(float(r.split("|")[2])) for r in rows)
    assert "predicted / true light DC over 3 pairs" in out and "input masked" in out
    # the unmasked input differs from the masked one, so the prediction (and a score) changes
    assert dr.main([str(model), "--data", str(tmp_path / "data"), "--size", "32", "--max-pairs", "3", "--unmasked"]) == 0
    unmasked = capsys.readouterr().out
    assert "input with its background" in unmasked and unmasked.split("\n", 1)[1] != out.split("\n", 1)[1]
    assert dr.main([str(model), "--data", str(tmp_path / "none"), "--size", "32"]) == 2
    assert "does not exist" in capsys.readouterr().err
