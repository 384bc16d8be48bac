"""The compact training pack (model.samples.compact_pack, read by model.samples.packs): each plane comes back within the error
its code allows (derived below from the code steps), lights and masks as stored, a damaged file
is refused naming it, and model.train trains from it as from an exact pack."""

import json

import numpy as np
import pytest

from model import train
from model.samples import compact_pack
from model.samples.compact_pack import (LOG_STOPS, decode_scene, encode_scene, fill_outside, from_octahedral,
                                        octahedral, read_compact_pack, write_compact_pack)
from model.samples.data_augment import preset_training_lights
from model.samples.data_crops import CroppedScene
from model.samples.synthetic import write_analytic_dataset
from model.samples.packs import read_training_packs
from model.samples.training_pack import COMPACT_FORMAT, read_manifest, read_training_pack, write_training_pack

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py

S = 32  # four 8 x 8 JPEG blocks a side


def unit(v):
    return v / np.linalg.norm(v, axis=0, keepdims=True)


def test_octahedral_round_trips_every_direction():
    """The octahedral square is a bijection of the sphere: axes, both hemispheres, the fold."""
    rng = np.random.default_rng(0)
    dirs = unit(rng.normal(size=(3, 40, 40)))
    axes = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float).T[:, :, None]
    for n in (dirs, axes):
        code = octahedral(n)
        assert code.shape[0] == 2 and np.abs(code).max() <= 1 + 1e-6
        assert np.abs(from_octahedral(code) - n).max() < 1e-5


def test_fill_outside_keeps_the_known_pixels_and_stays_inside_their_range():
    rng = np.random.default_rng(1)
    plane = rng.uniform(2, 3, (S, S)).astype(np.float32)
    known = np.zeros((S, S), bool)
    known[5:20, 9:14] = True
    filled = fill_outside(plane, known)
    assert np.array_equal(filled[known], plane[known])
    # averages of known values only: never outside their range
    assert plane[known].min() - 1e-5 <= filled.min() and filled.max() <= plane[known].max() + 1e-5
    assert np.allclose(fill_outside(np.full((S, S), 7.0, np.float32), known), 7.0)
    assert not fill_outside(plane, np.zeros((S, S), bool)).any()


def block_constant(rng, channels, lo, hi):
    """[channels, S, S] constant on each 8 x 8 block: a JPEG codes it by its DC terms alone."""
    return np.kron(rng.uniform(lo, hi, (channels, S // 8, S // 8)), np.ones((1, 8, 8))).astype(np.float32)


@pytest.fixture
def blocky_scene():
    """A scene whose every plane is constant on JPEG blocks, the person on whole blocks."""
    rng = np.random.default_rng(2)
    person = np.zeros((S, S), np.float32)
    person[8:32, 8:24] = 1
    alpha = person * np.kron(rng.integers(1, 256, (S // 8, S // 8)) / 255, np.ones((8, 8)))
    normal = unit(block_constant(rng, 3, -1, 1)) * person
    body_cover = np.zeros((S, S), np.float32)
    body_cover[8:24, 8:24] = 0.8
    return CroppedScene(index=3, alpha=alpha[None].astype(np.float32),
                        albedo=block_constant(rng, 3, 0.05, 0.9) * person,
                        transport=block_constant(rng, 25, -0.3, 0.3) * person,
                        normal=normal.astype(np.float32),
                        images=[block_constant(rng, 3, 0.01, 3.0), None],
                        lights=[rng.normal(size=(25, 3)).astype(np.float32) for _ in range(2)],
                        light_names=["forest", "hard:sun"], held_out=[False, True],
                        body=np.concatenate([unit(block_constant(rng, 3, -1, 1)) * (body_cover > 0),
                                             body_cover[None]]).astype(np.float32),
                        depth=(block_constant(rng, 1, 2.0, 2.6) * person).astype(np.float32))


def test_each_plane_comes_back_within_its_code_steps(blocky_scene):
    """On block-constant planes a JPEG of quality 90 moves a value by at most its DC quantizer
    over 16 (3/16 of a code) plus its rounding (1/2): under one code step, plus the half step of
    rounding to 8 bits, so 1.5 steps bound every lossy plane. Lights are stored as float32, the
    masks as 8 bits (half a step), the depth as 16 bits over the person's range (half a step)."""
    c = blocky_scene
    blob, floats, rec = encode_scene(c, quality=90)
    d = decode_scene(blob, floats, {**rec, "index": 3, "names": c.light_names, "held_out": c.held_out,
                                    "traced": [True, False], "body": True})
    person = c.alpha[0] > 0
    steps = 1.5
    assert all(np.array_equal(a, b) for a, b in zip(c.lights, d.lights))
    assert (d.index, d.light_names, d.held_out, d.images[1]) == (3, c.light_names, c.held_out, None)
    assert np.abs(d.alpha - c.alpha).max() <= 0.5 / 255 + 1e-7
    for got in (d.albedo, d.normal, d.transport):  # nothing off the person
        assert not got[:, ~person].any()
    gamma = lambda a: a ** (1 / compact_pack.GAMMA)
    assert np.abs(gamma(d.albedo) - gamma(c.albedo))[:, person].max() <= steps / 255
    assert np.abs(octahedral(d.normal) - octahedral(c.normal))[:, person].max() <= steps * 2 / 255 + 1e-6
    assert np.abs(np.linalg.norm(d.normal[:, person], axis=0) - 1).max() < 1e-5
    # one step for all components, an orthonormal basis: |dT| <= sqrt(rank) * 1.5 steps
    comps_step = np.abs(np.einsum("nr,nhw->rhw", floats_of(floats, rec, "transport_basis"),
                                  c.transport - floats_of(floats, rec, "transport_mean")[:, None, None])
                        [:, person]).max() / 127
    err = np.linalg.norm(d.transport - c.transport, axis=0)[person]
    assert err.max() <= np.sqrt(rec["rank"]) * steps * comps_step * (1 + 1e-4)
    log_err = np.abs(np.log2(d.images[0]) - np.log2(c.images[0])).max()
    assert log_err <= steps * LOG_STOPS / 255 + 1e-5
    cover = c.body[3] > 0
    assert np.abs(d.body[3] - c.body[3]).max() <= 0.5 / 255 + 1e-7
    assert np.abs(octahedral(d.body[:3]) - octahedral(c.body[:3]))[:, cover].max() <= steps * 2 / 255 + 1e-6
    near, far = c.depth[0][person].min(), c.depth[0][person].max()
    assert np.abs(d.depth - c.depth)[0][person].max() <= 0.5 * (far - near) / 65534 + 1e-6
    assert not d.depth[0][~person].any()


def floats_of(floats, rec, name):
    k = 0
    for key, shape in rec["floats"]:
        size = int(np.prod(shape))
        if key == name:
            return floats[k:k + size].reshape(shape)
        k += size
    raise KeyError(name)


def test_a_scene_with_nan_is_refused(blocky_scene):
    blocky_scene.transport[3, 10, 10] = np.nan
    with pytest.raises(ValueError, match="scene 3: NaN"):
        encode_scene(blocky_scene, quality=90)


def test_a_higher_quality_costs_bytes_and_buys_accuracy(blocky_scene):
    """On a scene with texture (noise on every plane), quality 95 is larger and closer than 50."""
    rng = np.random.default_rng(3)
    c = blocky_scene
    c.albedo = np.clip(c.albedo + rng.normal(0, 0.05, c.albedo.shape) * (c.alpha > 0), 0, 1).astype(np.float32)
    c.images = [c.images[0] * rng.uniform(0.7, 1.3, c.images[0].shape).astype(np.float32), None]
    sizes, errors = [], []
    for q in (50, 95):
        blob, floats, rec = encode_scene(c, quality=q)
        d = decode_scene(blob, floats, {**rec, "index": 3, "names": c.light_names, "held_out": c.held_out,
                                        "traced": [True, False], "body": True})
        sizes.append(len(blob))
        errors.append([np.abs(d.albedo - c.albedo).mean(), np.abs(np.log2(d.images[0] / c.images[0])).mean()])
    assert sizes[1] > sizes[0]
    assert errors[1][0] < errors[0][0] and errors[1][1] < errors[0][1]


@pytest.fixture(scope="module")
def exact_pack(tmp_path_factory):
    folder = tmp_path_factory.mktemp("analytic")
    scenes = write_analytic_dataset(folder / "scenes", n_scenes=4, size=32, order=4,
                                    lights=("studio", "city", "venice"), body=True)
    return write_training_pack(scenes, folder / "exact.npz", 16, 2, padding=1, source={"seed": 7})


def test_a_compact_pack_reads_as_a_training_pack(exact_pack, tmp_path):
    """Same scenes, names, size, order, lights and source; the passes left out are absent; each
    map near the exact one (analytic scenes: smooth, so the code's error is a few codes)."""
    exact = read_training_pack(exact_pack)
    path = write_compact_pack(exact_pack, tmp_path / "c.npz", quality=90, max_scenes=3, without=("body",))
    pack = read_training_packs([path])  # the one reader model.train calls
    assert pack.manifest["format"] == COMPACT_FORMAT and (pack.size, pack.order) == (16, 2)
    assert pack.manifest["source"] == {"seed": 7} and pack.names == exact.names[:3]
    assert pack.manifest["coding"]["without"] == ["body"] and pack.body_keys == exact.body_keys[:3]
    for got, want in zip(pack.scenes, exact.scenes):
        assert got.body is None and all(np.array_equal(a, b) for a, b in zip(got.lights, want.lights))
        assert (got.index, got.light_names, got.held_out) == (want.index, want.light_names, want.held_out)
        person = want.alpha[0] > 0
        assert np.array_equal(got.alpha[0] > 0, person)
        # the same scene's maps, not another's or a plane out of place (those differ by tenths):
        # a few codes of error on average, as the block-constant test bounds them exactly
        assert np.abs(got.albedo - want.albedo)[:, person].mean() < 4 / 255
        assert np.abs(got.normal - want.normal)[:, person].mean() < 8 / 255
    assert len(read_compact_pack(path, max_scenes=2).scenes) == 2


def test_a_damaged_compact_pack_is_refused_naming_the_file(exact_pack, tmp_path):
    path = write_compact_pack(exact_pack, tmp_path / "c.npz", max_scenes=2)
    data = path.read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["b1"] = arrays["b1"].copy()
    arrays["b1"][-10] ^= 1  # one bit of one scene's bytes: only the manifest's hash can tell
    with open(tmp_path / "flipped.npz", "wb") as f:
        np.savez(f, **arrays)
    arrays["b1"] = np.load(path)["b1"]
    arrays["presets"] = arrays["presets"] * np.float32(2)  # brighter extra lights
    with open(tmp_path / "presets.npz", "wb") as f:
        np.savez(f, **arrays)
    for name, why in (("cut.npz", "not a readable"), ("flipped.npz", "do not match"),
                      ("presets.npz", "preset lights do not match")):
        with pytest.raises(ValueError, match=why) as err:
            read_training_packs([tmp_path / name])
        assert str(tmp_path / name) in str(err.value)
    with pytest.raises(ValueError, match="not an exact one"):  # the exact reader names what it got
        read_training_pack(path)


def test_a_compact_pack_carries_the_preset_lights_and_trains_without_reading_a_map(exact_pack, tmp_path,
                                                                                    monkeypatch):
    """The extra training lights (the bundled maps' SH) travel in the pack: a GPU machine has no
    OpenEXR to read the maps with, so training from the pack must not project them."""
    path = write_compact_pack(exact_pack, tmp_path / "c.npz")
    pack = read_training_packs([path])
    want = preset_training_lights(2)
    assert [name for name, _ in pack.presets] == [name for name, _ in want]
    assert all(np.array_equal(got, sh) for (_, got), (_, sh) in zip(pack.presets, want))

    def no_maps(order):
        raise AssertionError("training from a compact pack projected the preset maps")

    monkeypatch.setattr("model.training.train_data.preset_training_lights", no_maps)
    argv = ["--from-pack", str(path), "--out", str(tmp_path / "run"), "--steps", "1", "--batch", "2",
            "--width", "4", "--depth", "2", "--padding", "1", "--val-fraction", "0.25", "--quiet"]
    assert train.main(argv) == 0


def test_the_command_writes_a_compact_pack_and_model_train_trains_from_it(exact_pack, tmp_path, capsys):
    out = tmp_path / "c.npz"
    assert compact_pack.main([str(exact_pack), str(out), "--quality", "80", "--without", "depth", "body"]) == 0
    said = capsys.readouterr().out.strip().splitlines()
    assert len(said) == 1 and "4 scenes" in said[0] and str(out) in said[0]
    assert read_manifest(out)["coding"] == {"quality": 80, "rank": 25, "without": ["body", "depth"],
                                            "from": exact_pack.name, "first": 0}
    argv = ["--from-pack", str(out), "--out", str(tmp_path / "run"), "--steps", "2", "--batch", "2",
            "--width", "4", "--depth", "2", "--padding", "1", "--val-fraction", "0.25", "--quiet"]
    assert train.main(argv) == 0
    record = json.loads((tmp_path / "run" / "model.json").read_text())
    assert record["training"]["train_scenes"] + record["training"]["val_scenes"] == 4
    for bad, why in ((["--quality", "99"], "quality must be 1-95"), (["--max-scenes", "0"], None)):
        capsys.readouterr()
        code = None
        try:
            code = compact_pack.main([str(exact_pack), str(tmp_path / "bad.npz")] + bad)
        except SystemExit as exc:  # argparse's own refusal
            code = exc.code
        assert code in (1, 2) and not (tmp_path / "bad.npz").exists()
        if why:
            err = capsys.readouterr().err.strip().splitlines()
            assert len(err) == 1 and why in err[0]
    capsys.readouterr()
    assert compact_pack.main([str(tmp_path / "missing.npz"), str(tmp_path / "bad.npz")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing.npz" in err[0]


def test_a_pack_in_parts_trains_as_one(exact_pack, tmp_path, capsys):
    """Two parts (--first) read back as the whole pack's scenes in order; --max-scenes counts
    across parts; a part packed at another size is refused naming it."""
    whole = read_training_pack(exact_pack)
    first = write_compact_pack(exact_pack, tmp_path / "a.npz", max_scenes=3)
    second = write_compact_pack(exact_pack, tmp_path / "b.npz", first=3)
    joined = read_training_packs([first, second])
    assert joined.names == whole.names and joined.body_keys == whole.body_keys
    assert joined.manifest["parts"] == [str(first), str(second)]
    assert [s.index for s in joined.scenes] == [s.index for s in whole.scenes]
    assert read_training_packs([first, second], max_scenes=2).names == whole.names[:2]
    assert read_training_packs([first, second], max_scenes=4).names == whole.names
    other = write_training_pack(write_analytic_dataset(tmp_path / "small", n_scenes=1, size=32, order=4),
                                tmp_path / "other.npz", 8, 2, padding=1)
    with pytest.raises(ValueError, match="another size") as err:
        read_training_packs([first, other])
    assert str(other) in str(err.value)
    argv = ["--from-pack", str(first), str(second), "--out", str(tmp_path / "run"), "--steps", "1", "--batch", "2",
            "--width", "4", "--depth", "2", "--padding", "1", "--val-fraction", "0.25", "--quiet"]
    assert train.main(argv) == 0
    record = json.loads((tmp_path / "run" / "model.json").read_text())
    assert record["training"]["train_scenes"] + record["training"]["val_scenes"] == 4
    assert record["training"]["data"] == [str(first), str(second)]
