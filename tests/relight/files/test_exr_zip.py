"""relight.files.exr_zip: ZIP EXRs written by us, read back by the OpenEXR library bit for bit."""

from __future__ import annotations

import io
import subprocess
import sys

import numpy as np
import OpenEXR
import pytest

from relight.files import exr_zip
from relight.files.exr import read_exr
from relight.files.exr_layout import read_layout


def _written(tmp_path, names, img, heights=None, **kwargs):
    h = img.shape[0]
    heights = heights or [h]
    bands, y = [], 0
    for rows in heights:
        bands.append(img[y:y + rows])
        y += rows
    path = tmp_path / "z.exr"
    with open(path, "wb") as f:
        exr_zip.write_zip_exr(f, names, h, img.shape[1], iter(bands), **kwargs)
    return path


def _values(h, w, c, seed=0):
    rng = np.random.default_rng(seed)
    img = rng.uniform(-5, 5, (h, w, c)).astype(np.float32)
    img[: h // 2] = np.round(img[: h // 2], 1)  # half the rows compress well, half hardly at all
    img.flat[::97] = np.float32(3.4e38)
    img.flat[5::101] = np.inf
    img.flat[7::103] = np.nan
    return img


@pytest.mark.parametrize("h, w, heights", [
    (1, 1, None), (16, 3, None), (17, 5, [1, 16]), (65, 33, [7, 9, 16, 33]), (300, 41, [64, 64, 64, 64, 44]),
])
def test_the_library_reads_back_every_bit(tmp_path, h, w, heights):
    names = ["R", "G", "B", "A"]  # stored in the order A, B, G, R
    img = _values(h, w, 4)
    path = _written(tmp_path, names, img, heights, threads=2)
    back = read_exr(path)  # the OpenEXR library reads the pixels
    for c, name in enumerate(names):
        assert back[name].dtype == np.float32
        np.testing.assert_array_equal(back[name].view(np.uint32), img[..., c].view(np.uint32))  # NaN bits too
    part, = read_layout(path)
    assert part.compression == 3 and part.window == (0, 0, w - 1, h - 1)


def test_half_names_attributes_and_the_library_says_nothing(tmp_path):
    names = ["Relight.Relit.R", "Relight.Albedo.R", "a_channel_name_longer_than_thirty_one_bytes"]
    img = _values(40, 9, 3, seed=2)
    attributes = {"relight": '{"light": "sunset", "note": "é ✓"}', "owner": "x"}
    path = _written(tmp_path, names, img, half=True, attributes=attributes)
    handle = OpenEXR.File(str(path), separate_channels=True)
    header = handle.header()
    assert header["relight"] == attributes["relight"] and header["owner"] == "x"
    assert header["compression"] == OpenEXR.ZIP_COMPRESSION
    for c, name in enumerate(names):
        pixels = handle.channels()[name].pixels
        assert pixels.dtype == np.float16
        with np.errstate(over="ignore"):
            expected = img[..., c].astype(np.float16)
        np.testing.assert_array_equal(pixels.view(np.uint16), expected.view(np.uint16))
    child = subprocess.run([sys.executable, "-c", f"import OpenEXR; OpenEXR.File({str(path)!r}, separate_channels=True)"],
                           capture_output=True, text=True, timeout=120)
    assert (child.returncode, child.stdout, child.stderr) == (0, "", "")


def test_a_chunk_deflate_cannot_shrink_is_stored_raw(tmp_path):
    rng = np.random.default_rng(3)
    img = rng.integers(0, 2**32, (32, 64, 1), dtype=np.uint32).view(np.float32)  # random bits
    path = _written(tmp_path, ["Z"], img)
    data = path.read_bytes()
    raw = 16 * 64 * 4
    assert data.count(np.int32(raw).tobytes()) >= 2  # both chunks' leaders say: raw size
    np.testing.assert_array_equal(read_exr(path)["Z"].view(np.uint32), img[..., 0].view(np.uint32))


def test_too_few_rows_is_an_error():
    with pytest.raises(ValueError, match="hold 16 of its 40 rows"):
        exr_zip.write_zip_exr(io.BytesIO(), ["R"], 40, 3, iter([np.zeros((16, 3, 1), np.float32)]))
