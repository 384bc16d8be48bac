"""Evaluation pieces: a perfect decomposition scores perfectly; baselines match hand values."""

import json

import numpy as np
import pytest

from model import evaluate
from model.scoring import geometry_diagnostics, metrics, pair_metrics, predictor


def _sample(seed=0, n=9, h=4, w=5):
    rng = np.random.default_rng(seed)
    albedo = rng.uniform(0.1, 0.9, (3, h, w))
    transport = rng.normal(0, 0.3, (n, h, w))
    residual = 0.05 * transport
    light, target_light = rng.normal(0, 1, (2, n, 3))
    light[0], target_light[0] = [2.0, 2.5, 3.0], [1.0, 5.0, 1.5]
    alpha = np.ones((1, h, w))
    alpha[0, 0, 0] = 0.0
    render = lambda L: (albedo * np.einsum("nhw,nc->chw", transport, L) + np.einsum("nhw,nc->chw", residual, L))
    sample = {"albedo": albedo, "transport": transport, "light": light, "target_light": target_light,
              "alpha": alpha, "image": render(light), "target_image": render(target_light)}
    pred = {"albedo": albedo, "transport": transport, "residual": residual, "light": light}
    return sample, pred


def test_perfect_prediction_scores_zero_error():
    sample, pred = _sample()
    scores = pair_metrics.evaluate_prediction(pred, sample, tstar=False)
    assert set(scores) == {f"{s}/{m}" for s in ("reconstruction", "relighting") for m in pair_metrics.MAPS}
    for key, m in scores.items():
        if key.endswith("shading"):
            continue  # GT shading is T.L (no E); the prediction's shading is T.L too
        assert m["l1"] < 1e-12 and m["psnr"] == pytest.approx(100.0), key
    assert scores["relighting/shading"]["l1"] < 1e-12


def test_identity_baselines_hand_values():
    sample, _ = _sample()
    ratio = sample["target_light"][0] / sample["light"][0]  # per channel: 0.5, 2, 0.5
    # an input that is exactly the target divided by the per-channel L00 ratio
    sample["input_linear"] = sample["target_image"] / ratio[:, None, None]
    matched = pair_metrics.baseline_identity(sample, exposure_matched=True)["relighting/image"]
    assert matched["l1"] < 1e-12
    plain = pair_metrics.baseline_identity(sample, exposure_matched=False)["relighting/image"]
    mask = sample["alpha"][0] > 0
    want = np.abs(sample["input_linear"] - sample["target_image"])[:, mask].mean()
    assert plain["l1"] == pytest.approx(want, rel=1e-12)


def test_pair_light_response_of_the_truth_is_physics_and_of_the_photo_is_none():
    """The relit image equal to the truth under b responds with slope 1, correlation 1; the photo
    returned as it is (the identity) with 0 and 0; the per-framing means leave NaN pairs out."""
    sample, pred = _sample(h=8, w=9)
    sample["metric_weight"], sample["input_linear"] = sample["alpha"], sample["image"]
    for k in ("image", "target_image"):  # log luminance needs positive pixels
        sample[k] = np.abs(sample[k]) + 0.05
    pred = dict(pred, albedo=sample["target_image"], transport=np.zeros_like(pred["transport"]),
                residual=np.zeros_like(pred["residual"]))
    pred["transport"][0] = 1.0  # a constant shading; the albedo below makes the render the truth
    pred["albedo"] = sample["target_image"] / np.einsum("nhw,nc->chw", pred["transport"], sample["target_light"])
    truth = evaluate.pair_light_response(sample, pred, tstar=False)
    assert truth["slope"] == pytest.approx(1.0, abs=1e-9) and truth["correlation"] == pytest.approx(1.0, abs=1e-9)
    assert truth["psnr"] == pytest.approx(100.0)
    photo = dict(pred, albedo=sample["input_linear"] / np.einsum("nhw,nc->chw", pred["transport"],
                                                                  sample["target_light"]))
    none = evaluate.pair_light_response(sample, photo, tstar=False)
    assert (none["slope"], none["correlation"]) == (0.0, 0.0)
    table = evaluate.light_response_table({"ours": {"waist-up": [truth, none, dict(none, slope=np.nan,
                                                                                      correlation=np.nan)]}})
    assert table["ours"]["waist-up"]["pairs"] == 3
    assert table["ours"]["waist-up"]["slope"] == pytest.approx(0.5) and table["ours"]["waist-up"]["correlation"] == 0.5


def test_gain_fitted_diagnostic_removes_exactly_a_colour_cast():
    sample, pred = _sample()
    for d in (sample, pred):  # no residual: the relit image is then linear in the albedo
        d["residual"] = np.zeros_like(sample["transport"])
    shading = lambda L: np.einsum("nhw,nc->chw", sample["transport"], L)
    sample["image"], sample["target_image"] = (sample["albedo"] * shading(L) for L in
                                               (sample["light"], sample["target_light"]))
    cast = np.array([2.0, 0.5, 1.25])
    pred = dict(pred, albedo=sample["albedo"] * cast[:, None, None])
    plain = pair_metrics.evaluate_prediction(pred, sample, tstar=False)
    fitted = pair_metrics.gain_fitted(pred, sample, tstar=False)
    assert plain["relighting/image"]["psnr"] < 30 and plain["relighting/albedo"]["psnr"] < 30
    # a pure per-channel cast is removed to float64 rounding (PSNR capped at 100 dB)
    assert fitted["relighting/image"]["psnr"] > 90 and fitted["relighting/albedo"]["psnr"] > 90
    mask = sample["alpha"][0][..., None]
    np.testing.assert_allclose(
        metrics.fit_channel_gains(np.moveaxis(pred["albedo"], 0, -1), np.moveaxis(sample["albedo"], 0, -1), mask),
        1 / cast, rtol=1e-12)
    # a structural error (noise) is not removed: gains fit, but the error stays
    rng = np.random.default_rng(9)
    noisy = dict(pred, albedo=sample["albedo"] * (1 + 0.3 * rng.normal(size=sample["albedo"].shape)))
    assert pair_metrics.gain_fitted(noisy, sample, tstar=False)["relighting/albedo"]["psnr"] < 40
    # an all-zero channel keeps gain 1 instead of dividing by zero
    assert metrics.fit_channel_gains(np.zeros((2, 2, 3)), np.ones((2, 2, 3))).tolist() == [1.0, 1.0, 1.0]


def test_table_and_contact_sheet_layout():
    results = {"ours": {"reconstruction/image": {"l1": 0.01234, "l2": 0.0005, "psnr": 33.0, "si_psnr": 35.5}}}
    md = evaluate.markdown_table(results, 3, "d")
    # L1 x100 with 2 decimals, L2 x100 with 3, PSNR and scale-invariant PSNR, missing maps as "-"
    assert "| ours | reconstruction | - | - | - | - | - | - | - | - | 1.23 | 0.050 | 33.00 | 35.50 |" in md
    header = next(line for line in md.splitlines() if line.startswith("| method"))
    assert header.count("|") - 1 == 2 + 4 * len(pair_metrics.MAPS) and "image SI PSNR" in header
    sheet = evaluate.contact_sheet([[np.zeros((4, 6, 3)), np.ones((4, 6, 3))]] * 2)
    assert sheet.shape == (2 * 6, 2 * 8, 3) and sheet.dtype == np.uint8
    assert sheet[0, 0].tolist() == [0, 0, 0] and sheet[0, 8].tolist() == [255, 255, 255]


def test_parse_baselines_names_paths_and_rejects_clashes(tmp_path):
    odd = tmp_path / "a=b.onnx"  # an existing file whose name holds "=" stays a path
    odd.write_bytes(b"")
    got = evaluate.parse_baselines(["small=runs/small/model.onnx", "runs/ke/model.safetensors", str(odd),
                                    ("mine", "x.onnx"), "runs/v=2/model.onnx"])
    assert [name for name, _ in got] == ["small", "baseline (ke/model.safetensors)",
                                         f"baseline ({tmp_path.name}/a=b.onnx)", "mine",
                                         "baseline (v=2/model.onnx)"]
    assert str(got[0][1]) == "runs/small/model.onnx" and got[2][1] == odd
    assert evaluate.parse_baselines(None) == [] and len(evaluate.parse_baselines("m.onnx")) == 1
    for bad in (["a=x.onnx", "a=y.onnx"], ["identity=x.onnx"], ["=x.onnx"], ["a|b=x.onnx"]):
        with pytest.raises(ValueError):
            evaluate.parse_baselines(bad)


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # torch's legacy (TorchScript) exporter
def test_several_baselines_share_one_table(tmp_path, capsys, one_thread):
    """Ours + an ONNX baseline of the same order + a safetensors baseline of order 2, one run:
    every baseline's row equals that model's own row when it is evaluated alone."""
    from export.random_model import export_random_model, random_relightnet
    from model.training.checkpoint import save_model
    from model.samples.synthetic import write_analytic_dataset

    data = tmp_path / "data"
    write_analytic_dataset(data, n_scenes=2, size=32, order=4, lights=("studio", "city", "venice"))
    ours = save_model(random_relightnet(1, sh_order=4, width=4, depth=2), tmp_path / "ours" / "model.safetensors")
    small, _, _ = export_random_model(tmp_path / "small.onnx", seed=2, sh_order=4, width=4, depth=2)
    ke = save_model(random_relightnet(3, sh_order=2, width=4, depth=2), tmp_path / "ke" / "model.safetensors")

    argv = [str(ours), "--data", str(data), "--out", str(tmp_path / "all"), "--size", "32",
            "--baseline", f"small={small}", "--baseline", str(ke), "--sheet-rows", "1"]
    assert evaluate.main(argv) == 0
    md = (tmp_path / "all" / "evaluation.md").read_text()
    rows = {line.split("|")[1].strip() for line in md.splitlines() if "| relighting |" in line}
    ke_name = "baseline (ke/model.safetensors)"
    assert rows == {"ours", "identity", "identity, exposure-matched", evaluate.ORACLE_ROW, evaluate.GAIN_ROW,
                    "small", ke_name, *geometry_diagnostics.BREAKDOWN_ROWS}
    record = json.loads((tmp_path / "all" / "evaluation.json").read_text())
    assert record["baselines"] == {"small": str(small), ke_name: str(ke)}
    # the per-pair records name their maps and average to the table's means
    per_pair = record["per_pair"]
    assert len(per_pair) == record["pairs"]
    assert {p["light_a"] for p in per_pair} | {p["light_b"] for p in per_pair} == {"studio", "city", "venice"}
    assert all(p["light_a"] != p["light_b"] for p in per_pair)
    ours_relit = record["methods"]["ours"]["relighting/image"]
    assert np.mean([p["relit_psnr"] for p in per_pair]) == pytest.approx(ours_relit["psnr"], rel=1e-12)
    assert np.mean([p["relit_si_psnr"] for p in per_pair]) == pytest.approx(ours_relit["si_psnr"], rel=1e-12)
    quotient = record["breakdown"][geometry_diagnostics.TRUE_LIGHT_ROW]["relighting/image"]["psnr"]
    assert np.mean([p["true_light_psnr"] for p in per_pair]) == pytest.approx(quotient, rel=1e-12)
    # the light's response beside the relit PSNR, per framing (analytic scenes record none: "-"),
    # for ours and every baseline; its means are the per-pair records'
    response = record["light_response"]
    assert set(response) == {"ours", "small", ke_name, *geometry_diagnostics.BREAKDOWN_ROWS}
    assert set(response["ours"]) == {"-"}
    # the breakdown's swaps respond too (where the response is lost), from the very images scored above
    for name in geometry_diagnostics.BREAKDOWN_ROWS:
        assert response[name]["-"]["psnr"] == pytest.approx(record["breakdown"][name]["relighting/image"]["psnr"],
                                                            rel=1e-12), name
    ours_response = response["ours"]["-"]
    assert ours_response["pairs"] == record["pairs"]
    assert ours_response["psnr"] == pytest.approx(ours_relit["psnr"], rel=1e-12)
    assert ours_response["slope"] == pytest.approx(np.nanmean([p["light_slope"] for p in per_pair]), rel=1e-12)
    assert ours_response["correlation"] == pytest.approx(
        np.nanmean([p["light_correlation"] for p in per_pair]), rel=1e-12)
    assert f"| ours | - | {record['pairs']} | {ours_relit['psnr']:.2f} |" in md
    together = record["methods"]
    for name, path in (("small", small), (ke_name, ke)):
        alone = evaluate.evaluate(path, data, tmp_path / name.split()[0], size=32, sheet_rows=1)
        assert alone["pairs"] == record["pairs"]
        # same network, same pairs, same order: identical numbers, not merely close
        assert alone["methods"]["ours"] == together[name], name

    capsys.readouterr()
    assert evaluate.main(argv + ["--baseline", f"small={ke}"]) == 2
    assert "used twice" in capsys.readouterr().err


# ------------------------------------------------------------------ real photos (model.evaluate_photos)


@pytest.fixture(scope="module")
def random_onnx(tmp_path_factory):
    """A small seeded random-weight RelightNet exported to ONNX (+ .sha256)."""
    import torch

    from export.random_model import export_random_model

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        path, _, _ = export_random_model(tmp_path_factory.mktemp("onnx") / "random.onnx", seed=5,
                                         sh_order=4, width=4, depth=2)
    finally:
        torch.set_num_threads(before)
    return path


def _photos(folder):
    """Two tiny photos: an opaque JPEG (predicted matte) and an RGBA PNG (the file's alpha)."""
    from PIL import Image

    rng = np.random.default_rng(3)
    folder.mkdir()
    Image.fromarray(rng.integers(0, 256, (40, 28, 3), dtype=np.uint8)).save(folder / "a.jpg", quality=90)
    rgba = rng.integers(0, 256, (30, 44, 4), dtype=np.uint8)
    rgba[..., 3] = 0
    rgba[5:25, 10:30, 3] = 255  # a person-sized opaque box inside a transparent frame
    Image.fromarray(rgba, "RGBA").save(folder / "b.png")
    (folder / "notes.txt").write_text("not a photo")
    return folder


def test_evaluate_photos_writes_table_sheet_and_the_documented_reconstruction(random_onnx, tmp_path, capsys):
    from model import evaluate_photos as ep
    from relight.network.runtime import Relighter

    photos = _photos(tmp_path / "photos")
    out = tmp_path / "out"
    # Draft: the network once, so the reconstruction below is one decomposition's (Balanced
    # averages it with its mirrored run)
    results = ep.evaluate_photos(random_onnx, photos, out, quality="draft", working_size=32, threads=1, tile=24)
    assert [r.name for r in results] == ["a.jpg", "b.png"]
    # a flat test image holds nobody for the person segmenter: the network's alpha is the matte
    assert [r.matte for r in results] == ["network alpha (no person found)", "file alpha"]
    md = (out / "photos.md").read_text()
    assert sum(line.startswith(("| a.jpg |", "| b.png |")) for line in md.splitlines()) == 2
    record = json.loads((out / "photos.json").read_text())
    for row in record["photos"]:
        assert all(np.isfinite(v) for v in row["reconstruction"].values()), row
    from PIL import Image

    sheet = Image.open(out / "contact_sheet.png")
    cols = 2 + len(ep.SHEET_DIRECTIONS) + len(ep.SHEET_PRESETS) * len(ep.SHEET_ROTATIONS)
    assert sheet.size == (cols * (24 + ep.GUTTER), ep.LABEL_HEIGHT + 2 * (24 + ep.GUTTER))

    # the number is what the table says: max(0, albedo * (T . L) + E . L) with the predicted L (the
    # runtime clamps negative light), against the photo at working resolution, weighted by the
    # matte (here the file's alpha)
    from relight.files import photo as photo_io

    image, mask = photo_io.read_photo(photos / "b.png")
    dec = Relighter(random_onnx, threads=1, working_size=32).decompose(image, mask=mask, augment=())  # Draft's
    L = dec.light.astype(np.float64)
    rerendered = np.maximum(dec.albedo * (dec.transport @ L) + dec.residual @ L, 0.0)
    w = dec.alpha[..., None]
    mse = float((w * (rerendered - dec.photo_working) ** 2).sum() / (3 * w.sum()))
    # float32 matmuls in the runtime vs float64 here: relative error ~1e-6 in the MSE
    assert record["photos"][1]["reconstruction"]["psnr"] == pytest.approx(-10 * np.log10(mse), abs=1e-3)


def test_evaluate_photos_cli_errors_and_presets(random_onnx, tmp_path, capsys):
    from model import evaluate_photos as ep
    from relight.lighting import presets

    assert not set(ep.SHEET_PRESETS) & presets.HELD_OUT  # never show an evaluation light
    (tmp_path / "empty").mkdir()
    assert ep.main([str(random_onnx), "--photos", str(tmp_path / "empty"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no photos" in err[0]
    assert ep.main([str(tmp_path / "missing.onnx"), "--out", str(tmp_path / "o")]) == 2
    assert "model file not found" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()  # nothing half-written


def test_evaluate_photos_needs_no_torch():
    import subprocess
    import sys

    code = "import sys, model.evaluate_photos; sys.exit('torch' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


def test_oracle_prt_misses_exactly_the_residual():
    """The oracle (GT albedo and T, no E) is off by exactly E.L: its error is the residual's."""
    sample, pred = _sample(seed=3)
    got = pair_metrics.oracle_prt(sample)
    mask = pair_metrics.channels_last(sample["alpha"])
    for setting, light, image in (("reconstruction", "light", "image"),
                                  ("relighting", "target_light", "target_image")):
        gt = pair_metrics.channels_last(sample[image])
        residual = pair_metrics.shading_np(pred["residual"], sample[light], False)
        want = metrics.all_metrics(gt - residual, gt, mask)
        assert got[f"{setting}/image"]["l1"] == pytest.approx(want["l1"], rel=1e-12)
        assert got[f"{setting}/image"]["l1"] > 1e-3


def test_interior_mask_drops_partly_covered_pixels():
    sample, _ = _sample(seed=4)
    sample["alpha"][0, 1, 1] = 0.5
    weighted = pair_metrics.with_metric_weight(dict(sample), "alpha")["metric_weight"]
    interior = pair_metrics.with_metric_weight(dict(sample), "interior")["metric_weight"]
    assert weighted[0, 1, 1] == 0.5 and interior[0, 1, 1] == 0.0 and interior[0, 0, 0] == 0.0
    assert interior.sum() == sample["alpha"].size - 2
    # an error only on the half-covered pixel counts under "alpha", not under "interior"
    sample["target_image"] = sample["target_image"].copy()
    bad = dict(sample)
    bad["input_linear"] = sample["target_image"].copy()
    bad["input_linear"][:, 1, 1] += 1.0
    bad["light"] = bad["target_light"]
    assert pair_metrics.baseline_identity(pair_metrics.with_metric_weight(dict(bad), "interior"), False)[
        "relighting/image"]["l1"] == 0.0
    assert pair_metrics.baseline_identity(pair_metrics.with_metric_weight(dict(bad), "alpha"), False)[
        "relighting/image"]["l1"] > 0.0
    with pytest.raises(ValueError, match="mask"):
        pair_metrics.with_metric_weight(dict(sample), "edges")


def test_onnx_predictor_opens_the_hash_checked_session(tmp_path):
    from export.random_model import export_random_model
    from relight.models.session import ModelSession

    path, _, _ = export_random_model(tmp_path / "m.onnx", seed=1, sh_order=2, width=4, depth=2)
    x = np.random.default_rng(0).uniform(-1, 1, (1, 3, 32, 32)).astype(np.float32)
    model = predictor.Predictor(path)
    assert model.order == 2 and not model.tstar
    want = ModelSession(path).run(x)
    got = model(x)
    for k in predictor.OUTPUTS:
        np.testing.assert_array_equal(got[k], want[k])
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="SHA-256 mismatch"):
        predictor.Predictor(path)


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_without_out_the_reports_go_to_a_run_folder_not_evaluation(tmp_path, monkeypatch, capsys, one_thread):
    """Issue 40: the default --out was ./evaluation, which from a checkout is the evaluation/
    package's own folder (untracked reports beside its modules)."""
    from export.random_model import random_relightnet
    from model.training.checkpoint import save_model
    from model.samples.synthetic import write_analytic_dataset

    data = tmp_path / "data"
    write_analytic_dataset(data, n_scenes=2, size=32, order=2, lights=("studio", "city"))
    ours = save_model(random_relightnet(1, sh_order=2, width=4, depth=2), tmp_path / "m" / "model.safetensors")
    monkeypatch.chdir(tmp_path)
    assert evaluate.main([str(ours), "--data", str(data), "--size", "32", "--sheet-rows", "1"]) == 0
    assert not (tmp_path / "evaluation").exists()
    assert (tmp_path / "runs" / "evaluate-model" / "evaluation.md").is_file()
    assert "runs/evaluate-model/evaluation.md" in capsys.readouterr().out
