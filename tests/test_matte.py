"""Person matte (relight/matte.py): hash-checked model, people, bad input, accuracy on real photos."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from relight import matte
from relight.models import REGISTRY_PATH
from relight.photo import read_photo

EVAL_DIR = Path(matte.__file__).resolve().parent / "data" / "matte_eval"


def _photo(name: str) -> np.ndarray:
    image, _ = read_photo(next(EVAL_DIR.glob(name + ".*")))
    return image


def test_shipped_model_is_registered_and_hash_checked(tmp_path):
    path = matte.matte_model_path()
    assert path.name == "person_matte.onnx" and path.is_file()
    # a byte changed: refused before onnxruntime sees it, with the registry's hash or the sidecar's
    bad = tmp_path / path.name
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    bad.write_bytes(bytes(data))
    shutil.copy(path.with_name(path.name + ".sha256"), tmp_path)
    with pytest.raises(ValueError, match="SHA-256 mismatch"):
        matte.person_matte(_photo("biden"), model_path=bad, registry_path=tmp_path / "models.json")
    (tmp_path / (path.name + ".sha256")).unlink()
    with pytest.raises(ValueError, match="no SHA-256 to check it against"):
        matte.person_matte(_photo("biden"), model_path=bad, registry_path=tmp_path / "models.json")
    # the registry of the package names the same hash as the sidecar
    from relight.models import load_registry, read_sidecar

    assert load_registry(REGISTRY_PATH)["models"][matte.MATTE_MODEL_NAME]["sha256"] == read_sidecar(path)


def test_matte_of_a_photo_is_soft_bounded_and_boxed():
    photo = _photo("obama_standing")
    m = matte.person_matte(photo)
    assert m.alpha.shape == photo.shape[:2] and m.alpha.dtype == np.float32
    assert m.alpha.min() == 0.0 and m.alpha.max() == 1.0
    soft = np.count_nonzero((m.alpha > 0) & (m.alpha < 1))
    assert soft > 0.01 * np.count_nonzero(m.alpha)  # a feathered edge, not a binary cut
    x0, y0, x1, y1 = m.box
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
    # Biden fills more of his half than Obama of his: he is person 1, alone in his matte
    assert first.alpha[:, :split].mean() > 0.5 and first.alpha[:, split + 20:].max() == 0.0
    assert second.alpha[:, split + 20:].mean() > 0.3 and second.alpha[:, :split - 20].max() == 0.0
    assert first.box[2] <= split + 20 and second.box[0] >= split - 20
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
