"""Evaluation pieces: a perfect decomposition scores perfectly; baselines match hand values."""

import numpy as np
import pytest

from model import evaluate


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
    scores = evaluate.evaluate_prediction(pred, sample, tstar=False)
    assert set(scores) == {f"{s}/{m}" for s in ("reconstruction", "relighting") for m in evaluate.MAPS}
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
    matched = evaluate.baseline_identity(sample, exposure_matched=True)["relighting/image"]
    assert matched["l1"] < 1e-12
    plain = evaluate.baseline_identity(sample, exposure_matched=False)["relighting/image"]
    mask = sample["alpha"][0] > 0
    want = np.abs(sample["input_linear"] - sample["target_image"])[:, mask].mean()
    assert plain["l1"] == pytest.approx(want, rel=1e-12)


def test_table_and_contact_sheet_layout():
    results = {"ours": {"reconstruction/image": {"l1": 0.01234, "l2": 0.0005, "psnr": 33.0}}}
    md = evaluate.markdown_table(results, 3, "d")
    # L1 x100 with 2 decimals, L2 x100 with 3, missing maps as "-"
    assert "| ours | reconstruction | - | - | - | - | - | - | 1.23 | 0.050 | 33.00 |" in md
    sheet = evaluate.contact_sheet([[np.zeros((4, 6, 3)), np.ones((4, 6, 3))]] * 2)
    assert sheet.shape == (2 * 6, 2 * 8, 3) and sheet.dtype == np.uint8
    assert sheet[0, 0].tolist() == [0, 0, 0] and sheet[0, 8].tolist() == [255, 255, 255]
