"""The training pack (model.samples.training_pack): what goes in comes back bit for bit, a damaged
file is refused naming it, and model.train trains from it without the scene files."""

import json
import zipfile

import numpy as np
import pytest

from model import train
from model.samples.data_crops import load_cropped
from model.samples.data_splits import body_key, held_out_light_names
from model.samples.synthetic import write_analytic_dataset
from model.samples.training_pack import FORMAT, read_manifest, read_training_pack, write_training_pack
from relight.files.dataset import read_sidecar

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    folder = tmp_path_factory.mktemp("analytic")
    return write_analytic_dataset(folder, n_scenes=4, size=32, order=4, lights=("studio", "city", "venice"),
                                  body=True)


def test_pack_round_trips_the_cropped_scenes_exactly(scenes, tmp_path):
    """Every map is the loader's crop rounded to float16, every light the loader's float32, with
    nothing else changed; the manifest names each scene's EXR hash and body, and the source."""
    path = write_training_pack(scenes, tmp_path / "p.npz", 16, 2, padding=1, source={"seed": 7})
    pack = read_training_pack(path)
    assert pack.manifest["format"] == FORMAT and (pack.size, pack.order) == (16, 2)
    assert pack.manifest["source"] == {"seed": 7} and pack.names == [p.stem for p in scenes]
    for json_path, rec, got in zip(scenes, pack.manifest["scenes"], pack.scenes):
        meta = read_sidecar(json_path)
        assert rec["exr_sha256"] == meta["exr_sha256"] and rec["body_key"] == body_key(meta)
        want = load_cropped(json_path, 16, 2, 1, held_out_light_names())
        f16 = lambda a: a.astype(np.float16).astype(np.float32)
        for name in ("alpha", "albedo", "transport", "normal"):
            assert np.array_equal(getattr(got, name), f16(getattr(want, name))), name
            assert getattr(got, name).dtype == np.float32
        assert all(np.array_equal(g, f16(w)) for g, w in zip(got.images, want.images) if w is not None)
        assert [g is None for g in got.images] == [w is None for w in want.images]
        assert all(np.array_equal(g, w) for g, w in zip(got.lights, want.lights))
        assert (got.index, got.light_names, got.held_out) == (want.index, want.light_names, want.held_out)
        # the body prior's normals are made unit again after float16, as data_crops' packs do
        assert np.allclose(got.body, want.body, atol=2e-3)
    # packed twice, the same arrays (the zip's own dates aside)
    again = read_training_pack(write_training_pack(scenes, tmp_path / "q.npz", 16, 2, padding=1, source={"seed": 7}))
    assert again.manifest == pack.manifest


def test_a_damaged_or_foreign_pack_is_refused_naming_the_file(scenes, tmp_path):
    path = write_training_pack(scenes[:2], tmp_path / "p.npz", 16, 2, padding=1)
    data = path.read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    # one scene's maps replaced by others of the same shape: only the manifest's hashes can tell
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["s0"] = arrays["s0"] + np.float16(0.5)
    with open(tmp_path / "swapped.npz", "wb") as f:
        np.savez_compressed(f, **arrays)
    other = dict(arrays, manifest=np.frombuffer(json.dumps({"format": "relight-pack/2"}).encode(), np.uint8))
    with open(tmp_path / "foreign.npz", "wb") as f:
        np.savez_compressed(f, **other)
    with zipfile.ZipFile(tmp_path / "empty.npz", "w"):
        pass
    for name, why in (("cut.npz", "not a readable training pack"), ("swapped.npz", "do not match"),
                      ("foreign.npz", "unknown format"), ("empty.npz", "not a readable training pack"),
                      ("missing.npz", "not found")):
        with pytest.raises(ValueError, match=why) as err:
            read_training_pack(tmp_path / name)
        assert str(tmp_path / name) in str(err.value)
    with pytest.raises(ValueError, match="unknown format"):
        read_manifest(tmp_path / "foreign.npz")


def test_train_from_a_pack_without_the_scene_files(scenes, tmp_path, capsys, monkeypatch):
    """The scene files moved away, model.train --from-pack trains at the pack's size and order, and
    records where its scenes came from; a pack at another size is refused in one line."""
    path = write_training_pack(scenes, tmp_path / "p.npz", 16, 2, padding=1, source={"seed": 7})
    for json_path in scenes:  # nothing but the pack is left to read
        json_path.rename(json_path.with_suffix(".gone"))
        json_path.with_suffix(".exr").rename(json_path.with_suffix(".exrgone"))
    try:
        argv = ["--from-pack", str(path), "--out", str(tmp_path / "run"), "--steps", "2", "--batch", "2",
                "--width", "4", "--depth", "2", "--padding", "1", "--val-fraction", "0.25", "--quiet"]
        assert train.main(argv) == 0
        record = json.loads((tmp_path / "run" / "model.json").read_text())
        assert record["config"]["sh_order"] == 2 and record["training"]["args"]["size"] == 16
        assert record["training"]["pack_source"] == {"seed": 7}
        assert record["training"]["train_scenes"] + record["training"]["val_scenes"] == 4
        capsys.readouterr()
        assert train.main(argv[:-1] + ["--size", "32", "--quiet"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "packed at 16 px" in err[0] and str(path) in err[0]
        # the held-out maps changed since packing: its per-scene held-out flags are stale
        monkeypatch.setattr("model.training.train_data.held_out_light_names", lambda: frozenset({"studio"}))
        assert train.main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "packed when the held-out maps were" in err[0] and str(path) in err[0]
    finally:
        for json_path in scenes:
            json_path.with_suffix(".gone").rename(json_path)
            json_path.with_suffix(".exrgone").rename(json_path.with_suffix(".exr"))
