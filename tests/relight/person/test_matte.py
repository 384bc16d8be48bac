"""Person matte (relight/person/matte.py): hash-checked model, people, bad input, accuracy on real photos."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from evaluation.matte_eval import EVAL_DIR
from relight.person import matte
from relight.models import REGISTRY_PATH
from relight.files.photo import read_photo



def _photo(name: str) -> np.ndarray:
    image, _ = read_photo(next(EVAL_DIR.glob(name + ".*")))
    return image


def _registry_copy(folder: Path) -> Path:
    """The shipped matte networks and a registry of only them, copied into `folder`."""
    import json

    from relight.models import load_registry

    registry = load_registry(REGISTRY_PATH)
    names = [name for name, _ in matte.MODELS.values()]
    copy = {"format": registry["format"], "default": None, "models": {n: registry["models"][n] for n in names}}
    for path in matte.model_paths().values():
        shutil.copy(path, folder)
        shutil.copy(path.with_name(path.name + ".sha256"), folder)
    (folder / "models.json").write_text(json.dumps(copy))
    return folder / "models.json"


@pytest.mark.parametrize("kind", sorted(matte.MODELS))
def test_shipped_networks_are_registered_and_hash_checked(tmp_path, kind):
    from relight.models import load_registry, read_sidecar

    paths = matte.model_paths()
    entries = load_registry(REGISTRY_PATH)["models"]
    for k, (name, file) in matte.MODELS.items():  # the registry's hash is the sidecar's
        assert paths[k].name == file and entries[name]["sha256"] == read_sidecar(paths[k])
    registry = _registry_copy(tmp_path)
    photo = _photo("biden")
    # one byte of one network changed: refused before onnxruntime sees it
    bad = tmp_path / paths[kind].name
    good = bad.read_bytes()
    data = bytearray(good)
    data[len(data) // 2] ^= 0xFF
    bad.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="SHA-256 mismatch"):
        matte.person_matte(photo, registry_path=registry)
    bad.write_bytes(good)
    assert matte.person_matte(photo, registry_path=registry).count == 1  # the intact copy loads
    bad.write_bytes(bytes(data))
    # no recorded hash at all (sidecar gone, entry gone): refused too
    import json

    reg = json.loads(registry.read_text())
    del reg["models"][matte.MODELS[kind][0]]
    (tmp_path / "other").mkdir()
    for p in tmp_path.glob("*.onnx*"):
        shutil.copy(p, tmp_path / "other")
    (tmp_path / "other" / (bad.name + ".sha256")).unlink()
    (tmp_path / "other" / "models.json").write_text(json.dumps(reg))
    with pytest.raises(ValueError, match="no SHA-256 to check it against"):
        matte.person_matte(photo, registry_path=tmp_path / "other" / "models.json")


def test_matte_of_a_photo_is_soft_bounded_and_boxed():
    photo = _photo("obama_standing")
    m = matte.person_matte(photo)
    assert m.alpha.shape == photo.shape[:2] and m.alpha.dtype == np.float32
    assert m.alpha.min() == 0.0 and m.alpha.max() == 1.0
    soft = np.count_nonzero((m.alpha > 0) & (m.alpha < 1))
    assert soft > 0.01 * np.count_nonzero(m.alpha)  # a feathered edge, not a binary cut
    y0, y1, x0, x1 = m.box
    inside = np.zeros_like(m.alpha, bool)
    inside[y0:y1, x0:x1] = True
    assert not np.any(m.alpha[~inside])  # the box holds every matte pixel ...
    assert m.alpha[y0].any() and m.alpha[y1 - 1].any() and m.alpha[:, x0].any() and m.alpha[:, x1 - 1].any()
    assert (m.index, m.count) == (1, 1)


def test_several_people_largest_first_and_selectable():
    left, right = _photo("biden"), _photo("obama_standing")  # both 800 px tall
    both = np.concatenate([left, right], axis=1)
    split = left.shape[1]
    first, again, second = (matte.person_matte(both, p) for p in (None, 1, 2))
    assert first.count == second.count == 2 and (first.index, second.index) == (1, 2)
    np.testing.assert_array_equal(first.alpha, again.alpha)
    # Biden fills more of his half than Obama of his: he is person 1; each matte holds one man
    # (measured: person 1 reaches 52 px past the seam with at most 0.14, the pose mask's soft tail)
    assert first.alpha[:, :split].mean() > 0.5 and first.alpha[:, split + 20:].max() < 0.5
    assert first.alpha[:, split + 20:].mean() < 0.01
    assert second.alpha[:, split + 20:].mean() > 0.3 and second.alpha[:, :split - 20].max() < 0.5
    assert first.box.x1 <= split + 80 and second.box.x0 >= split - 20
    with pytest.raises(ValueError, match="person 3 asked for, but the photo shows 2 people"):
        matte.person_matte(both, 3)
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ValueError, match="person must be 1"):
            matte.person_matte(both, bad)


@pytest.mark.parametrize("scene", ["black", "grey", "noise", "gradient"])
def test_no_person_is_one_clear_error(scene):
    rng = np.random.default_rng(0)
    image = {"black": np.zeros((300, 400, 3), np.float32),
             "grey": np.full((300, 400, 3), 0.2, np.float32),
             "noise": rng.random((300, 400, 3), dtype=np.float32),
             "gradient": np.broadcast_to(np.linspace(0.05, 0.8, 300, dtype=np.float32)[:, None, None],
                                         (300, 400, 3)).copy()}[scene]
    with pytest.raises(matte.NoPersonError, match="^no person found in the photo"):
        matte.person_matte(image)


@pytest.mark.parametrize("image, message", [
    (np.zeros((16, 300, 3), np.float32), "too small for a person matte"),
    (np.zeros((300, 300), np.float32), "greyscale"),
    (np.zeros((300, 300, 1), np.float32), "greyscale"),
    (np.zeros((300, 300, 4), np.float32), "4 channels"),
    (np.zeros((300, 300, 3), np.uint16), "dtype uint16"),
    (np.zeros((300, 300, 3), np.uint8), "dtype uint8"),
    (np.full((300, 300, 3), np.nan, np.float32), "NaN or Inf"),
])
def test_bad_input_is_one_clear_error(image, message):
    with pytest.raises(ValueError, match=message) as info:
        matte.person_matte(image)
    assert "\n" not in str(info.value)


# measured 2026-11-22 (python -m evaluation.matte_eval): IoU astronaut 0.953, biden 0.958, camera 0.939,
# grace_hopper 0.986, obama 0.985, obama_standing 0.989, mean 0.968. Margin 0.03 for runtime and
# library drift (onnxruntime, Pillow resampling); a matte that lost a limb or took in the background
# falls far below (the network alpha head: mean 0.49 on the same photos; the selfie network alone
# 0.76 on the astronaut, whose helmet it takes in: docs/MATTE.md).
IOU_MARGIN = 0.03
MEASURED_IOU = {"astronaut": 0.953, "biden": 0.958, "camera": 0.939, "grace_hopper": 0.986,
                "obama": 0.985, "obama_standing": 0.989}


# mean spill (soft matte outside the reference per reference pixel) measured 0.026; the arithmetic
# mean of the two networks gave 0.037 (ghosts): the bound, measured + 25 %, tells them apart
MAX_MEAN_SPILL = 0.026 * 1.25


def test_matte_matches_the_references_of_the_bundled_photos():
    from evaluation.matte_eval import boundary_f, eval_photos, iou, read_reference, spill

    found = {name: (p, r) for name, p, r in eval_photos()}
    assert sorted(found) == sorted(MEASURED_IOU)
    scores, spills = {}, []
    for name, (photo_path, ref_path) in found.items():
        photo, _ = read_photo(photo_path)
        alpha = matte.person_matte(photo).alpha
        reference = read_reference(ref_path, photo.shape[:2])
        scores[name] = iou(alpha, reference)
        assert scores[name] >= MEASURED_IOU[name] - IOU_MARGIN, (name, scores[name])
        assert boundary_f(alpha, reference) > 0.7, name
        spills.append(spill(alpha, reference))
    assert np.mean(list(scores.values())) >= np.mean(list(MEASURED_IOU.values())) - IOU_MARGIN
    assert np.mean(spills) <= MAX_MEAN_SPILL, spills


def test_metrics_on_known_shapes():
    from evaluation.matte_eval import boundary_f, iou, spill

    ref = np.zeros((100, 100), bool)
    ref[20:60, 20:60] = True                   # 1600 px
    pred = np.zeros((100, 100), np.float32)
    pred[20:60, 30:70] = 1.0                   # shifted 10 px: overlap 1200, union 2000
    assert iou(pred, ref) == pytest.approx(0.6)
    assert boundary_f(ref.astype(np.float32), ref) == 1.0
    # tolerance 0.008 x 141 px = 1 px: a 10 px shift keeps only the top/bottom edges' overlap
    assert 0.3 < boundary_f(pred, ref) < 0.7
    assert spill(pred, ref) == pytest.approx(400 / 1600)  # 10 x 40 px outside, per reference pixel


# ------------------------------------------------------------------ `relight image`


def _run(args):
    from relight.cli import main

    return main(["image", *map(str, args)])


def test_cli_no_person_and_bad_choices_exit_2_and_write_nothing(tmp_path, capsys):
    from PIL import Image

    empty = tmp_path / "wall.png"
    Image.fromarray(np.full((200, 300, 3), 90, np.uint8)).save(empty)
    out = tmp_path / "out.png"
    assert _run([empty, "--light", "studio", "--out", out]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"relight image: error: {empty}: no person found in the photo")
    tiny = tmp_path / "tiny.png"
    Image.fromarray(np.full((20, 30, 3), 90, np.uint8)).save(tiny)
    assert _run([tiny, "--light", "studio", "--out", out]) == 2
    assert "too small for a person matte" in capsys.readouterr().err
    photo = EVAL_DIR / "biden.jpg"
    assert _run([photo, "--light", "studio", "--person", "2", "--out", out]) == 2
    assert "person 2 asked for, but the photo shows 1 person" in capsys.readouterr().err
    assert _run([photo, "--light", "studio", "--person", "0", "--out", out]) == 2
    assert _run([photo, "--light", "studio", "--matte", "alpha", "--out", out]) == 2
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["tiny.png", "wall.png"]


def test_cli_relights_only_the_person_and_keeps_the_network_matte_for_comparison(tmp_path):
    photo = EVAL_DIR / "obama_standing.jpg"
    image, _ = read_photo(photo)
    from relight.network import quality

    # the matte the command uses: Draft's person segmenter
    alpha = matte.person_matte(image, method=quality.preset("draft").matte_method).alpha
    out, net = tmp_path / "person.png", tmp_path / "network.png"
    assert _run([photo, "--light", "studio", "--quality", "draft", "--out", out]) == 0
    assert _run([photo, "--light", "studio", "--quality", "draft", "--matte", "network", "--out", net]) == 0
    relit, _ = read_photo(out)
    background = alpha == 0
    # outside the person the photo is untouched (8-bit round trip of the same values)
    np.testing.assert_array_equal(relit[background], image[background])
    assert np.abs(relit[alpha == 1] - image[alpha == 1]).mean() > 0.01  # and the person is relit
    by_network, _ = read_photo(net)
    assert np.abs(by_network - relit).mean() > 0  # --matte network: the alpha head's matte, not the segmenter's


def test_cli_greyscale_16bit_and_alpha_files(tmp_path):
    from PIL import Image

    rgb = np.asarray(Image.open(EVAL_DIR / "biden.jpg").convert("RGB"))
    grey = tmp_path / "grey.png"
    Image.fromarray(rgb.mean(axis=2).astype(np.uint8)).save(grey)
    deep = tmp_path / "deep.png"
    Image.fromarray((rgb[..., 1].astype(np.uint16) * 257)).save(deep)  # 16-bit greyscale
    alpha = tmp_path / "alpha.png"
    rgba = np.dstack([rgb, np.where(np.arange(rgb.shape[1]) < 200, 255, 0).astype(np.uint8)[None, :]
                      .repeat(rgb.shape[0], 0)])
    Image.fromarray(rgba, "RGBA").save(alpha)
    for src in (grey, deep, alpha):
        out = tmp_path / (src.stem + "_out.png")
        assert _run([src, "--light", "studio", "--quality", "draft", "--out", out]) == 0, src
        assert out.is_file()
    # the file's own alpha is the mask: right of column 200 the photo is untouched
    relit, _ = read_photo(tmp_path / "alpha_out.png")
    original, _ = read_photo(alpha)
    np.testing.assert_array_equal(relit[:, 200:], original[:, 200:])


def test_decompose_takes_the_person_matte_as_its_mask():
    from relight.network import quality
    from relight.network.runtime import Relighter

    photo = _photo("obama_standing")
    relighter = Relighter(quality.model_path("draft"), threads=1, working_size=quality.preset("draft").working_size)
    d = relighter.decompose(photo, matte="person", person=1)
    expected = matte.person_matte(photo)
    np.testing.assert_array_equal(d.mask, expected.alpha)  # exactly the matte, as a given mask would be
    assert (d.person_matte.index, d.person_matte.count) == (1, 1)
    x0, y0, x1, y1 = expected.box
    by, by1, bx, bx1 = d.box  # the crop holds the person (plus the runtime's margin)
    assert by <= y0 and bx <= x0 and by1 >= y1 and bx1 >= x1
    assert relighter.decompose(photo, matte="network").person_matte is None  # the alpha head stays selectable
    with pytest.raises(ValueError, match="matte must be one of"):
        relighter.decompose(photo, matte="auto")
    with pytest.raises(matte.NoPersonError):
        relighter.decompose(np.full((200, 300, 3), 0.3, np.float32), matte="person")


def test_the_librarys_default_decompose_uses_the_person_matte():
    """`Relighter().decompose(photo)` as its docstring shows it (default model, threads and
    matte) mattes real photos like the command and the add-on: the person segmenter's IoU,
    not the alpha head's (0.49 on these photos)."""
    import inspect

    from evaluation.matte_eval import eval_photos, iou, read_reference
    from relight.network.runtime import Relighter

    assert inspect.signature(Relighter.decompose).parameters["matte"].default == "person"
    relighter = Relighter()
    scores = {}
    for name, photo_path, ref_path in eval_photos():
        photo, _ = read_photo(photo_path)
        d = relighter.decompose(photo)
        assert d.person_matte is not None and d.person_matte.index == 1
        scores[name] = iou(d.full_alpha(), read_reference(ref_path, photo.shape[:2]))
        assert scores[name] >= MEASURED_IOU[name] - IOU_MARGIN, (name, scores[name])
    assert np.mean(list(scores.values())) >= 0.90  # issue 24's goal; measured 0.968


def test_24_megapixel_photo_with_the_person_matte_stays_under_2_gb(tmp_path):
    """The whole `relight image` run with the person matte on 24 MP (a bundled photo enlarged):
    the full-resolution matte adds one float32 plane; the limit is the runtime's (2 GB)."""
    import subprocess
    import sys

    from PIL import Image

    from export.random_model import export_random_model
    from peak_memory import CHILD, LIMIT_BYTES

    model, _, _ = export_random_model(tmp_path / "m.onnx", seed=2, sh_order=4, width=4, depth=2)
    with Image.open(EVAL_DIR / "obama_standing.jpg") as im:
        im.convert("RGB").resize((3690, 6000), Image.Resampling.BILINEAR).save(tmp_path / "big.jpg", quality=85)
    out = tmp_path / "big_relit.png"
    res = subprocess.run([sys.executable, "-c", CHILD, "image", str(tmp_path / "big.jpg"), "--light", "studio",
                          "--model", str(model), "--out", str(out), "--threads", "2"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    peak = int(res.stdout.split("PEAK_RSS_BYTES")[1].split()[0])
    assert peak < LIMIT_BYTES, f"peak RSS {peak / 2**20:.0f} MiB"


def test_the_relighters_threads_reach_the_matte():
    # issue 39: `relight image --threads N` opened the matte's networks on every core
    from relight.network import quality
    from relight.network.runtime import Relighter

    relighter = Relighter(quality.model_path("draft"), threads=1, working_size=quality.preset("draft").working_size)
    before = set(matte._SESSIONS)
    relighter.decompose(_photo("obama_standing"), matte="person", matte_method="selfie")
    assert {key[2] for key in set(matte._SESSIONS) - before} <= {1}
    assert any(key[0] == "selfie" and key[2] == 1 for key in matte._SESSIONS)
