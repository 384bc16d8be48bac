"""Per-photo choices (issue 26): what a relight evaluates is what the request needs, the
output's metadata says what was done, Best refines on a farm scene, and the preset rule
of benchmarks/bench_quality.py follows its Pareto front."""

from __future__ import annotations

import importlib.util
import itertools
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from relight.network import quality
from relight.lighting import sh
from relight.cli import main
from relight.network.decomposition import ORDER_TOLERANCE, Decomposition
from relight.network.runtime import Relighter
from relight.files.video_io import decode_srgb

ROOT = Path(__file__).resolve().parents[3]
FIXTURE = ROOT / "tests" / "data" / "farm_clip.npz"
ASTRONAUT = ROOT / "relight" / "data" / "examples" / "astronaut.jpg"


def random_decomposition(seed: int, residual: bool, order: int = 4, size: int = 24) -> Decomposition:
    rng = np.random.default_rng(seed)
    n = sh.num_coeffs(order)
    photo = rng.uniform(0.05, 0.9, (size, size, 3)).astype(np.float32)
    transport = rng.normal(0.0, 0.3, (size, size, n)).astype(np.float32)
    transport[..., 0] = np.abs(transport[..., 0]) + 0.3
    e = rng.normal(0.0, 0.05, (size, size, n)).astype(np.float32) if residual else np.zeros_like(transport)
    alpha = np.zeros((size, size), np.float32)
    alpha[3:-3, 4:-4] = 1.0
    return Decomposition(albedo=rng.uniform(0, 1, (size, size, 3)).astype(np.float32), transport=transport,
                         residual=e, light=rng.normal(0, 0.3, (n, 3)).astype(np.float32), alpha=alpha,
                         box=(0, size, 0, size), working_size=(size, size), photo=photo, photo_working=photo,
                         sh_order=order)


def full_order(d: Decomposition, light: np.ndarray) -> np.ndarray:
    """albedo * (T . L) + E . L over every band, at working resolution (before the clamp)."""
    return d.albedo * (d.transport @ light) + d.residual @ light


@pytest.mark.parametrize("seed, residual", [(0, False), (1, True), (2, True)])
def test_a_light_of_lower_order_is_evaluated_at_its_order_and_nothing_moves(seed, residual):
    d = random_decomposition(seed, residual)
    inside = d.alpha > 0
    for light_order in range(5):
        light = np.zeros((25, 3), np.float32)
        light[:sh.num_coeffs(light_order)] = np.random.default_rng(seed + 10).normal(
            0, 0.5, (sh.num_coeffs(light_order), 3))
        light[0] = np.abs(light[0]) + 1.0
        got = d.relit_at_working_size(light)
        assert d.last_stats.sh_order == light_order  # bands 1.. of a DC light reach every pixel: all needed
        assert d.last_stats.residual is residual
        want = np.maximum(full_order(d, light), 0.0)
        # float32 matmuls over 25 terms of values O(1): rounding ~ 25 * 2^-24 * sum |terms|
        np.testing.assert_allclose(got[inside], want[inside], atol=1e-5)


def test_a_dim_light_drops_the_bands_that_cannot_move_a_value():
    """Bands whose bound (largest |T_l| x |L_l| over the matte) is under ORDER_TOLERANCE are
    not evaluated, and the result moves by no more than that bound."""
    d = random_decomposition(3, residual=True)
    light = np.zeros((25, 3), np.float32)
    light[0] = 1.0
    light[1:4] = 0.3
    light[4:] = 1e-6  # bands 2-4: far under the tolerance
    got = d.relit_at_working_size(light)
    assert d.last_stats.sh_order == 1
    want = np.maximum(full_order(d, light), 0.0)
    inside = d.alpha > 0
    assert np.abs(got - want)[inside].max() <= ORDER_TOLERANCE + 1e-6
    # an exposure that brightens the result makes those bands count again
    d.relight(light, exposure_ev=16.0)
    assert d.last_stats.sh_order == 4


def test_a_zero_residual_is_neither_evaluated_nor_upsampled():
    d = random_decomposition(4, residual=False)
    assert not d.has_residual
    layer = d.layer("residual", d.light)
    assert layer.shape == (24, 24, 3) and not layer.any()
    out = np.full((24, 24, 3), 7.0, np.float32)
    assert d.layer("residual", d.light, out=out) is out and not out.any()
    assert random_decomposition(5, residual=True).has_residual


@pytest.fixture(scope="module")
def farm_frames():
    with np.load(FIXTURE) as z:
        return (decode_srgb(z["frames"]), decode_srgb(z["truth"]), z["alpha"].astype(np.float32) / 255.0,
                z["light"].astype(np.float64))


def test_refinement_lowers_its_objective_and_keeps_the_relit_error_on_farm_frames(farm_frames):
    """12 frames of a farm clip (a person under a held-out light, relit to another): refining
    the light lowers each frame's objective monotonically, and the relit error stays near the
    network's: with the model shipped before it gained 0.5 dB on these frames, with the
    full-body release it changed it by -0.17 dB on average (the presets no longer refine,
    docs/TRADEOFFS.md), with the every-framing model (issue 37) it gains +0.63 dB. What the test
    guards is that refining never costs: a mean loss above 0.5 dB (3x the one loss measured)
    fails; a gain does not."""
    from model.scoring import metrics
    from model.scoring.metrics import interior_weight

    frames, truth, alpha, light = farm_frames
    relighter = Relighter(threads=2)
    gains = []
    for i in range(len(frames)):
        w = interior_weight(alpha[i])
        plain = relighter.decompose(frames[i], mask=alpha[i], working_size=128)
        refined = relighter.decompose(frames[i], mask=alpha[i], working_size=128, refine=8)
        residuals = refined.choices["refine"]
        assert residuals["iterations"] >= 1
        assert residuals["residual_after"] < residuals["residual_before"]
        gains.append(metrics.psnr(refined.relight(light), truth[i], w) - metrics.psnr(plain.relight(light), truth[i], w))
    assert np.mean(gains) > -0.5, gains


def _run(capsys, *argv):
    code = main(["image", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


def test_relight_image_records_what_it_did_in_json_png_and_exr(tmp_path, capsys):
    small = tmp_path / "astronaut.png"
    Image.open(ASTRONAUT).convert("RGB").resize((160, 160)).save(small)
    out = tmp_path / "o.png"
    code, printed, err = _run(capsys, small, "--light", "studio", "--quality", "best", "--refine", "3",
                              "--json", "--out", out)
    assert code == 0, err
    record = json.loads(printed.splitlines()[0])
    best = quality.preset("best")
    assert record["quality"] == "best" and record["working_size"] == best.working_size
    assert record["augment"] == [[float(s), bool(m)] for s, m in best.augment]
    assert record["refine"]["stopped"] in ("converged", "iterations") and 1 <= record["refine"]["iterations"] <= 3
    assert record["relight"]["residual"] is False  # the shipped geometry-first model has no E
    assert 0 <= record["relight"]["sh_order"] <= 4
    with Image.open(out) as png:
        assert json.loads(png.text["relight"]) == {k: v for k, v in record.items() if k not in ("photo", "output")}
    exr = tmp_path / "o.exr"
    code, _, err = _run(capsys, small, "--light", "studio", "--quality", "draft", "--out", exr, "--layers")
    assert code == 0, err
    import OpenEXR

    with OpenEXR.File(str(exr), header_only=True) as f:
        header = json.loads(f.header()["relight"])
    assert header["quality"] == "draft" and header["refine"] == {"iterations": 0, "stopped": "off"}
    code, _, err = _run(capsys, small, "--light", "studio", "--refine", "-1")
    assert code == 2 and "--refine" in err


def test_video_refuses_refine(tmp_path, capsys):
    code = main(["video", str(tmp_path / "none.mp4"), "--light", "studio", "--refine", "2", "--out",
                 str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code != 0 and "refine" in err


def _bench_quality():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    spec = importlib.util.spec_from_file_location("bench_quality", ROOT / "benchmarks" / "bench_quality.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["bench_quality"] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def test_preset_rule_follows_a_brute_force_front():
    bq = _bench_quality()
    rng = np.random.default_rng(7)
    cands = [bq.Candidate(s) for s in (64, 96, 128, 160)] + [bq.Candidate(128, refine=k) for k in (2, 8)] \
        + [bq.BALANCED]
    for _ in range(20):
        acc = {c: rng.normal(20, 1, (6, 2)) + [[c.working_size / 100 + c.refine / 10, 0]] for c in cands}
        acc["identity"] = rng.normal(19, 1, (6, 2))
        acc["exposure-matched identity"] = rng.normal(19, 1, (6, 2))
        ms = {c: float(rng.uniform(10, 4000)) for c in cands}
        rows = bq.rows_from(acc, ms, cands)
        for r in rows:  # brute force: nobody at least as fast and as accurate, better in one
            beaten = any(o["ms"] <= r["ms"] and o["psnr"] >= r["psnr"] and (o["ms"] < r["ms"] or o["psnr"] > r["psnr"])
                         for o in rows)
            assert r["front"] is (not beaten)
        chosen = bq.propose(rows)
        assert chosen["balanced"]["candidate"] == bq.BALANCED
        front = [r for r in rows if r["front"]]
        fast = [r for r in front if r["ms"] <= bq.BEST_SECONDS * 1e3]
        if fast:  # the fastest within the tie of the most accurate (the seventh candidate made ties happen)
            top = max(r["psnr"] for r in fast)
            assert chosen["best"] is min((r for r in fast if r["psnr"] >= top - bq.BEST_TIE_DB), key=lambda r: r["ms"])
        keeping = [r for r in front if r["vs_base"] >= -bq.DRAFT_DB and r["share"] >= bq.DRAFT_SHARE]
        assert (chosen["draft"] is None) == (not keeping)
        if keeping:
            assert chosen["draft"]["ms"] == min(r["ms"] for r in keeping)


def test_the_rules_balanced_is_the_shipped_one_and_runs_bests_first_augmentation():
    """Balanced (issue 37): the network at its trained size averaged with its run on the mirrored
    crop, which is Best's first augmentation (one code path, relight.network.tta); Draft the network once."""
    bq = _bench_quality()
    balanced, best = quality.preset("balanced"), quality.preset("best")
    assert (balanced.working_size, balanced.augment) == (bq.BALANCED.working_size, bq.BALANCED.augment)
    assert balanced.augment == best.augment[:1] == ((1.0, True),) and balanced.augment_until_agreed is None
    assert quality.preset("draft").augment == ()


def test_presets_are_monotone_in_work():
    """Each preset does at least what the one before it does (more pixels, runs or iterations, or
    the person segmenter's ensemble for its selfie model alone), and something more."""
    for a, b in itertools.pairwise(quality.PRESETS):
        assert all(x <= y for x, y in zip(a.work(), b.work())) and a.work() != b.work()


@pytest.mark.parametrize("kind", ["black", "white", "single colour", "backlit"])
def test_best_stays_finite_on_extreme_photos(kind):
    """The shipped network with Best's augmentations and refinement on photos with no shading
    to read: finite outputs, a non-negative relit person, an objective that never rose."""
    h, w = 96, 64
    y, x = np.mgrid[0:h, 0:w]
    person = (((x - w / 2) / (w / 4)) ** 2 + ((y - h / 2) / (h / 2.4)) ** 2 <= 1).astype(np.float32)
    photo = {"black": np.zeros((h, w, 3)), "white": np.ones((h, w, 3)),
             "single colour": np.broadcast_to([0.4, 0.1, 0.05], (h, w, 3)),
             # lit from behind: a bright rim at the person's edge, the rest near black
             "backlit": np.where((np.abs(x - w / 2) > w / 4 - 3)[..., None], 0.9, 0.01) * np.ones((h, w, 3)),
             }[kind].astype(np.float32)
    best = quality.preset("best")
    d = Relighter(threads=2).decompose(photo, mask=person, **dict(best.decompose_options(), matte="person"))
    assert all(np.all(np.isfinite(a)) for a in (d.albedo, d.transport, d.light))
    report = d.choices["refine"]
    if report["iterations"]:
        assert report["residual_after"] <= report["residual_before"]
    relit = d.relight(np.asarray([[1.0, 0.9, 0.8]] + [[0.2, 0.2, 0.2]] * 24, np.float32))
    assert np.all(np.isfinite(relit)) and relit.min() >= 0.0


def test_an_ensemble_averages_the_other_networks_answers_on_the_same_crop(tmp_path):
    """Relighter.decompose(ensemble=(name,)): the registry's other network runs on the same
    crop (and on each augmentation made) and its transport and light join the average; the
    choice is recorded; a network of another SH order, or a name the registry lacks, is
    refused. Here: the shipped network and a small geometry-first one with other weights."""
    import shutil

    import torch

    from export.onnx_export import export_onnx, read_metadata
    from model.networks.geometry import GeometryNet
    from relight import models

    registry = tmp_path / "models"
    registry.mkdir()
    shipped = ROOT / "relight" / "models"
    shutil.copy(shipped / "geometry.onnx", registry / "geometry.onnx")
    entries = json.loads((shipped / "models.json").read_text())
    entries["models"] = {"geometry": entries["models"]["geometry"]}
    (registry / "models.json").write_text(json.dumps(entries))
    torch.manual_seed(3)
    path, digest = export_onnx(GeometryNet(sh_order=4, width=4, depth=4, decoder_width=4).eval(),
                               registry / "other.onnx")
    models.register_model("other", path, digest, read_metadata(path), registry_path=registry / "models.json")
    torch.manual_seed(4)
    path2, digest2 = export_onnx(GeometryNet(sh_order=2, width=4, depth=4, decoder_width=4).eval(),
                                 registry / "order2.onnx")
    models.register_model("order2", path2, digest2, read_metadata(path2), registry_path=registry / "models.json")
    photo = np.asarray(Image.open(ASTRONAUT).convert("RGB").resize((96, 96)), np.float32) / 255.0
    mask = np.zeros((96, 96), np.float32)
    mask[10:90, 20:76] = 1.0
    main_net = Relighter(registry / "geometry.onnx", threads=1, registry_path=registry / "models.json")
    other = Relighter(registry / "other.onnx", threads=1, registry_path=registry / "models.json")
    alone = main_net.decompose(photo, mask=mask, working_size=64, level=False)
    theirs = other.decompose(photo, mask=mask, working_size=64, level=False)
    both = main_net.decompose(photo, mask=mask, working_size=64, ensemble=("other",), level=False)
    assert both.choices["ensemble"] == ["other"]
    np.testing.assert_allclose(both.light, (alone.light + theirs.light) / 2, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(both.transport, (alone.transport + theirs.transport) / 2, rtol=1e-5, atol=1e-6)
    # the shipped network's level prior corrects the average, once (relight.network.level)
    levelled = main_net.decompose(photo, mask=mask, working_size=64, ensemble=("other",))
    gains = main_net.level_prior.gains(both.transport, both.light, both.alpha)
    np.testing.assert_allclose(levelled.light, both.light / gains[None, :], rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="SH order 2"):
        main_net.decompose(photo, mask=mask, working_size=64, ensemble=("order2",))
    with pytest.raises(ValueError, match="not in"):
        main_net.decompose(photo, mask=mask, working_size=64, ensemble=("nobody",))
