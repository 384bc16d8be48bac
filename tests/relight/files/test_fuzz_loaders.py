"""Fuzzing the photo, mask, EXR and Radiance .hdr loaders (Hypothesis; profile in fuzz_support).

Property: whatever the bytes, a loader returns a valid result (finite, the
right shape and dtype) or raises ValueError with a one-line message; never
another exception, NaN, or an allocation sized by a forged header (the
declared size is weighed first; `make fuzz` runs under a 4 GB address-space
limit, where such an allocation would be a MemoryError and fail the run).
"""

from __future__ import annotations

import io
import struct
import warnings
from collections import Counter

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from PIL import Image

from fuzz_support import (CASES, OUTCOMES, accepted_share, exr_bytes, fuzz_settings, new_case, png_bytes, radiance_hdr,
                          record, run_case)
from relight.lighting import envmap
from relight.files import exr, photo


def _pillow_bytes(fmt: str, mode: str, **kw) -> bytes:
    rng = np.random.default_rng(len(fmt) + len(mode))
    channels = {"RGB": 3, "RGBA": 4, "L": 1, "LA": 2, "P": 1, "I;16": 1}[mode]
    if mode == "I;16":
        im = Image.fromarray(rng.integers(0, 65536, (9, 13), dtype=np.uint16))
    else:
        pixels = rng.integers(0, 256, (9, 13, channels), dtype=np.uint8)
        im = Image.fromarray(pixels[..., 0] if channels == 1 else pixels, "L" if mode == "P" else mode)
        if mode == "P":
            im = im.convert("P")
    buf = io.BytesIO()
    im.save(buf, format=fmt, **kw)
    return buf.getvalue()


@pytest.fixture(scope="module")
def seeds(tmp_path_factory) -> dict[str, bytes]:
    """One small valid file of every kind the photo loader takes: the fuzzers mutate these."""
    tmp = tmp_path_factory.mktemp("seeds")
    rng = np.random.default_rng(0)
    planes = {c: rng.uniform(0, 1, (9, 13)).astype(np.float32) for c in "RGBA"}
    return {
        "png-rgb": _pillow_bytes("PNG", "RGB"),
        "png-rgba": _pillow_bytes("PNG", "RGBA"),
        "png-palette": _pillow_bytes("PNG", "P", transparency=0),
        "png-grey16": _pillow_bytes("PNG", "I;16"),
        "png-rgb16": png_bytes(9, 13, bit_depth=16, colour=2),
        "png-rgba16": png_bytes(9, 13, bit_depth=16, colour=6),
        "jpeg": _pillow_bytes("JPEG", "RGB"),
        "jpeg-progressive": _pillow_bytes("JPEG", "RGB", progressive=True),
        "tiff": _pillow_bytes("TIFF", "RGBA"),
        "webp": _pillow_bytes("WEBP", "RGB", lossless=True),
        "bmp": _pillow_bytes("BMP", "RGB"),
        "gif": _pillow_bytes("GIF", "P"),
        "exr-rgba": exr_bytes(tmp, planes),
        "exr-half-y": exr_bytes(tmp, {"Y": planes["R"], "A": planes["A"]}, compression="piz"),
        "exr-layers": exr_bytes(tmp, {f"View.Combined.{c}": planes[c] for c in "RGB"}, compression="rle"),
    }


@st.composite
def mutated(draw, seeds: dict[str, bytes]) -> bytes:
    """A seed file changed the way damaged or hostile files are: bytes overwritten
    (mostly in the header), cut short, extended, or its declared size forged."""
    data = bytearray(seeds[draw(st.sampled_from(sorted(seeds)))])
    kind = draw(st.sampled_from(["edit", "truncate", "append", "forge", "none"]))
    if kind == "edit":
        for pos, value in draw(st.lists(st.tuples(st.integers(0, 2**16), st.integers(0, 255)), min_size=1, max_size=8)):
            data[pos % (len(data) if draw(st.booleans()) else min(len(data), 400))] = value
    elif kind == "truncate":
        data = data[: draw(st.integers(0, len(data)))]
    elif kind == "append":
        data += draw(st.binary(max_size=256))
    elif kind == "forge":
        data = bytearray(_forge_size(bytes(data), draw(st.integers(0, 2**31 - 1)), draw(st.integers(0, 2**31 - 1))))
    return bytes(data)


def _forge_size(data: bytes, height: int, width: int) -> bytes:
    """Patch the declared size into a PNG IHDR (CRC fixed), a JPEG SOF or an EXR dataWindow."""
    import zlib

    out = bytearray(data)
    if out.startswith(b"\x89PNG") and len(out) >= 33:
        struct.pack_into(">II", out, 16, width, height)
        struct.pack_into(">I", out, 29, zlib.crc32(bytes(out[12:29])))
    elif out.startswith(b"\xff\xd8"):
        for marker in (b"\xff\xc0", b"\xff\xc2"):
            at = out.find(marker)
            if at > 0 and at + 9 <= len(out):
                struct.pack_into(">HH", out, at + 5, height % 65536, width % 65536)
    elif out.startswith(b"\x76\x2f\x31\x01"):
        at = out.find(b"dataWindow\x00box2i\x00")
        if at > 0 and at + 39 <= len(out):
            struct.pack_into("<iiii", out, at + 23, 0, 0, width - 1, height - 1)
    return bytes(out)


def _check_image(img: np.ndarray, mask) -> None:
    assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.float32 and img.size > 0
    assert np.all(np.isfinite(img)) and img.min() >= 0
    if mask is not None:
        assert mask.shape == img.shape[:2] and mask.dtype == np.float32
        assert np.all(np.isfinite(mask)) and mask.min() >= 0 and mask.max() <= 1


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz-loaders")


def _drawn_file(path, data: bytes, test: str):
    """Write one generated case's bytes and count the case."""
    path.write_bytes(data)
    new_case(test)
    return path


def test_fuzz_photo_loader(seeds, folder):
    @given(st.data())
    @fuzz_settings()
    def case(data):
        path = _drawn_file(folder / "photo.bin", data.draw(mutated(seeds)), "test_fuzz_photo_loader")
        result = run_case("photo", lambda: photo.read_photo(path))
        if result is not None:
            _check_image(*result)

    with accepted_share("photo", 0.1):  # q = 1/5: mutated's "none" leaves a valid seed as it is
        case()


def test_fuzz_mask_loader(seeds, folder):
    @given(st.data(), st.tuples(st.integers(1, 16), st.integers(1, 16)))
    @fuzz_settings()
    def case(data, shape):
        path = folder / "mask.bin"
        raw = data.draw(mutated(seeds))
        path.write_bytes(raw)
        if data.draw(st.booleans()):  # the shape of the file itself, when it has one: the mask is then read
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    with Image.open(io.BytesIO(raw)) as im:
                        shape = im.size[::-1]
                except Exception:
                    pass
        new_case("test_fuzz_mask_loader")
        mask = run_case("mask", lambda: photo.read_mask(path, shape))
        if mask is not None:
            assert mask.shape == tuple(shape) and mask.dtype == np.float32
            assert np.all(np.isfinite(mask)) and mask.min() >= 0 and mask.max() <= 1 and np.any(mask > 0)

    with accepted_share("mask", 0.05):  # q = 1/5 * 1/2: a seed left as it is, read at its own size
        case()


_SPECIAL = [0.0, -1.0, 1e-45, 65504.0, 3e38, -3e38, np.inf, -np.inf, np.nan]


@st.composite
def exr_file(draw, folder) -> bytes:
    """A generated EXR (random size, channel names, values including Inf/NaN/huge, compression), maybe damaged."""
    h = draw(st.integers(1, 12))
    w = draw(st.sampled_from([2 * h, draw(st.integers(1, 24))]))  # 2:1 often, so maps load too
    names = draw(st.sampled_from([("R", "G", "B"), ("R", "G", "B", "A"), ("Y",), ("Y", "A"), ("X",),
                                  ("L.Combined.R", "L.Combined.G", "L.Combined.B"), ("a.R", "a.G", "a.B", "b.R")]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    planes = {}
    for name in names:
        plane = rng.uniform(-0.1, draw(st.sampled_from([1.0, 100.0, 3e38])), (h, w)).astype(np.float32)
        for _ in range(draw(st.integers(0, 2))):
            plane[rng.integers(h), rng.integers(w)] = draw(st.sampled_from(_SPECIAL))
        planes[name] = plane
    data = exr_bytes(folder, planes, compression=draw(st.sampled_from(["zip", "none", "piz", "rle"])))
    return draw(mutated({"exr": data})) if draw(st.booleans()) else data


def test_fuzz_exr_loaders(folder):
    @given(st.data())
    @fuzz_settings()
    def case(data):
        path = _drawn_file(folder / "gen.exr", data.draw(exr_file(folder)), "test_fuzz_exr_loaders")
        channels = run_case("exr.read_exr", lambda: exr.read_exr(path))
        if channels is not None:
            assert channels and all(a.ndim == 2 and a.dtype in (np.float32, np.uint32) for a in channels.values())
        env = run_case("exr.load_equirect", lambda: envmap.load_equirect(path))
        if env is not None:
            h, w = env.shape
            assert w == 2 * h and env.pixels.dtype == np.float32 and np.all(np.isfinite(env.pixels))
            assert env.pixels.min() >= 0
        result = run_case("exr.read_photo", lambda: photo.read_photo(path))
        if result is not None:
            _check_image(*result)

    # read_exr: q = 1/2, the generated file left undamaged (any values are a valid EXR);
    # a map or a photo may hold NaN, Inf or no RGB by design: no branch is valid by construction
    with accepted_share("exr.read_exr", 0.25), accepted_share("exr.load_equirect", 0.0), \
            accepted_share("exr.read_photo", 0.0):
        case()


@st.composite
def hdr_file(draw) -> bytes:
    """A generated Radiance file: random size, flat or RLE scanlines, any exponent,
    a resolution line that may lie (up to 10^12), then maybe damaged."""
    h = draw(st.integers(1, 8))
    w = draw(st.sampled_from([2 * h, draw(st.integers(1, 40))]))
    rle = draw(st.booleans()) and 8 <= w < 32768
    declared = None
    if draw(st.booleans()):
        number = st.one_of(st.integers(0, 10**12).map(str), st.sampled_from(["", "-1", "1e9", "99999999999999999999"]))
        declared = (draw(number), draw(number))
    exponent = draw(st.one_of(st.none(), st.sampled_from([0, 1, 128, 200, 254, 255])))
    data = radiance_hdr(h, w, declared=declared, exponent=exponent, rle=rle, seed=draw(st.integers(0, 2**32 - 1)))
    return draw(mutated({"hdr": data})) if draw(st.booleans()) else data


def test_fuzz_hdr_loader(folder):
    @given(hdr_file())
    @fuzz_settings()
    def case(data):
        path = _drawn_file(folder / "gen.hdr", data, "test_fuzz_hdr_loader")
        img = run_case("hdr.read_radiance_hdr", lambda: envmap.read_radiance_hdr(path))
        if img is not None:
            assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.float32
            assert np.all(np.isfinite(img)) and img.min() >= 0
        env = run_case("hdr.load_equirect", lambda: envmap.load_equirect(path))
        if env is not None:
            assert env.shape[1] == 2 * env.shape[0] and np.all(np.isfinite(env.pixels))

    # q = 1/2 * 1/2: undamaged with an honest resolution line (every exponent decodes finite);
    # a map also needs width 2 x height, drawn half the time: q = 1/8
    with accepted_share("hdr.read_radiance_hdr", 0.125), accepted_share("hdr.load_equirect", 0.0625):
        case()


def test_the_floor_fails_a_loader_that_refuses_everything(seeds, folder, monkeypatch):
    """Each case allows a one-line refusal, so only the floor catches a loader that refuses all."""
    def refuse(path):
        raise ValueError("refused")

    monkeypatch.setattr(photo, "read_photo", refuse)
    counted = Counter(OUTCOMES["photo"]), Counter(CASES)
    try:
        with pytest.raises(AssertionError, match=r"photo: 0 of \d+ calls accepted"):
            test_fuzz_photo_loader(seeds, folder)
    finally:  # `make fuzz` counts the real loader only
        OUTCOMES["photo"] = counted[0]
        CASES.clear()
        CASES.update(counted[1])
    with pytest.raises(AssertionError, match="1 of 5 calls accepted, below the floor of 25.0%"):
        with accepted_share("floor-check", 0.25):
            for outcome in ("ok", "ValueError", "ValueError", "ValueError", "ValueError"):
                record("floor-check", outcome)
    with accepted_share("floor-check", 0.2):  # 1 of 5 meets a 20% floor
        for outcome in ("ok", "ValueError", "ValueError", "ValueError", "ValueError"):
            record("floor-check", outcome)
    del OUTCOMES["floor-check"]
