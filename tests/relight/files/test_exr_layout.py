"""relight.files.exr_layout: an EXR's framing checked before the library reads it.

Valid files of every framing the library writes pass and read back; each kind of
damaged framing is refused in one line naming the file, and is a file the library
itself would have printed about (checked in a child process, whose streams are
its own).
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys

import numpy as np
import OpenEXR
import pytest

from relight.files.exr import exr_size, read_exr, write_exr
from relight.files.exr_layout import read_layout

_RNG = np.random.default_rng(0)


def _plane(h, w, dtype=np.float32):
    return (_RNG.random((h, w)) * 10).astype(dtype)


def _tiles(w, h, mode=OpenEXR.ONE_LEVEL):
    description = OpenEXR.TileDescription()
    description.xSize, description.ySize, description.mode = w, h, mode
    return description


def _write(path, header, channels):
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))
    return path


VALID = {
    "zip float": lambda p: write_exr(p, {c: _plane(40, 30) for c in "RGB"}),
    "none half": lambda p: write_exr(p, {c: _plane(5, 3) for c in "YA"}, compression="none", half=True),
    "rle one pixel": lambda p: write_exr(p, {"Z": _plane(1, 1)}, compression="rle"),
    "piz uint": lambda p: _write(p, {"compression": OpenEXR.PIZ_COMPRESSION, "type": OpenEXR.scanlineimage},
                                 {"id": _plane(70, 9, np.uint32)}),
    "dwab offset window, decreasing y": lambda p: _write(
        p, {"compression": OpenEXR.DWAB_COMPRESSION, "type": OpenEXR.scanlineimage,
            "lineOrder": OpenEXR.DECREASING_Y,
            "dataWindow": (np.array([5, -9], np.int32), np.array([34, 300], np.int32))},
        {c: _plane(310, 30) for c in "RG"}),
    "tiled": lambda p: _write(p, {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.tiledimage,
                                  "tiles": _tiles(16, 8)}, {c: _plane(45, 70) for c in "RG"}),
    "two parts (Blender 5)": lambda p: OpenEXR.File([
        OpenEXR.Part({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                     {"R": _plane(20, 31)}, "ViewLayer.Combined"),
        OpenEXR.Part({"compression": OpenEXR.PIZ_COMPRESSION, "type": OpenEXR.tiledimage, "tiles": _tiles(8, 8)},
                     {"Z": _plane(20, 31)}, "ViewLayer.Depth")]).write(str(p)) or p,
}


@pytest.mark.parametrize("kind", sorted(VALID))
def test_valid_framings_pass_and_read(tmp_path, kind):
    path = tmp_path / "v.exr"
    VALID[kind](path)
    parts = read_layout(path)
    handle = OpenEXR.File(str(path), separate_channels=True)
    assert len(parts) == len(handle.parts)
    for ours, theirs in zip(parts, handle.parts):
        (x0, y0), (x1, y1) = theirs.header["dataWindow"]
        assert ours.window == (x0, y0, x1, y1)
        assert sorted(c[0] for c in ours.channels) == sorted(theirs.channels)
    assert exr_size(path) == tuple(max(p.size[i] for p in parts) for i in (0, 1))
    assert all(a.size for a in read_exr(path).values())


def _zip_file(tmp_path, name="z.exr", compression="zip"):
    """A 40-line scanline file (3 ZIP chunks of 16 lines) and where its offset table starts."""
    path = write_exr(tmp_path / name, {c: _plane(40, 30) for c in "RGB"}, compression=compression)
    data = bytearray(path.read_bytes())
    chunks = 3 if compression == "zip" else 40
    table = next(p for p in range(8, len(data) - 8) if struct.unpack_from("<Q", data, p)[0] == p + 8 * chunks)
    return path, data, table, chunks


def _damaged(tmp_path, kind):
    path, data, table, chunks = _zip_file(tmp_path, compression="none" if kind == "uncompressed size" else "zip")
    first = struct.unpack_from("<Q", data, table)[0]
    second = struct.unpack_from("<Q", data, table + 8)[0]
    if kind == "truncated in the data":
        data = data[: len(data) // 2]
    elif kind == "truncated in the header":
        data = data[:60]
    elif kind == "offset past the end and a chunk cut short":
        struct.pack_into("<Q", data, table + 8, len(data) + 1000)
        data = data[:-10]
    elif kind == "leader names other lines":
        struct.pack_into("<i", data, second, 3)  # the second chunk holds lines 16-31
    elif kind == "leader says too many bytes":
        struct.pack_into("<i", data, first + 4, 30 * 3 * 4 * 16 + 1)
    elif kind == "uncompressed size":
        struct.pack_into("<i", data, first + 4, struct.unpack_from("<i", data, first + 4)[0] - 4)
    elif kind == "not an EXR":
        data[0] ^= 0xFF
    bad = tmp_path / "bad.exr"
    bad.write_bytes(bytes(data))
    return bad


_LIBRARY_READ = """
import json, sys, OpenEXR
try:
    parts = len(OpenEXR.File(sys.argv[1], separate_channels=True).parts)
except Exception as exc:
    parts = -1
sys.stdout.flush()
sys.stderr.write("\\n" + json.dumps(parts) + "\\n")
"""


def _library_complains(path) -> bool:
    """Whether the library, reading `path` in a child process, prints anything or fails."""
    res = subprocess.run([sys.executable, "-c", _LIBRARY_READ, str(path)], capture_output=True, text=True,
                         timeout=120)
    said = (res.stdout + res.stderr).strip().splitlines()
    return len(said) > 1 or json.loads(said[-1]) < 1


@pytest.mark.parametrize("kind, match", [
    ("truncated in the data", "truncated"),
    ("truncated in the header", "truncated"),
    ("offset past the end and a chunk cut short", "part 0's chunk 2 runs past the end of the file"),
    ("leader names other lines", "part 0's chunk 1 names the wrong lines"),
    ("leader says too many bytes", "part 0's chunk 0 says 5761 bytes of data"),
    ("uncompressed size", "part 0's chunk 0 says 356 bytes of data"),
    ("not an EXR", "no EXR magic number"),
])
def test_damaged_framing_is_refused_in_one_line(tmp_path, capfd, kind, match):
    bad = _damaged(tmp_path, kind)
    capfd.readouterr()
    for call in (read_layout, read_exr):
        with pytest.raises(ValueError, match=match) as caught:
            call(bad)
        assert str(caught.value).startswith(f"cannot read EXR {bad}: ") and "\n" not in str(caught.value)
    assert capfd.readouterr() == ("", "")
    assert _library_complains(bad)  # refused only where the library would have printed or failed


def test_an_offset_table_entry_outside_the_file_is_rebuilt_as_the_library_does(tmp_path, capfd):
    """The library rebuilds such a table from the chunks' leaders and reads the file silently: so do we."""
    path, data, table, _ = _zip_file(tmp_path)
    struct.pack_into("<Q", data, table + 8, len(data) + 1000)
    (tmp_path / "rebuilt.exr").write_bytes(bytes(data))
    assert not _library_complains(tmp_path / "rebuilt.exr")
    capfd.readouterr()
    for name, plane in read_exr(path).items():
        np.testing.assert_array_equal(read_exr(tmp_path / "rebuilt.exr")[name], plane)
    assert capfd.readouterr() == ("", "")


def test_a_leader_naming_another_part_is_refused(tmp_path):
    path = tmp_path / "m.exr"
    VALID["two parts (Blender 5)"](path)
    data = bytearray(path.read_bytes())
    # the offset tables follow the headers: part 0's two chunks of 16 lines, then part 1's 12 tiles (4 x 3)
    table = next(p for p in range(8, len(data) - 8) if struct.unpack_from("<Q", data, p)[0] == p + 8 * 14)
    first_tile = struct.unpack_from("<Q", data, table + 16)[0]
    struct.pack_into("<i", data, first_tile, 0)  # the part number of part 1's first tile
    (tmp_path / "bad.exr").write_bytes(bytes(data))
    with pytest.raises(ValueError, match="part 1's chunk 0 names another part"):
        read_exr(tmp_path / "bad.exr")
    assert _library_complains(tmp_path / "bad.exr")


def test_a_tile_leader_naming_another_tile_is_refused(tmp_path):
    path = VALID["tiled"](tmp_path / "t.exr")
    data = bytearray(path.read_bytes())
    table = next(p for p in range(8, len(data) - 8) if struct.unpack_from("<Q", data, p)[0] == p + 8 * 30)
    struct.pack_into("<i", data, struct.unpack_from("<Q", data, table + 8 * 7)[0], 0)  # tile 7 is (2, 1)
    (tmp_path / "bad.exr").write_bytes(bytes(data))
    with pytest.raises(ValueError, match="part 0's chunk 7 names the wrong tile"):
        read_exr(tmp_path / "bad.exr")
    assert _library_complains(tmp_path / "bad.exr")


def test_deep_and_folders_are_refused_in_one_line(tmp_path):
    path, data, _, _ = _zip_file(tmp_path)
    data[5] |= 0x08  # the version field's "non-image" (deep) flag
    (tmp_path / "deep.exr").write_bytes(bytes(data))
    with pytest.raises(ValueError, match="deep data is not read"):
        exr_size(tmp_path / "deep.exr")
    (tmp_path / "folder.exr").mkdir()
    with pytest.raises(ValueError, match="it is a folder"):
        read_layout(tmp_path / "folder.exr")
