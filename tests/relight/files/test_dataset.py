"""relight.files.exr and relight.files.dataset: EXR I/O and the scene file format."""

import json
import os

import numpy as np
import OpenEXR
import pytest

from relight.files import dataset, exr, fileio

RNG = np.random.default_rng(5)
H, W, ORDER = 6, 10, 2
N = (ORDER + 1) ** 2


def make_scene(k_lights=2, transport=True, images=True):
    f32 = lambda *s: RNG.random(s).astype(np.float32)
    channels = {
        "alpha": f32(H, W),
        "albedo": f32(H, W, 3),
        "normal": f32(H, W, 3),
        "material": f32(H, W, 3),
        "depth": f32(H, W, 1),
    }
    if transport:
        channels["transport"] = RNG.normal(size=(H, W, N)).astype(np.float32)
    for k in range(k_lights):
        if images:
            channels[f"image.L{k}"] = f32(H, W, 3)
        if transport:
            channels[f"shading.L{k}"] = f32(H, W, 3)
            channels[f"prt.L{k}"] = f32(H, W, 3)
    lights = [
        {"name": f"light{k}", "source": "preset", "rotation_deg": 30.0 * k, "scale": 1.0,
         "sh": RNG.normal(size=(N, 3)), "sh8": RNG.normal(size=(81, 3))}
        for k in range(k_lights)
    ]
    meta = {"index": 7, "seed": 123, "sh_order": ORDER, "lights": lights, "camera": {"fov": 40.0},
            "passes": {"asked": ["all"], "skipped": []}}
    return channels, meta


# ---------------------------------------------------------------- EXR


def test_exr_round_trip_float_and_half(tmp_path):
    a = RNG.normal(size=(5, 7)).astype(np.float32)
    exr.write_exr(tmp_path / "f.exr", {"x.A": a, "R": a * 2})
    back = exr.read_exr(tmp_path / "f.exr")
    assert sorted(back) == ["R", "x.A"]
    np.testing.assert_array_equal(back["x.A"], a)  # float32 is lossless
    exr.write_exr(tmp_path / "h.exr", {"R": a}, half=True, compression="piz")
    half = exr.read_exr(tmp_path / "h.exr")["R"]
    assert half.dtype == np.float32
    # half precision: 11-bit mantissa, relative rounding error <= 2^-11
    np.testing.assert_allclose(half, a, rtol=2**-11, atol=2**-24)
    assert oct(os.stat(tmp_path / "f.exr").st_mode & 0o777) != "0o600"
    # strided views (a channel of an [H, W, 3] image) are written correctly
    rgb = RNG.random((5, 7, 3)).astype(np.float32)
    exr.write_exr(tmp_path / "v.exr", {"G": rgb[..., 1], "B": np.asfortranarray(rgb[..., 2])})
    back = exr.read_exr(tmp_path / "v.exr")
    np.testing.assert_array_equal(back["G"], rgb[..., 1])
    np.testing.assert_array_equal(back["B"], rgb[..., 2])
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_exr_reads_every_part(tmp_path):
    # Blender 5 writes one part per pass
    a = RNG.random((4, 6)).astype(np.float32)
    parts = [
        OpenEXR.Part({}, {"R": a, "G": a + 1, "B": a + 2}, "ViewLayer.Combined"),
        OpenEXR.Part({}, {"ViewLayer.Depth.Z": a * 3}, "ViewLayer.Depth"),
    ]
    OpenEXR.File(parts).write(str(tmp_path / "multi.exr"))
    back = exr.read_exr(tmp_path / "multi.exr")
    assert sorted(back) == ["ViewLayer.Combined.B", "ViewLayer.Combined.G", "ViewLayer.Combined.R", "ViewLayer.Depth.Z"]
    np.testing.assert_array_equal(back["ViewLayer.Combined.G"], a + 1)
    np.testing.assert_array_equal(back["ViewLayer.Depth.Z"], a * 3)


def test_exr_bad_input(tmp_path):
    with pytest.raises(FileNotFoundError):
        exr.read_exr(tmp_path / "missing.exr")
    (tmp_path / "junk.exr").write_bytes(b"not an exr at all")
    with pytest.raises(ValueError, match="cannot read EXR"):
        exr.read_exr(tmp_path / "junk.exr")
    good = np.zeros((2, 2), np.float32)
    cases = [
        ({}, "at least one channel"),
        ({"R": np.zeros(4, np.float32)}, "2D"),
        ({"R": good, "G": np.zeros((3, 2), np.float32)}, "shape"),
        ({"": good}, "non-empty"),
        ({"R": np.array([["a", "b"], ["c", "d"]])}, "dtype"),
    ]
    for channels, match in cases:
        with pytest.raises(ValueError, match=match):
            exr.write_exr(tmp_path / "bad.exr", channels)
    with pytest.raises(ValueError, match="compression"):
        exr.write_exr(tmp_path / "bad.exr", {"R": good}, compression="jpeg")
    assert not (tmp_path / "bad.exr").exists()


# ---------------------------------------------------------------- scenes


def test_scene_round_trip(tmp_path):
    channels, meta = make_scene()
    exr_path, json_path = dataset.write_scene(dataset.scene_stem(tmp_path, 7), channels, meta)
    assert exr_path.name == "scene_000007.exr" and json_path.name == "scene_000007.json"
    scene = dataset.read_scene(json_path)
    assert scene.index == 7 and scene.resolution == (H, W) and scene.sh_order == ORDER
    np.testing.assert_array_equal(scene.alpha[..., 0], channels["alpha"])
    for name in ("albedo", "normal", "material", "depth", "transport"):
        np.testing.assert_array_equal(getattr(scene, name), channels[name])
    for k in range(2):
        np.testing.assert_array_equal(scene.images[k], channels[f"image.L{k}"])
        np.testing.assert_array_equal(scene.shading[k], channels[f"shading.L{k}"])
        np.testing.assert_array_equal(scene.prt[k], channels[f"prt.L{k}"])
        np.testing.assert_allclose(scene.lights[k]["sh"], meta["lights"][k]["sh"], rtol=1e-15)
        assert scene.lights[k]["sh8"].shape == (81, 3)
    side = json.loads(json_path.read_text())
    assert side["format"] == "relight-scene/1" and side["resolution"] == [H, W]
    assert side["exr_sha256"] == dataset.file_sha256(exr_path)
    assert side["camera"] == {"fov": 40.0} and side["seed"] == 123
    # the EXR holds exactly the channel names of the spec
    names = sorted(exr.read_exr(exr_path))
    assert names == side["channels"]
    assert "transport.00" in names and "transport.08" in names and "image.L1.B" in names
    assert "alpha.A" in names and "normal.Z" in names and "depth.Z" in names
    # the stem and the .exr path work as well
    assert dataset.read_scene(exr_path).index == dataset.read_scene(json_path.with_suffix("")).index == 7


def test_scene_without_optional_passes(tmp_path):
    channels, meta = make_scene(k_lights=1, transport=False)
    dataset.write_scene(tmp_path / "scene_000007", channels, meta)
    scene = dataset.read_scene(tmp_path / "scene_000007.json")
    assert scene.transport is None and scene.shading is None and scene.prt is None
    assert len(scene.images) == 1
    channels, meta = make_scene(k_lights=1, images=False)
    dataset.write_scene(tmp_path / "scene_000007", channels, meta)
    assert dataset.read_scene(tmp_path / "scene_000007").images is None


def test_hash_mismatch_and_partial_files(tmp_path):
    channels, meta = make_scene()
    exr_path, json_path = dataset.write_scene(tmp_path / "scene_000007", channels, meta)
    data = bytearray(exr_path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    exr_path.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="does not match its sidecar"):
        dataset.read_scene(json_path)
    exr_path.write_bytes(bytes(data[: len(data) // 3]))  # truncated by a crash
    with pytest.raises(ValueError, match="partial or modified"):
        dataset.read_scene(json_path)
    exr_path.unlink()
    with pytest.raises(ValueError, match="missing EXR"):
        dataset.read_scene(json_path)


def test_unfinished_scene_and_listing(tmp_path):
    channels, meta = make_scene()
    for index in (3, 12, 7):
        meta = dict(meta, index=index)
        dataset.write_scene(dataset.scene_stem(tmp_path, index), channels, meta)
    # scene 12 crashed before its JSON was written; a stray temp file lingers
    (tmp_path / "scene_000012.json").unlink()
    (tmp_path / ".scene_000020.json.abc.tmp.json").write_text("{}")
    (tmp_path / "scene_000021.exr").write_bytes(b"")
    found = dataset.list_finished_scenes(tmp_path)
    assert [p.name for p in found] == ["scene_000003.json", "scene_000007.json"]
    with pytest.raises(ValueError, match="not finished"):
        dataset.read_scene(tmp_path / "scene_000012.exr")
    with pytest.raises(ValueError, match="does not exist"):
        dataset.list_finished_scenes(tmp_path / "nowhere")


def test_sidecar_problems(tmp_path):
    channels, meta = make_scene()
    _, json_path = dataset.write_scene(tmp_path / "scene_000007", channels, meta)
    side = json.loads(json_path.read_text())
    json_path.write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        dataset.read_scene(json_path)
    json_path.write_text(json.dumps(dict(side, format="other/2")))
    with pytest.raises(ValueError, match="relight-scene/1"):
        dataset.read_scene(json_path)
    json_path.write_text(json.dumps(dict(side, channels=side["channels"][:-1])))
    with pytest.raises(ValueError, match="channels differ"):
        dataset.read_scene(json_path)
    json_path.write_text(json.dumps(dict(side, resolution=[H + 1, W])))
    with pytest.raises(ValueError, match="sidecar says"):
        dataset.read_scene(json_path)
    bad_light = dict(side["lights"][0], sh=[[0, 0, 0]] * 4)
    json_path.write_text(json.dumps(dict(side, lights=[bad_light, side["lights"][1]])))
    with pytest.raises(ValueError, match="light 0 'sh'"):
        dataset.read_scene(json_path)


def test_write_scene_bad_input(tmp_path):
    stem = tmp_path / "scene_000007"

    def expect(match, channels=None, meta=None, path=stem):
        c, m = make_scene()
        if channels is not None:
            c = channels(c)
        if meta is not None:
            m = meta(m)
        with pytest.raises(ValueError, match=match):
            dataset.write_scene(path, c, m)
        assert not stem.with_suffix(".json").exists()

    expect("scene_NNNNNN", path=tmp_path / "frame7")
    expect("index", meta=lambda m: dict(m, index=8))
    expect("lacks 'sh_order'", meta=lambda m: {k: v for k, v in m.items() if k != "sh_order"})
    expect("required pass 'normal'", channels=lambda c: {k: v for k, v in c.items() if k != "normal"})
    expect("transport", channels=lambda c: dict(c, transport=c["transport"][..., :4]))
    expect("albedo", channels=lambda c: dict(c, albedo=c["albedo"][:, :-1]))
    expect("NaN", channels=lambda c: dict(c, depth=np.full((H, W), np.nan, np.float32)))
    expect("unknown scene pass", channels=lambda c: dict(c, emission=c["albedo"]))
    expect("names light 5", channels=lambda c: dict(c, **{"image.L5": c["albedo"]}))
    expect("cover lights", channels=lambda c: {k: v for k, v in c.items() if k != "image.L1"})
    expect("needs the transport", channels=lambda c: {k: v for k, v in c.items() if k != "transport"})
    expect("floating point", channels=lambda c: dict(c, alpha=np.ones((H, W), np.int32)))
    expect("light 1 'sh8'", meta=lambda m: dict(m, lights=[m["lights"][0], dict(m["lights"][1], sh8=np.ones((9, 3)))]))
    expect("non-finite", meta=lambda m: dict(m, camera={"fov": float("nan")}))
    with pytest.raises(ValueError, match="index"):
        dataset.scene_stem(tmp_path, -1)


def test_crash_during_exr_write_leaves_no_scene(tmp_path, monkeypatch):
    channels, meta = make_scene()

    def failing_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(fileio.os, "replace", failing_replace)  # every atomic write renames here
    with pytest.raises(OSError, match="disk full"):
        dataset.write_scene(tmp_path / "scene_000007", channels, meta)
    assert list(tmp_path.iterdir()) == []  # no EXR, no JSON, no temp files


def test_body_passes_round_trip_and_come_together(tmp_path):
    channels, meta = make_scene(k_lights=1)
    body = {"body_normal": RNG.normal(size=(H, W, 3)).astype(np.float32),
            "body_alpha": RNG.random((H, W)).astype(np.float32),
            "body_depth": RNG.random((H, W, 1)).astype(np.float32)}
    dataset.write_scene(tmp_path / "scene_000007", {**channels, **body}, meta)
    s = dataset.read_scene(tmp_path / "scene_000007")
    np.testing.assert_array_equal(s.body_normal, body["body_normal"])
    np.testing.assert_array_equal(s.body_alpha[..., 0], body["body_alpha"])
    np.testing.assert_array_equal(s.body_depth, body["body_depth"])
    plain = tmp_path / "plain"
    plain.mkdir()
    dataset.write_scene(plain / "scene_000007", channels, meta)
    assert dataset.read_scene(plain / "scene_000007").body_normal is None
    with pytest.raises(ValueError, match="body passes must come together"):
        dataset.write_scene(plain / "scene_000007", {**channels, "body_normal": body["body_normal"]}, meta)
