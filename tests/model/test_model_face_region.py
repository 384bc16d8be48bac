"""The face-region metric of model.evaluate (issue 37, model/scoring/face_region.py): on small synthetic
arrays with known answers, and end to end on analytic scenes given a head mask."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from model.scoring import face_region, metrics
from relight.files import dataset


def test_face_weight_is_the_metric_weight_where_the_head_mask_passes_half():
    weight = np.array([[[1.0, 1.0, 0.0, 1.0]]], np.float32)  # [1, 1, 4]
    head = np.array([[[0.2, 0.6, 0.9, 0.5]]], np.float32)
    assert face_region.face_weight(weight, head).tolist() == [[[0.0, 1.0, 0.0, 0.0]]]


def test_face_psnr_counts_only_the_face_and_matches_the_formula():
    # error 0.1 on the 4 face pixels, 0 elsewhere: over the face MSE = 0.01 -> exactly 20 dB;
    # over the whole 8 x 8 person the same error is 4 / 64 of the pixels: 20 + 10 log10(16)
    truth = np.full((8, 8, 3), 0.5)
    pred = truth.copy()
    head = np.zeros((8, 8))
    head[1:3, 3:5] = 1.0
    pred[head > 0.5] += 0.1
    whole = np.ones((8, 8))
    face = face_region.face_weight(whole, head)
    assert metrics.psnr(pred, truth, face) == pytest.approx(20.0, abs=1e-9)
    assert metrics.psnr(pred, truth, whole) == pytest.approx(20.0 + 10.0 * math.log10(16.0), abs=1e-9)


def test_normal_angles_are_the_rotation_between_the_maps():
    rng = np.random.default_rng(3)
    n = rng.normal(size=(6, 6, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    t = math.radians(12.0)
    rot = np.array([[math.cos(t), -math.sin(t), 0.0], [math.sin(t), math.cos(t), 0.0], [0.0, 0.0, 1.0]])
    # rotating about Z turns a normal by 12 degrees times sin of its angle to Z: pick normals in the XY plane
    n[..., 2] = 0.0
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    mask = np.zeros((6, 6))
    mask[2:5, 1:4] = 1.0
    angles = face_region.normal_angles_deg(n @ rot.T, n, mask)
    assert angles.shape == (9,)
    assert np.allclose(angles, 12.0, atol=1e-6)


def test_face_rows_skip_small_faces_and_average_the_rest():
    rows = face_region.FaceRows(size=8)
    big, small = np.zeros((1, 8, 8), np.float32), np.zeros((1, 8, 8), np.float32)
    big[0, :4, :5] = 1.0  # 20 pixels >= MIN_FACE_PIXELS
    small[0, :2, :2] = 1.0  # 4 pixels
    rows._heads = {"big": big, "small": small, "old": None}
    sample = {"metric_weight": np.ones((1, 8, 8), np.float32)}
    assert rows.face_sample(sample, "small") is None and rows.face_sample(sample, "old") is None
    fs = rows.face_sample(sample, "big")
    assert fs["metric_weight"].sum() == 20.0 and sample["metric_weight"].sum() == 64.0  # the input is not changed
    rows.add("ours", {"relighting/image": {"psnr": 20.0, "si_psnr": 24.0}})
    rows.add("ours", {"relighting/image": {"psnr": 30.0, "si_psnr": 26.0}})
    s = rows.summary()
    assert (s["pairs"], s["pairs_with_face"]) == (3, 1)
    assert s["methods"]["ours"] == {"psnr": 25.0, "si_psnr": 25.0}
    assert "| ours | 25.00 | 25.00 |" in rows.markdown()


def _with_head(json_path, rows: slice):
    """Rewrite an analytic scene with a head mask: the person's pixels in `rows` (image rows)."""
    scene = dataset.read_scene(json_path)
    channels = {"alpha": scene.alpha, "albedo": scene.albedo, "normal": scene.normal, "material": scene.material,
                "depth": scene.depth, "transport": scene.transport}
    for kind, maps in (("image", scene.images), ("shading", scene.shading), ("prt", scene.prt)):
        for k, m in enumerate(maps or []):
            channels[f"{kind}.L{k}"] = m
    head = np.zeros_like(scene.alpha)
    head[rows] = (scene.alpha[rows] > 0).astype(np.float32)
    channels["head"] = head
    meta = {k: v for k, v in scene.meta.items() if k not in ("format", "resolution", "channels", "exr_sha256")}
    dataset.write_scene(json_path.with_suffix(""), channels, meta)
    return head


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_evaluate_reports_the_face_rows_measured_over_the_head_mask(tmp_path, one_thread):
    """model.evaluate's face identity row equals the identity PSNR recomputed by hand over the
    cropped head mask times the interior weight, pair by pair."""
    from export.random_model import random_relightnet
    from model import evaluate
    from model.training.checkpoint import save_model
    from model.samples.data import EvaluationPairs
    from model.samples.data_splits import find_scenes, held_out_light_names
    from model.scoring.pair_metrics import baseline_identity, with_metric_weight

    data = tmp_path / "data"
    paths = __import__("model.samples.synthetic", fromlist=["x"]).write_analytic_dataset(
        data, n_scenes=2, size=32, order=4, lights=("studio", "city", "venice"))
    for p in paths:
        head = _with_head(p, slice(0, 16))
        assert dataset.read_scene(p).head is not None and head.sum() > 0
    ours = save_model(random_relightnet(1, sh_order=4, width=4, depth=2), tmp_path / "ours" / "model.safetensors")
    result = evaluate.evaluate(ours, data, tmp_path / "out", size=64, sheet_rows=1)
    face = result["face"]
    assert face["pairs"] == result["pairs"] and face["pairs_with_face"] >= 1
    expected = []
    pairs = EvaluationPairs(find_scenes(data), 64, 4, held_out=held_out_light_names())
    for i in range(len(pairs)):
        sample = with_metric_weight(evaluate.numpy_sample(pairs[i]), "interior")
        head = face_region.cropped_head(pairs.paths[pairs.pairs[i][0]], 64)
        weight = face_region.face_weight(sample["metric_weight"], head)
        if (weight > 0.5).sum() >= face_region.MIN_FACE_PIXELS:
            expected.append(baseline_identity(dict(sample, metric_weight=weight), False)["relighting/image"]["psnr"])
            whole = baseline_identity(sample, False)["relighting/image"]["psnr"]
            assert expected[-1] != pytest.approx(whole, abs=1e-6)  # the face is not the whole person
    assert len(expected) == face["pairs_with_face"]
    assert face["methods"]["identity"]["psnr"] == pytest.approx(float(np.mean(expected)), rel=1e-12)
    assert 0.0 <= face["normal_median_deg"] <= 180.0
    md = (tmp_path / "out" / "evaluation.md").read_text()
    assert "## Face region" in md and "| physics: quotient, true normals, true input light |" in md
    assert json.loads((tmp_path / "out" / "evaluation.json").read_text())["face"]["pairs_with_face"] == len(expected)
