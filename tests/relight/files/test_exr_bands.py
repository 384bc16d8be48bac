"""relight.files.exr.write_exr_bands: a multi-layer EXR written from bands of rows."""

from __future__ import annotations

import weakref

import numpy as np
import pytest

from relight.files import exr_zip
from relight.files.exr import read_exr, write_exr, write_exr_bands

NAMES = ["Albedo.R", "Albedo.G", "Albedo.B", "Shading.R", "Shading.G", "Shading.B", "Alpha.A"]


def _image(h: int, w: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = rng.uniform(-2.0, 40.0, (h, w, len(NAMES))).astype(np.float32)
    img[0, 0, 0], img[-1, -1, 1] = np.inf, np.nan  # any float32 travels as it is
    return img


def _cut(img: np.ndarray, heights: list[int]):
    y = 0
    for rows in heights:
        yield img[y:y + rows]
        y += rows


@pytest.mark.parametrize("compression", ["zip", "piz", "none", "rle"])
@pytest.mark.parametrize("heights", [[1, 5, 16, 15], [37], [3] * 12 + [1], [17, 20]])
def test_bands_read_back_equal_to_the_whole_array_write(tmp_path, compression, heights):
    img = _image(37, 23)
    write_exr_bands(tmp_path / "bands.exr", NAMES, 37, 23, _cut(img, heights), compression=compression,
                    attributes={"relight": "Albedo and Shading, 37 rows"})
    write_exr(tmp_path / "whole.exr", {n: img[..., c] for c, n in enumerate(NAMES)}, compression=compression)
    bands, whole = read_exr(tmp_path / "bands.exr"), read_exr(tmp_path / "whole.exr")
    assert sorted(bands) == sorted(NAMES) == sorted(whole)
    for c, name in enumerate(NAMES):
        assert bands[name].dtype == np.float32
        np.testing.assert_array_equal(bands[name], whole[name])  # lossless codecs: bit for bit
        np.testing.assert_array_equal(bands[name], img[..., c])
    import OpenEXR

    assert OpenEXR.File(str(tmp_path / "bands.exr"), header_only=True).header()["relight"] == \
        "Albedo and Shading, 37 rows"


def test_half_bands_equal_float16_rounding(tmp_path):
    img = _image(9, 6, seed=3)
    write_exr_bands(tmp_path / "h.exr", NAMES, 9, 6, _cut(img.astype(np.float64), [4, 5]), half=True)
    back = read_exr(tmp_path / "h.exr")
    for c, name in enumerate(NAMES):
        np.testing.assert_array_equal(back[name], img[..., c].astype(np.float16).astype(np.float32))


@pytest.mark.parametrize("heights, match", [
    ([4, 4], "hold 8 of its 9 rows"),
    ([4, 6], "hold more than its 9 rows"),
])
def test_wrong_row_counts_leave_the_old_file(tmp_path, heights, match):
    out = tmp_path / "o.exr"
    out.write_bytes(b"previous")
    img = np.zeros((10, 5, len(NAMES)), np.float32)
    with pytest.raises(ValueError, match=match):
        write_exr_bands(out, NAMES, 9, 5, _cut(img, heights))
    assert out.read_bytes() == b"previous" and [p.name for p in tmp_path.iterdir()] == ["o.exr"]


@pytest.mark.parametrize("band, match", [
    (np.zeros((2, 4, len(NAMES)), np.float32), r"must be \[rows, 5, 7\], got \(2, 4, 7\)"),
    (np.zeros((2, 5, 3), np.float32), r"must be \[rows, 5, 7\]"),
    (np.zeros((2, 5), np.float32), r"must be \[rows, 5, 7\]"),
    (np.zeros((2, 5, len(NAMES)), np.uint8), "must hold floats"),
])
def test_a_wrong_band_is_refused_and_nothing_written(tmp_path, band, match):
    with pytest.raises(ValueError, match=match):
        write_exr_bands(tmp_path / "o.exr", NAMES, 4, 5, iter([np.zeros((2, 5, len(NAMES)), np.float32), band]))
    assert list(tmp_path.iterdir()) == []


class Cancelled(Exception):
    pass


def test_a_band_source_that_raises_cancels_the_write(tmp_path):
    out = tmp_path / "o.exr"
    out.write_bytes(b"previous")
    drawn = []

    def bands():
        for y in range(0, 30, 10):
            if y == 20:
                raise Cancelled  # e.g. the user pressed Esc
            drawn.append(y)
            yield np.ones((10, 8, len(NAMES)), np.float32)

    with pytest.raises(Cancelled):
        write_exr_bands(out, NAMES, 30, 8, bands())
    assert drawn == [0, 10]
    assert out.read_bytes() == b"previous" and [p.name for p in tmp_path.iterdir()] == ["o.exr"]


@pytest.mark.parametrize("writer", ["exr_zip", "library"])
def test_bands_are_let_go_once_written(tmp_path, monkeypatch, writer):
    """The writer holds a bounded number of rows, not the image: when a band is drawn, the bands
    written well before it are gone (the library's writer: all but the last one; exr_zip's: all
    but its tasks in flight, at most (IN_FLIGHT * 4 threads + 1) tasks of TASK_LINES rows)."""
    if writer == "library":
        monkeypatch.setattr(exr_zip, "available", lambda: False)
    rows, count = 16, 200
    held_rows = 1 * rows if writer == "library" else (exr_zip.IN_FLIGHT * 4 + 1) * exr_zip.TASK_LINES
    alive_when_drawn, refs = [], []

    def bands():
        for k in range(count):  # (arrays hold no cycles: a band let go is freed at once)
            alive_when_drawn.append(sum(r() is not None for r in refs))
            band = np.full((rows, 8, len(NAMES)), float(k), np.float32)
            refs.append(weakref.ref(band))
            yield band
            del band

    write_exr_bands(tmp_path / "o.exr", NAMES, rows * count, 8, bands())
    assert max(alive_when_drawn) <= held_rows // rows + 1 < count // 2, alive_when_drawn
    back = read_exr(tmp_path / "o.exr")["Shading.G"]
    np.testing.assert_array_equal(back[:, 0], np.repeat(np.arange(count, dtype=np.float32), rows))


@pytest.mark.parametrize("kwargs, match", [
    ({"names": ["R", "R"]}, "distinct non-empty strings"),
    ({"names": []}, "distinct non-empty strings"),
    ({"names": ["x" * 256]}, "at most 255 bytes"),
    ({"height": 0}, "positive integers"),
    ({"compression": "jpeg"}, "compression must be one of"),
    ({"attributes": {"channels": "x"}}, "attributes must map new names"),
    ({"attributes": {"note": 3}}, "attributes must map new names"),
    ({"attributes": {"n" * 256: "x"}}, "attributes must map new names"),
])
def test_bad_arguments_are_refused_before_any_file(tmp_path, kwargs, match):
    args = {"names": ["R"], "height": 2, "width": 2, "bands": iter([np.zeros((2, 2, 1), np.float32)])} | kwargs
    with pytest.raises(ValueError, match=match):
        write_exr_bands(tmp_path / "o.exr", **args)
    assert list(tmp_path.iterdir()) == []


def test_a_missing_folder_is_said_as_by_write_exr(tmp_path):
    with pytest.raises(FileNotFoundError, match="output folder does not exist"):
        write_exr_bands(tmp_path / "no" / "o.exr", ["R"], 1, 1, iter([np.zeros((1, 1, 1), np.float32)]))
