"""relight.lighting.envmap (loading, validation) and relight.lighting.presets."""

import subprocess
import sys

import numpy as np
import pytest

from relight.lighting import envmap, light, presets, sh, sh_projection, sh_rotation
from relight.files import exr

RNG = np.random.default_rng(11)


def to_rgbe(img):
    """Float RGB -> RGBE bytes (Ward's encoding: shared exponent of the max)."""
    v = img.max(axis=-1)
    m, e = np.frexp(v)
    scale = np.where(v > 1e-32, m * 256.0 / np.where(v > 0, v, 1), 0.0)
    rgbe = np.zeros(img.shape[:-1] + (4,), np.uint8)
    rgbe[..., :3] = np.clip(img * scale[..., None], 0, 255).astype(np.uint8)
    rgbe[..., 3] = np.where(v > 1e-32, e + 128, 0)
    return rgbe


def rle_component(values):
    """New-style Radiance run-length code of one component of one scanline."""
    out = bytearray()
    i = 0
    while i < len(values):
        run = 1
        while i + run < len(values) and run < 127 and values[i + run] == values[i]:
            run += 1
        if run >= 3:
            out += bytes([128 + run, values[i]])
            i += run
            continue
        j = i
        while j < len(values) and j - i < 128:
            if j + 2 < len(values) and values[j] == values[j + 1] == values[j + 2]:
                break
            j += 1
        out += bytes([j - i]) + bytes(values[i:j])
        i = j
    return bytes(out)


def write_hdr(path, img, rle):
    rgbe = to_rgbe(img)
    h, w = img.shape[:2]
    data = bytearray(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {h} +X {w}\n".encode())
    for row in rgbe:
        if rle:
            data += bytes([2, 2, w >> 8, w & 255])
            for c in range(4):
                data += rle_component(row[:, c].tolist())
        else:
            data += row.tobytes()
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("rle", [False, True])
def test_radiance_hdr_reader(tmp_path, rle):
    img = RNG.random((8, 16, 3)).astype(np.float32) * 50
    img[2, :] = [1.0, 2.0, 3.0]  # long runs exercise the run-length branch
    img[3, 3] = 0.0
    write_hdr(tmp_path / "m.hdr", img, rle)
    back = envmap.read_radiance_hdr(tmp_path / "m.hdr")
    assert back.shape == (8, 16, 3) and back.dtype == np.float32
    # one 8-bit mantissa step of the shared exponent: |error| <= max / 128
    assert np.all(np.abs(back - img) <= img.max(axis=-1, keepdims=True) / 128 + 1e-30)
    assert np.all(back[3, 3] == 0)
    loaded = envmap.load_equirect(tmp_path / "m.hdr")
    np.testing.assert_array_equal(loaded.pixels, back)


def test_radiance_hdr_bad_files(tmp_path):
    p = tmp_path / "bad.hdr"
    p.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 2 +X 4\n")
    with pytest.raises(ValueError, match="unsupported Radiance format"):
        envmap.read_radiance_hdr(p)
    p.write_bytes(b"#?RADIANCE\n\n+Y 2 +X 4\n" + bytes(32))
    with pytest.raises(ValueError, match="orientation"):
        envmap.read_radiance_hdr(p)
    p.write_bytes(b"#?RADIANCE\n\n-Y 2 +X 4\n" + bytes(20))
    with pytest.raises(ValueError, match="truncated"):
        envmap.read_radiance_hdr(p)
    p.write_bytes(b"#?RADIANCE\n\n-Y 1 +X 8\n" + bytes([2, 2, 0, 8, 0]))  # zero-length literal
    with pytest.raises(ValueError, match="truncated or corrupt"):
        envmap.read_radiance_hdr(p)


def test_load_exr_map_and_clamp_negatives(tmp_path):
    img = RNG.random((16, 32, 3)).astype(np.float32)
    img[0, 0, 0] = -0.5
    img[5, 7, 2] = -1e-3
    exr.write_exr(tmp_path / "m.exr", {"R": img[..., 0], "G": img[..., 1], "B": img[..., 2], "A": np.ones((16, 32))})
    loaded = envmap.load_equirect(tmp_path / "m.exr")
    assert loaded.negatives_clamped == 2 and loaded.shape == (16, 32)
    assert loaded.pixels.min() == 0.0
    np.testing.assert_array_equal(loaded.pixels, np.maximum(img, 0))
    assert not loaded.pixels.flags.writeable


def test_load_blender_style_multipart_exr(tmp_path):
    import OpenEXR

    img = RNG.random((8, 16, 3)).astype(np.float32)
    # OpenEXR's Part ignores numpy strides: hand it contiguous planes
    r, g, b = (np.ascontiguousarray(img[..., c]) for c in range(3))
    parts = [
        OpenEXR.Part({}, {"R": r, "G": g, "B": b}, "ViewLayer.Combined"),
        OpenEXR.Part({}, {"R": img[..., 0] * 0, "G": img[..., 0] * 0, "B": img[..., 0] * 0}, "ViewLayer.Normal"),
    ]
    OpenEXR.File(parts).write(str(tmp_path / "mp.exr"))
    np.testing.assert_array_equal(envmap.load_equirect(tmp_path / "mp.exr").pixels, img)


@pytest.mark.parametrize(
    "pixels, match",
    [
        (np.ones((8, 16)), "rank 2"),
        (np.ones((8, 16, 2)), "3 or 4 channels"),
        (np.ones((8, 8, 3)), "2:1"),
        (np.ones((8, 17, 3)), "2:1"),
        (np.where(np.arange(3) == 1, np.nan, 1.0) * np.ones((8, 16, 3)), "8 NaN or Inf"),
        (np.full((8, 16, 3), np.inf), "NaN or Inf"),
        (np.full((8, 16, 3), "x"), "numeric"),
        (np.full((8, 16, 3), 1e39), "beyond float32 range"),
    ],
)
def test_validate_bad_maps(pixels, match):
    with pytest.raises(ValueError, match=match):
        envmap.validate_equirect(pixels, source="test")


def test_load_bad_files(tmp_path):
    with pytest.raises(ValueError, match="not found"):
        envmap.load_equirect(tmp_path / "none.exr")
    (tmp_path / "x.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(20))
    with pytest.raises(ValueError, match="not an OpenEXR or Radiance"):
        envmap.load_equirect(tmp_path / "x.png")
    exr.write_exr(tmp_path / "z.exr", {"Z": np.ones((4, 8))})
    with pytest.raises(ValueError, match="no R, G, B"):
        envmap.load_equirect(tmp_path / "z.exr")
    exr.write_exr(tmp_path / "sq.exr", {c: np.ones((8, 8)) for c in "RGB"})
    with pytest.raises(ValueError, match="2:1"):
        envmap.load_equirect(tmp_path / "sq.exr")


def test_light_sources_agree(tmp_path):
    path = presets.preset_path("venice")
    by_name = light.sh_light("venice", 4, normalize=False)
    by_path = light.sh_light(str(path), 4, normalize=False)
    by_env = light.sh_light(envmap.load_equirect(path), 4, normalize=False)
    by_pixels = light.sh_light(envmap.load_equirect(path).pixels, 4, normalize=False)
    np.testing.assert_array_equal(by_name, by_path)
    np.testing.assert_array_equal(by_name, by_env)
    np.testing.assert_array_equal(by_name, by_pixels)
    np.testing.assert_array_equal(by_name, sh_projection.project_equirect(envmap.load_equirect(path).pixels, 4))
    rotated = light.sh_light("venice", 4, rotation_deg=45.0, target=0.7)
    expected, _ = sh.normalize_reference(sh_rotation.rotate(by_name, sh_rotation.z_rotation(45.0)), 0.7)
    np.testing.assert_array_equal(rotated, expected)  # the recipe: project, rotate about Z, normalize
    with pytest.raises(ValueError, match="neither a file nor a preset"):
        light.sh_light("no-such-light", 4)


# ---------------------------------------------------------------- presets


def test_bundled_presets():
    names = presets.list_presets()
    assert len(names) == 18 and "venice" in names and "apartment" in names
    assert presets.HELD_OUT <= set(names)
    assert not set(presets.training_presets()) & presets.HELD_OUT
    assert len(presets.training_presets()) == 14
    for name in names:
        env = envmap.load_equirect(presets.preset_path(name))
        assert env.shape == (256, 512)
        # real light: positive mean, and DWAB ringing only touches a few texels
        assert sh.mean_luminance(sh_projection.project_equirect(env.pixels, 0)) > 0.01
        assert env.negatives_clamped < 0.02 * env.pixels.size
    assert (presets.HDRI_DIR / "LICENSE.md").read_text().count("CC0-1.0") >= 1


def test_blender_presets():
    import importlib.util

    names = presets.list_blender_presets()
    if importlib.util.find_spec("bpy") is None:  # the core also runs without Blender
        assert names == []
        with pytest.raises(ValueError, match="needs Blender"):
            presets.preset_path("blender:city")
        return
    assert names == [f"blender:{n}" for n in
                     ("city", "courtyard", "forest", "interior", "night", "studio", "sunrise", "sunset")]
    env = envmap.load_equirect(presets.preset_path("blender:courtyard"))
    assert env.shape == (512, 1024)
    with pytest.raises(ValueError, match="unknown Blender preset"):
        presets.preset_path("blender:mars")


@pytest.mark.parametrize("name", ["mars", "", "../hdri/venice", None])
def test_unknown_preset(name):
    with pytest.raises(ValueError, match="preset"):
        presets.preset_path(name)
    # the light's "file or preset?" lookup: no preset is None (map_file then says neither), not an error
    assert presets.preset_file(name) is None


def test_preset_file_is_the_presets_file_by_its_exact_name():
    for name in presets.list_presets():
        assert presets.preset_file(name) == presets.preset_path(name)
    assert presets.preset_file("Venice") is None and presets.preset_file("venice.exr") is None
    assert light.map_file("venice") == presets.preset_path("venice")
    with pytest.raises(ValueError, match="neither a file nor a preset name"):
        light.map_file("Venice")


def test_core_imports_neither_bpy_nor_torch():
    code = (
        "import sys, relight, relight.lighting.sh, relight.network.prt, relight.imaging.colour, relight.files.exr, relight.lighting.envmap, "
        "relight.files.dataset, relight.lighting.presets, relight.cli; relight.lighting.presets.list_presets(); "
        "relight.cli.build_parser(); "
        "bad = [m for m in ('bpy', 'torch') if m in sys.modules]; assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


def load_decoder():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[3] / "tools" / "decode_pmndrs_hdri.py"
    spec = importlib.util.spec_from_file_location("decode_pmndrs_hdri", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_pmndrs_decoder_round_trip(tmp_path):
    import base64
    import io
    import tarfile

    decoder = load_decoder()
    img = RNG.random((4, 8, 3)).astype(np.float32)
    exr.write_exr(tmp_path / "tiny.exr", {c: img[..., i] for i, c in enumerate("RGB")}, half=True)
    raw = (tmp_path / "tiny.exr").read_bytes()
    module = f"export default 'data:application/exr;base64,{base64.b64encode(raw).decode()}'\n"
    assert decoder.decode_module(module) == raw
    with pytest.raises(ValueError, match="not an `export default"):
        decoder.decode_module("export default 'data:image/png;base64,AAAA'")
    not_exr = base64.b64encode(b"hello").decode()
    with pytest.raises(ValueError, match="not an OpenEXR"):
        decoder.decode_module(f"export default 'data:application/exr;base64,{not_exr}'")
    # a tarball laid out like the npm package
    tarball = tmp_path / "pkg.tgz"
    with tarfile.open(tarball, "w:gz") as tar:
        for name, text in (("package/hdri/tiny.exr.js", module), ("package/README.md", "x")):
            data = text.encode()
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    out = tmp_path / "out"
    assert decoder.main([str(tarball), "--out", str(out)]) == 0
    assert (out / "tiny.exr").read_bytes() == raw
    assert decoder.main([str(tmp_path / "missing.tgz"), "--out", str(out)]) == 2
