"""Photo I/O: PNG/JPEG/EXR reading (orientation, bit depths, alpha), writing, size guards."""

from __future__ import annotations

import struct
import subprocess
import sys
import zlib

import numpy as np
import pytest
from PIL import Image

from relight.files import photo as ph
from relight.imaging.colour import srgb_decode, srgb_encode
from relight.files.exr import read_exr, write_exr


def _encode_png16(values: np.ndarray, filters: list[int]) -> bytes:
    """A 16-bit RGB(A) PNG with the given row filter types (reference implementation, per byte)."""
    h, w, c = values.shape
    raw = values.astype(">u2").tobytes()
    stride, bpp = w * c * 2, c * 2
    rows = [raw[i * stride:(i + 1) * stride] for i in range(h)]
    out = bytearray()
    prev = bytes(stride)
    for r, line in enumerate(rows):
        kind = filters[r % len(filters)]
        enc = bytearray([kind])
        for x in range(stride):
            a = line[x - bpp] if x >= bpp else 0
            b = prev[x]
            cc = prev[x - bpp] if x >= bpp else 0
            if kind == 0:
                pred = 0
            elif kind == 1:
                pred = a
            elif kind == 2:
                pred = b
            elif kind == 3:
                pred = (a + b) // 2
            else:
                p = a + b - cc
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - cc)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else cc)
            enc.append((line[x] - pred) & 255)
        out += enc
        prev = line

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", w, h, 16, 2 if c == 3 else 6, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(bytes(out)))
            + chunk(b"IEND", b""))


def _rgb8(h=6, w=5, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def test_8bit_png_decodes_through_the_srgb_curve(tmp_path):
    u8 = _rgb8()
    Image.fromarray(u8).save(tmp_path / "a.png")
    img, mask = ph.read_photo(tmp_path / "a.png")
    assert img.dtype == np.float32 and img.shape == (6, 5, 3) and mask is None
    np.testing.assert_allclose(img, srgb_decode(u8 / 255.0), rtol=1e-6, atol=1e-9)


def test_png_round_trip_is_within_half_a_code_value(tmp_path):
    lin = np.random.default_rng(1).uniform(0, 1, (7, 9, 3)).astype(np.float32)
    ph.write_png(tmp_path / "o.png", lin)
    back = np.asarray(Image.open(tmp_path / "o.png"))
    # the writer rounds the encoded value to the nearest of 255 steps
    assert np.max(np.abs(back / 255.0 - srgb_encode(lin))) <= 0.5 / 255 + 1e-6
    assert not list(tmp_path.glob(".*tmp*"))


@pytest.mark.parametrize("channels", [3, 4])
def test_16bit_colour_png_keeps_all_16_bits_with_every_row_filter(tmp_path, channels):
    rng = np.random.default_rng(channels)
    values = rng.integers(0, 65536, (7, 6, channels), dtype=np.uint16)
    values[3] = values[2] // 2  # some structure for the Up/Average/Paeth predictors
    path = tmp_path / "deep.png"
    path.write_bytes(_encode_png16(values, [0, 1, 2, 3, 4]))
    img, mask = ph.read_photo(path)
    np.testing.assert_allclose(img, srgb_decode(values[..., :3] / 65535.0), rtol=1e-6, atol=1e-9)
    if channels == 4:
        np.testing.assert_allclose(mask, values[..., 3] / 65535.0, rtol=1e-7)
    else:
        assert mask is None
    # only Sub/Up rows take the row-by-row path
    path.write_bytes(_encode_png16(values, [1, 2, 0]))
    np.testing.assert_array_equal(ph.read_photo(path)[0], img)
    # wider than tall and taller than wide: the anti-diagonal sweep covers every cell
    for shape in ((9, 23), (23, 9)):
        big = rng.integers(0, 65536, shape + (channels,), dtype=np.uint16)
        path.write_bytes(_encode_png16(big, [4, 3, 1, 4, 2, 0]))
        np.testing.assert_allclose(ph.read_photo(path)[0], srgb_decode(big[..., :3] / 65535.0),
                                   rtol=1e-6, atol=1e-9)


def test_16bit_grey_png(tmp_path):
    grey = np.arange(0, 65536, 2731, dtype=np.uint16).reshape(4, 6)
    Image.fromarray(grey).save(tmp_path / "g.png")
    img, mask = ph.read_photo(tmp_path / "g.png")
    expect = srgb_decode(grey / 65535.0)
    for c in range(3):
        np.testing.assert_allclose(img[..., c], expect, rtol=1e-6, atol=1e-9)


def test_grey_and_alpha_variants(tmp_path):
    grey = np.arange(30, dtype=np.uint8).reshape(5, 6) * 8
    Image.fromarray(grey, "L").save(tmp_path / "l.png")
    img, mask = ph.read_photo(tmp_path / "l.png")
    assert mask is None and np.all(img[..., 0] == img[..., 2])
    la = np.stack([grey, 255 - grey], axis=-1)
    Image.fromarray(la, "LA").save(tmp_path / "la.png")
    img, mask = ph.read_photo(tmp_path / "la.png")
    np.testing.assert_allclose(mask, (255 - grey) / 255.0, rtol=1e-7)
    rgba = np.concatenate([_rgb8(5, 6), grey[..., None]], axis=-1)
    Image.fromarray(rgba, "RGBA").save(tmp_path / "rgba.png")
    img, mask = ph.read_photo(tmp_path / "rgba.png")
    np.testing.assert_allclose(mask, grey / 255.0, rtol=1e-7)
    np.testing.assert_allclose(img, srgb_decode(rgba[..., :3] / 255.0), rtol=1e-6, atol=1e-9)


def test_exif_orientation_is_applied(tmp_path):
    # 2 rows x 3 columns stored; EXIF 6 = "rotate 90 CW to view": viewed 3 x 2
    stored = np.zeros((20, 30, 3), np.uint8)
    stored[:10, :10] = (255, 0, 0)  # red block at stored top-left
    im = Image.fromarray(stored)
    exif = Image.Exif()
    exif[0x0112] = 6
    im.save(tmp_path / "o.jpg", quality=95, exif=exif.tobytes())
    img, _ = ph.read_photo(tmp_path / "o.jpg")
    assert img.shape == (30, 20, 3)
    # after a 90 degree clockwise turn the stored top-left is the viewed top-right
    assert img[2, 17, 0] > 0.8 and img[2, 17, 1] < 0.1
    assert img[2, 2, 0] < 0.1


def test_exr_photos_are_linear_and_keep_alpha(tmp_path):
    rng = np.random.default_rng(3)
    rgb = rng.uniform(0, 4, (5, 7, 3)).astype(np.float32)
    a = rng.uniform(0, 1, (5, 7)).astype(np.float32)
    write_exr(tmp_path / "p.exr", {"R": rgb[..., 0], "G": rgb[..., 1], "B": rgb[..., 2], "A": a})
    img, mask = ph.read_photo(tmp_path / "p.exr")
    np.testing.assert_array_equal(img, rgb)
    np.testing.assert_array_equal(mask, a)
    write_exr(tmp_path / "y.exr", {"Y": rgb[..., 0]})
    img, mask = ph.read_photo(tmp_path / "y.exr")
    np.testing.assert_array_equal(img[..., 2], rgb[..., 0])
    write_exr(tmp_path / "c.exr", {f"ViewLayer.Combined.{c}": rgb[..., i] for i, c in enumerate("RGB")})
    np.testing.assert_array_equal(ph.read_photo(tmp_path / "c.exr")[0], rgb)
    ph.write_exr_image(tmp_path / "w.exr", rgb)
    np.testing.assert_array_equal(ph.read_photo(tmp_path / "w.exr")[0], rgb)


def test_multilayer_exr_channels(tmp_path):
    rng = np.random.default_rng(4)
    h, w = 4, 5
    lay = {k: rng.uniform(0, 1, (h, w, 3)).astype(np.float32) for k in ("albedo", "shading", "residual")}
    lay["alpha"] = rng.uniform(0, 1, (h, w)).astype(np.float32)
    relit = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    ph.write_layers_exr(tmp_path / "l.exr", relit, lay)
    ch = read_exr(tmp_path / "l.exr")
    expect = {f"Relight.{p}.{c}" for p in ("Relit", "Albedo", "Shading", "Residual") for c in "RGB"}
    assert set(ch) == expect | {"Relight.Relit.A", "Relight.Alpha.A"}
    np.testing.assert_array_equal(ch["Relight.Shading.G"], lay["shading"][..., 1])
    np.testing.assert_array_equal(ch["Relight.Alpha.A"], lay["alpha"])
    np.testing.assert_array_equal(ch["Relight.Relit.B"], relit[..., 2])


BPY_SCRIPT = r"""
import sys, bpy
img = bpy.data.images.load(sys.argv[1])
tree = bpy.data.node_groups.new("check", "CompositorNodeTree")
node = tree.nodes.new("CompositorNodeImage")
node.image = img
print("PASSES", img.type, sorted((s.name, s.type) for s in node.outputs if s.enabled))
"""


def test_blender_reads_the_multilayer_exr_as_passes(tmp_path):
    lay = {k: np.full((4, 6, 3), 0.5, np.float32) for k in ("albedo", "shading", "residual")}
    lay["alpha"] = np.ones((4, 6), np.float32)
    path = ph.write_layers_exr(tmp_path / "l.exr", np.ones((4, 6, 3), np.float32), lay)
    script = tmp_path / "check.py"
    script.write_text(BPY_SCRIPT)
    res = subprocess.run([sys.executable, str(script), str(path)], capture_output=True, text=True,
                         timeout=120)
    line = [x for x in res.stdout.splitlines() if x.startswith("PASSES")]
    assert line, res.stderr[-2000:]
    assert line[0] == ("PASSES MULTILAYER [('Albedo', 'RGBA'), ('Alpha', 'VALUE'), ('Relit', 'RGBA'), "
                       "('Residual', 'RGBA'), ('Shading', 'RGBA')]")


def test_huge_header_is_refused_before_decoding(tmp_path):
    def png_header(w, h):
        def chunk(kind, body):
            return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
        # a valid header and one small compressed chunk: decoding would need gigabytes
        return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
                + chunk(b"IDAT", zlib.compress(bytes(4096))) + chunk(b"IEND", b""))
    for w, h in ((50_000, 10), (20_000, 20_000)):
        (tmp_path / "big.png").write_bytes(png_header(w, h))
        with pytest.raises(ValueError, match="too large"):
            ph.read_photo(tmp_path / "big.png")


@pytest.mark.parametrize("maker", ["jpeg", "png", "exr"])
def test_truncated_files_are_one_value_error(tmp_path, maker):
    path = tmp_path / f"t.{maker}"
    if maker == "exr":
        write_exr(path, {c: np.random.default_rng(0).uniform(0, 1, (64, 64)).astype(np.float32)
                         for c in "RGB"})
    else:
        Image.fromarray(_rgb8(64, 64)).save(path, format=maker.upper())
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(ValueError):
        ph.read_photo(path)


def test_other_bad_files(tmp_path):
    (tmp_path / "empty.png").write_bytes(b"")
    (tmp_path / "text.jpg").write_text("not an image at all")
    with pytest.raises(ValueError, match="empty"):
        ph.read_photo(tmp_path / "empty.png")
    with pytest.raises(ValueError, match="not a readable image"):
        ph.read_photo(tmp_path / "text.jpg")
    with pytest.raises(ValueError, match="not found"):
        ph.read_photo(tmp_path / "absent.png")
    with pytest.raises(ValueError, match="not a file"):
        ph.read_photo(tmp_path)
    nan = np.full((4, 4), np.nan, np.float32)
    write_exr(tmp_path / "nan.exr", {"R": nan, "G": nan, "B": nan})
    with pytest.raises(ValueError, match="NaN"):
        ph.read_photo(tmp_path / "nan.exr")


def test_masks(tmp_path):
    m = np.zeros((6, 8), np.uint8)
    m[2:4, 3:6] = 255
    Image.fromarray(m, "L").save(tmp_path / "m.png")
    mask = ph.read_mask(tmp_path / "m.png", (6, 8))
    np.testing.assert_array_equal(mask, m / 255.0)
    with pytest.raises(ValueError, match="mask is 8x6 but the photo is 9x6"):
        ph.read_mask(tmp_path / "m.png", (6, 9))
    Image.fromarray(np.zeros((6, 8), np.uint8), "L").save(tmp_path / "z.png")
    with pytest.raises(ValueError, match="empty"):
        ph.read_mask(tmp_path / "z.png", (6, 8))


def test_writes_are_atomic_and_checked(tmp_path):
    bad = np.full((4, 4, 3), np.nan, np.float32)
    with pytest.raises(ValueError, match="NaN"):
        ph.write_png(tmp_path / "x.png", bad)
    with pytest.raises(ValueError, match="folder does not exist"):
        ph.write_png(tmp_path / "no" / "x.png", np.zeros((4, 4, 3), np.float32))
    for write in (ph.write_image, ph.write_exr_image):  # the EXR writers say it in the same words
        with pytest.raises(ValueError, match="folder does not exist"):
            write(tmp_path / "no" / "x.exr", np.zeros((4, 4, 3), np.float32))
    with pytest.raises(ValueError, match=r"\.png or \.exr"):
        ph.write_image(tmp_path / "x.tif", np.zeros((4, 4, 3), np.float32))
    assert list(tmp_path.iterdir()) == []
    # an existing file is replaced whole, never half-written
    ph.write_png(tmp_path / "x.png", np.zeros((4, 4, 3), np.float32))
    with pytest.raises(ValueError):
        ph.write_png(tmp_path / "x.png", bad)
    assert np.all(np.asarray(Image.open(tmp_path / "x.png")) == 0)
    assert [p.name for p in tmp_path.iterdir()] == ["x.png"]


def _idat_stream(path) -> tuple[dict, bytes]:
    """(IHDR fields, the IDAT chunks' bytes joined) of a PNG, every chunk's CRC checked."""
    import struct
    import zlib

    data = (tmp := open(path, "rb")).read()
    tmp.close()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, kinds = 8, b"", []
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + n]
        assert struct.unpack(">I", data[pos + 8 + n:pos + 12 + n])[0] == zlib.crc32(kind + body), kind
        kinds.append(kind)
        if kind == b"IHDR":
            w, h, depth, colour = struct.unpack(">IIBB", body[:10])
            header = {"size": (w, h), "depth": depth, "colour": colour}
        idat += body if kind == b"IDAT" else b""
        pos += 12 + n
    assert kinds[0] == b"IHDR" and kinds[-1] == b"IEND"
    return header, idat


@pytest.mark.parametrize("engine", ["installed", "zlib"])
@pytest.mark.parametrize("shape", [(1, 1), (2, 7), (255, 3), (256, 5), (257, 4), (700, 33)])
def test_the_fast_png_writer_is_a_valid_png_of_the_rounded_codes(tmp_path, monkeypatch, engine, shape):
    """Issue 40: the PNG writer is relight.files.png_encoder's (table sRGB encode, Up filter, bands deflated
    on threads, ISA-L when installed): a strict zlib inflate (its Adler-32 checked) of the bands
    joined gives the Up-filtered rows of the codes, which Pillow decodes, metadata included."""
    import zlib

    from relight.files import png_encoder

    if engine == "zlib":
        monkeypatch.setattr(png_encoder, "deflate_module", lambda: (zlib, 1, zlib.Z_RLE))
    h, w = shape
    lin = np.random.default_rng(h * w).uniform(-0.1, 1.2, (h, w, 3)).astype(np.float32) ** 2
    lin[0, 0] = [-0.0, 1.0, 0.5]  # -0.0: its sign bit must not index past the encode table
    meta = {"relight": '{"quality": "balanced"}', "Comment": "caf\u00e9 \u2014 \u263a"}
    ph.write_png(tmp_path / "o.png", lin, meta)
    want = np.rint(srgb_encode(np.clip(lin, 0, 1)) * 255).astype(np.uint8)
    with Image.open(tmp_path / "o.png") as im:
        got = np.asarray(im)
        assert im.mode == "RGB" and im.info == meta
    # the table gives the curve's rounding except within float32 rounding of a threshold
    assert np.abs(got.astype(int) - want).max() <= 1 and np.mean(got != want) < 1e-3
    header, idat = _idat_stream(tmp_path / "o.png")
    assert header == {"size": (w, h), "depth": 8, "colour": 2}
    rows = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, 1 + 3 * w)
    assert np.all(rows[:, 0] == 2)  # "Up" on every row
    flat = got.reshape(h, 3 * w)
    np.testing.assert_array_equal(rows[:, 1:], np.concatenate([flat[:1], flat[1:] - flat[:-1]]))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.png"]


def test_a_nan_in_a_late_band_leaves_no_png(tmp_path):
    from relight.files import png_encoder

    lin = np.full((png_encoder.BAND_ROWS * 3, 4, 3), 0.5, np.float32)
    lin[-1, -1, 0] = np.nan
    with pytest.raises(ValueError, match="NaN or Inf"):
        ph.write_png(tmp_path / "o.png", lin)
    assert list(tmp_path.iterdir()) == []


def test_exr_output_is_lossless_zip_written_on_openexrs_threads(tmp_path):
    """Issue 40: OpenEXR's thread pool was empty (its blocks compressed on one thread). ZIP stays
    the compression: on relit float32 values PIZ took 1.4x its CPU for 1.2x its size
    (benchmarks/bench_write.py); both are lossless."""
    import OpenEXR

    lin = np.random.default_rng(3).uniform(0, 4, (300, 41, 3)).astype(np.float32)
    ph.write_exr_image(tmp_path / "o.exr", lin, alpha=np.full((300, 41), 0.5, np.float32))
    ph.write_layers_exr(tmp_path / "l.exr", lin, {"albedo": lin, "shading": lin, "residual": lin,
                                                  "alpha": np.ones((300, 41), np.float32)})
    for name in ("o.exr", "l.exr"):
        with OpenEXR.File(str(tmp_path / name)) as f:
            assert f.header()["compression"] == OpenEXR.ZIP_COMPRESSION
    assert OpenEXR.global_thread_count() >= 1
    back, alpha = ph.read_photo(tmp_path / "o.exr")
    np.testing.assert_allclose(back, lin, rtol=1e-7, atol=0)
    np.testing.assert_allclose(alpha, 0.5, rtol=1e-7)


def _with_exif_orientation(png: bytes, orientation: int) -> bytes:
    """The PNG with an eXIf chunk (big-endian TIFF, one IFD entry: Orientation) before IEND."""
    tiff = b"MM\x00*" + struct.pack(">I", 8) + struct.pack(">H", 1) \
        + struct.pack(">HHIHH", 0x0112, 3, 1, orientation, 0) + struct.pack(">I", 0)
    body = struct.pack(">I", len(tiff)) + b"eXIf" + tiff + struct.pack(">I", zlib.crc32(b"eXIf" + tiff))
    return png[:-12] + body + png[-12:]


@pytest.mark.parametrize("orientation", range(1, 9))
def test_a_16_bit_png_is_turned_upright_as_pillow_turns_an_8_bit_one(tmp_path, orientation):
    """read_png16 bypasses Pillow's pixels, so its orientation is the core's own table; it must
    match exif_transpose on the same pixels at 8 bits (the codes are multiples of 257, so the two
    decodes give the same linear values up to float32 rounding)."""
    codes8 = _rgb8(h=4, w=7, seed=orientation)
    stored16 = codes8.astype(np.uint16) * 257
    png16 = tmp_path / "sixteen.png"
    png16.write_bytes(_with_exif_orientation(_encode_png16(stored16, [0]), orientation))
    png8 = tmp_path / "eight.png"
    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.fromarray(codes8).save(png8, exif=exif)
    got16, _ = ph.read_photo(png16)
    got8, _ = ph.read_photo(png8)
    assert ph.exif_orientation(png16) == orientation
    assert got16.shape == got8.shape == ((7, 4, 3) if orientation >= 5 else (4, 7, 3))
    np.testing.assert_allclose(got16, got8, rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(ph.as_stored(ph.upright(stored16, orientation), orientation), stored16)


def test_layers_go_to_the_writer_in_bands(tmp_path):
    """write_layers_exr copies no whole layer: what it allocates at its peak is bounded by the rows
    the writer holds (exr_zip's tasks in flight and one band: held twice, as views and packed), not
    by the image (the four passes' channel copies it made before were 4 x 12 B per pixel)."""
    import tracemalloc

    from relight.files import exr_zip

    h, w = 4096, 256
    rng = np.random.default_rng(5)
    relit = rng.uniform(0, 2, (h, w, 3)).astype(np.float32)
    lay = {k: relit * s for k, s in (("albedo", 0.5), ("shading", 1.5), ("residual", 0.1))}
    lay["alpha"] = np.ones((h, w), np.float32)
    held_rows = (exr_zip.IN_FLIGHT * 4 + 1) * exr_zip.TASK_LINES + ph.EXR_BAND_ROWS  # 4 threads at most
    bound = 2 * held_rows * w * 14 * 4 + (1 << 20)  # 14 float32 channels; 1 MB for the file's own buffers
    whole_copies = 4 * h * w * 3 * 4
    assert bound < whole_copies / 2
    tracemalloc.start()
    try:
        ph.write_layers_exr(tmp_path / "l.exr", relit, lay)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < bound, (peak, bound)
    np.testing.assert_array_equal(read_exr(tmp_path / "l.exr")["Relight.Shading.B"], lay["shading"][..., 2])
