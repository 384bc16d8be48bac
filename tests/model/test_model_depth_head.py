"""The depth head (issue 45): its scale-and-shift-invariant loss, the depth in the data and the
packs (old packs read as before), and a tiny model that learns one scene's depth."""

import numpy as np
import pytest
import torch

from model.networks.geometry import GeometryNet, geometry_losses
from model.samples import data, data_splits
from model.samples.data_crops import load_cropped
from model.samples.synthetic import write_analytic_dataset
from model.samples.training_pack import read_training_pack, write_training_pack
from model.training.checkpoint import init_weights
from model.networks.depth_loss import EPS, ssi_depth_loss
from relight.lighting import presets

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    folder = tmp_path_factory.mktemp("analytic")
    return write_analytic_dataset(folder, n_scenes=3, size=32, order=4, lights=("studio", "city", "venice"))


def _depths(seed=0, shape=(2, 1, 12, 10)):
    rng = np.random.default_rng(seed)
    truth = torch.from_numpy(rng.uniform(2.0, 3.0, shape))
    weight = torch.from_numpy((rng.uniform(size=shape) > 0.3).astype(np.float64))
    return truth, weight


def test_loss_is_zero_for_an_affine_copy_and_positive_otherwise():
    truth, weight = _depths()
    mean = (truth * weight).sum((1, 2, 3), keepdim=True) / weight.sum((1, 2, 3), keepdim=True)
    var = float(((((truth - mean) ** 2) * weight).sum((1, 2, 3)) / weight.sum((1, 2, 3))).min())
    for a, b in ((1.0, 0.0), (3.7, -2.0), (0.01, 50.0)):
        # exact but for EPS: x_n = x's standard score times sqrt(v / (v + EPS)) (v its variance, a^2 var(t)
        # for p), which lies within EPS / (2 v) of 1; so |p_n - t_n| <= |t's score| EPS / (2 min(a^2, 1)
        # var(t)), and the score's weighted mean |.| is <= 1 (its mean square is 1); plus float64 rounding
        bound = EPS / (2 * min(a * a, 1.0) * var) + 1e-12
        assert float(ssi_depth_loss(a * truth + b, truth, weight)) <= bound
    # inverted: every standardized value the truth's negative, so the loss is 2 mean_w |t_n| > 0
    t_n = (truth - (truth * weight).sum((1, 2, 3), keepdim=True) / weight.sum((1, 2, 3), keepdim=True))
    t_n = t_n / torch.sqrt((t_n ** 2 * weight).sum((1, 2, 3), keepdim=True) / weight.sum((1, 2, 3), keepdim=True))
    want = float(((2 * t_n.abs() * weight).sum((1, 2, 3)) / weight.sum((1, 2, 3))).mean())
    assert float(ssi_depth_loss(-2.0 * truth + 1.0, truth, weight)) == pytest.approx(want, rel=1e-9)
    noisy = truth + 0.05 * torch.from_numpy(np.random.default_rng(1).normal(size=truth.shape))
    assert float(ssi_depth_loss(noisy, truth, weight)) > 0.01
    # pixels of weight 0 do not count; an image without any counts for nothing
    wild = torch.where(weight > 0, truth, torch.full_like(truth, 1e6))
    assert float(ssi_depth_loss(wild, truth, weight)) < 1e-6
    empty = weight.clone()
    empty[1] = 0
    assert float(ssi_depth_loss(noisy, truth, empty)) == pytest.approx(
        float(ssi_depth_loss(noisy[:1], truth[:1], weight[:1])), rel=1e-12)


def test_loss_is_invariant_to_the_predictions_scale_and_shift_and_its_gradient_checks():
    truth, weight = _depths(2)
    pred = truth + torch.from_numpy(np.random.default_rng(3).normal(0, 0.2, truth.shape))
    base = float(ssi_depth_loss(pred, truth, weight))
    mean = (pred * weight).sum((1, 2, 3), keepdim=True) / weight.sum((1, 2, 3), keepdim=True)
    var = float(((((pred - mean) ** 2) * weight).sum((1, 2, 3)) / weight.sum((1, 2, 3))).min())
    for a, b in ((2.5, 1.0), (1e-3, -4.0)):
        # invariant but for EPS, as in the test above: within EPS / (2 min(a^2, 1) var(p))
        assert abs(float(ssi_depth_loss(a * pred + b, truth, weight)) - base) <= EPS / (2 * min(a * a, 1) * var) + 1e-12
    # and to the truth's: metres or millimetres, near or far, the same loss
    assert float(ssi_depth_loss(pred, 1000 * truth - 7, weight)) == pytest.approx(base, abs=EPS / var)
    x = pred.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda p: ssi_depth_loss(p, truth, weight), (x,), eps=1e-6, atol=1e-6)
    # the gradient is blind to the shift and scale it is invariant to: orthogonal to 1 (exactly: the shift
    # leaves every standard score as it is) and to p itself (d/da of the loss of a p at a = 1; only EPS
    # makes it depend on a: the score's factor sqrt(v / (v + EPS)) moves by at most EPS / v per unit of a)
    ssi_depth_loss(x, truth, weight).backward()
    g = x.grad * weight
    for k in range(2):
        assert abs(float(g[k].sum())) < 1e-12
        assert abs(float((g[k] * x[k].detach()).sum())) <= EPS / var + 1e-12


def test_the_depth_reaches_crops_samples_and_packs(scenes, tmp_path):
    held = data_splits.held_out_light_names()
    crop = load_cropped(scenes[0], 16, 2, 1, held)
    inner = crop.alpha[0] > 0.999
    assert crop.depth.shape == (1, 16, 16) and np.all(crop.depth[0][crop.alpha[0] == 0] == 0)
    assert crop.depth[0][inner].min() > 0            # no zero from outside mixed into the person
    ds = data.TrainingScenes(scenes, 16, 2, padding=1, extra_lights=[], held_out=held, depth=True, flip_prob=1.0)
    item = ds.item(0, 0)
    assert np.array_equal(item["depth"].numpy(), crop.depth[..., ::-1])  # mirrored with the image
    pack = read_training_pack(write_training_pack(scenes, tmp_path / "p.npz", 16, 2, padding=1))
    assert np.array_equal(pack.scenes[0].depth, crop.depth) and pack.scenes[0].depth.dtype == np.float32
    # a pack from before the depth head (no depth arrays, no record of them) reads as it did
    with np.load(tmp_path / "p.npz") as z:
        arrays = {k: z[k] for k in z.files if not k.startswith("d")}
    import json

    manifest = json.loads(bytes(arrays["manifest"]).decode())
    for rec in manifest["scenes"]:
        rec.pop("depth"), rec.pop("depth_sha256")
    arrays["manifest"] = np.frombuffer(json.dumps(manifest).encode(), np.uint8)
    with open(tmp_path / "old.npz", "wb") as f:
        np.savez_compressed(f, **arrays)
    old = read_training_pack(tmp_path / "old.npz")
    assert old.scenes[0].depth is None and np.array_equal(old.scenes[0].transport, pack.scenes[0].transport)
    with pytest.raises(ValueError, match="no depth pass"):
        data.TrainingScenes(None, 16, 2, extra_lights=[], held_out=held, depth=True,
                            scenes=_Scenes(old.scenes)).item(0, 0)


class _Scenes:
    def __init__(self, items):
        self.items, self.paths = items, [str(i) for i in range(len(items))]

    def __call__(self, i):
        return self.items[i]


def test_a_tiny_model_learns_one_scenes_depth(scenes):
    """200 Adam steps on one scene's two samples: the depth loss falls below a tenth of its first value
    (measured 1.208 -> 0.026 here: 47x); the other terms are trained alongside."""
    ds = data.TrainingScenes(scenes, 16, 2, padding=1, extra_lights=[], held_out=frozenset(presets.HELD_OUT),
                             depth=True)
    batch = torch.utils.data.default_collate([ds.item(0, 0), ds.item(0, 1)])
    batch = {k: v for k, v in batch.items() if isinstance(v, torch.Tensor)}
    torch.manual_seed(0)
    model = GeometryNet(sh_order=2, width=8, depth=2, decoder_width=6, depth_head=True).train()
    opt = torch.optim.Adam(model.parameters(), lr=5e-3)
    first = last = None
    for _ in range(200):
        terms = geometry_losses(model(batch["input"]), batch)
        last = float(terms["depth"].detach())
        first = first or last
        opt.zero_grad()
        terms["total"].backward()
        opt.step()
    print(f"depth loss {first:.3f} -> {last:.3f}")
    assert last < 0.1 * first, (first, last)
    without = {k: v for k, v in batch.items() if k != "depth"}
    with pytest.raises(ValueError, match="carries no depth"):
        geometry_losses(model(batch["input"]), without)


def test_the_head_is_added_to_a_model_without_it():
    """--init from a model without the head: every weight carried over, the geometry head's first five
    channels too, so its outputs are the start model's; the depth channel is new."""
    torch.manual_seed(1)
    start = GeometryNet(sh_order=2, width=4, depth=2, decoder_width=4).eval()
    model = GeometryNet(sh_order=2, width=4, depth=2, decoder_width=4, depth_head=True).eval()
    init_weights(model, start, "start.safetensors")
    x = torch.rand(1, 3, 16, 16) * 2 - 1
    with torch.no_grad():
        a, b = start(x), model(x)
    for name in ("normal", "alpha", "albedo", "light"):
        assert torch.equal(a[name], b[name]), name
    assert "depth" in b and "depth" not in a
    other = GeometryNet(sh_order=2, width=8, depth=2, decoder_width=4, depth_head=True)
    with pytest.raises(ValueError, match="start.safetensors"):
        init_weights(other, start, "start.safetensors")


def test_depth_errors_align_before_scoring():
    """An affine copy of the truth scores 0; a flat depth and an inverted one score a whole relief
    (shape 1: the alignment's scale is >= 0); AbsRel is the error over the distance."""
    from model.scoring.depth_metrics import depth_errors

    rng = np.random.default_rng(5)
    truth = rng.uniform(2.0, 2.4, (10, 12))
    weight = np.ones_like(truth)
    exact = depth_errors(-3.0 + 0.2 * truth, truth, weight)
    assert max(exact.values()) < 1e-12
    for bad in (np.zeros_like(truth), -truth):
        assert depth_errors(bad, truth, weight)["shape"] == pytest.approx(1.0, abs=1e-12)
    off = depth_errors(truth + np.where(np.arange(12) < 6, 0.05, -0.05), truth, weight)
    spread = np.abs(truth - truth.mean()).mean()
    assert 0 < off["shape"] < 0.05 / spread + 1e-9 and off["absrel"] < 0.05 / 2.0


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_evaluate_reports_the_depth_error_per_framing(scenes, tmp_path):
    """model.evaluate on a checkpoint with the head: a depth table per framing (the network's depth and
    the relief of its normals), in evaluation.md and .json; a model without the head has none."""
    import json

    from model import evaluate
    from model.training.checkpoint import save_model

    for head in (True, False):
        torch.manual_seed(0)
        net = GeometryNet(sh_order=2, width=4, depth=2, decoder_width=4, depth_head=head).eval()
        weights = save_model(net, tmp_path / f"m{head}.safetensors")
        evaluate.evaluate(weights, scenes[0].parent, tmp_path / f"e{head}", size=32, sheet_rows=1, mask="alpha")
        report = json.loads((tmp_path / f"e{head}" / "evaluation.json").read_text())
        text = (tmp_path / f"e{head}" / "evaluation.md").read_text()
        if not head:
            assert report["depth"] is None and "Depth, per framing" not in text
            continue
        rows = report["depth"]["-"]   # the analytic scenes have no framing
        assert set(rows) == {"network depth", "relief of its normals"}
        assert rows["network depth"]["pairs"] == report["pairs"]
        assert all(0 <= v["shape"] and 0 <= v["absrel_med"] for v in rows.values())
        assert "Depth, per framing" in text
