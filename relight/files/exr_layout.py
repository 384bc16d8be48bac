"""An EXR file's framing read by us before the OpenEXR library sees it: magic
number, part headers, offset tables and every chunk's leader (the file layout
of openexr.com's "OpenEXR File Layout").

The library reports a damaged file by printing on the process's stderr (its C
core) and stdout (its Python binding), streams shared with everything else in
the process (Blender's console, other add-ons). Checking here what the library
would complain about lets a damaged file be refused with one line of ours and
never reach it: a bad header, a size or an offset table that does not fit, a
chunk whose leader names the wrong part or lines, or that runs past the end
(a truncated file). Damage inside a chunk's compressed data is the library's
to find while decoding.
"""

from __future__ import annotations

import math
import mmap
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["ExrPart", "read_layout"]

_MAGIC = 20000630
_TILED, _LONG_NAMES, _DEEP, _MULTIPART = 0x200, 0x400, 0x800, 0x1000
# lines per chunk of each compression code (OpenEXRCore's exr_compression_lines_per_chunk)
_LINES_PER_CHUNK = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256, 10: 256, 11: 32}
_PIXEL_BYTES = {0: 4, 1: 2, 2: 4}  # uint, half, float
_FIXED_SIZES = {"box2i": 16, "box2f": 16, "v2i": 8, "v2f": 8, "v3i": 12, "v3f": 12, "int": 4, "float": 4,
                "double": 8, "compression": 1, "lineOrder": 1, "envmap": 1, "deepImageState": 1,
                "chromaticities": 32, "m33f": 36, "m44f": 64, "m33d": 72, "m44d": 128, "rational": 8,
                "timecode": 8, "keycode": 28, "tiledesc": 9}
_REQUIRED = {"channels": "chlist", "compression": "compression", "dataWindow": "box2i"}
# checked where present: the library reads a file without them (or with their type damaged) silently
_OPTIONAL = {"displayWindow": "box2i", "lineOrder": "lineOrder", "pixelAspectRatio": "float",
             "screenWindowWidth": "float"}
_LARGE = 2**30 - 1  # the core's bound on window coordinates (INT32_MAX / 2)


class _Damaged(Exception):
    """One reason a file is not a readable EXR (worded for the one-line error)."""


@dataclass(frozen=True)
class ExrPart:
    """One part's header fields that frame its pixels."""

    name: str
    storage: str  # "scanlineimage" or "tiledimage"
    window: tuple[int, int, int, int]  # data window: x0, y0, x1, y1 (inclusive)
    channels: tuple[tuple[str, int, int, int], ...]  # name, pixel type (0 uint, 1 half, 2 float), x, y sampling
    compression: int
    tiles: tuple[int, int, int, int] | None  # tile width, height, level mode, rounding mode
    line_order: int = 0  # 0 increasing y, 1 decreasing, 2 random

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the data window."""
        x0, y0, x1, y1 = self.window
        return x1 - x0 + 1, y1 - y0 + 1


def read_layout(path, *, chunks: bool = True) -> list[ExrPart]:
    """The parts of the EXR at `path`, its headers checked (and with `chunks`, its
    offset tables and every chunk's leader too). Raises FileNotFoundError for a
    missing file and ValueError "cannot read EXR <path>: <reason>" for a file the
    library would refuse (or print about) for its framing."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            size = f.seek(0, 2)
            if size < 8:
                raise _Damaged(f"only {size} bytes, not an EXR file")
            with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
                return _read(data, size, chunks)
    except _Damaged as exc:
        raise ValueError(f"cannot read EXR {path}: {exc}") from None
    except IsADirectoryError:
        raise ValueError(f"cannot read EXR {path}: it is a folder") from None


class _Reader:
    def __init__(self, data, size: int, long_names: bool):
        self.data, self.size, self.at, self.max_name = data, size, 8, 255 if long_names else 31

    def take(self, n: int, what: str) -> bytes:
        if n < 0 or self.at + n > self.size:
            raise _Damaged(f"the file ends inside {what} (truncated?)")
        out = self.data[self.at:self.at + n]
        self.at += n
        return out

    def name(self, what: str) -> str:
        end = self.data.find(b"\0", self.at, min(self.size, self.at + self.max_name + 1))
        if end < 0:
            raise _Damaged(f"{what} is not a name ending within {self.max_name} bytes (damaged header)")
        raw = self.take(end - self.at + 1, what)[:-1]
        return raw.decode("utf-8", errors="replace")


def _read(data, size: int, chunks: bool) -> list[ExrPart]:
    magic, version = struct.unpack_from("<ii", data, 0)
    if magic != _MAGIC:
        raise _Damaged("not an EXR file (no EXR magic number)")
    flags = version & ~0xFF
    if version & 0xFF != 2 or flags & ~(_TILED | _LONG_NAMES | _DEEP | _MULTIPART):
        raise _Damaged(f"unsupported EXR version field 0x{version:x}")
    if flags & _DEEP:
        raise _Damaged("deep data is not read (only flat images)")
    if flags & _TILED and flags & _MULTIPART:
        raise _Damaged("damaged header: a multi-part file with the single-part tiled flag")
    reader = _Reader(data, size, bool(flags & _LONG_NAMES))
    headers = []
    while True:
        headers.append(_header(reader))
        if not flags & _MULTIPART or data[reader.at:reader.at + 1] == b"\0":
            break
    if flags & _MULTIPART:
        reader.take(1, "the end of the headers")
    parts = [_part(h, i, flags) for i, h in enumerate(headers)]
    if chunks:
        table_start = reader.at
        counts = [_chunk_count(p, h) for p, h in zip(parts, headers)]
        first_chunk = table_start + 8 * sum(counts)
        if first_chunk > size:
            raise _Damaged("the file ends inside its chunk offset table (truncated?)")
        for index, (part, count) in enumerate(zip(parts, counts)):
            offsets = np.frombuffer(data, "<u8", count, table_start).astype(np.int64)  # a copy: data stays closable
            table_start += 8 * count
            _check_chunks(data, size, first_chunk, part, index, offsets, bool(flags & _MULTIPART))
    return parts


def _header(reader: _Reader) -> dict[str, tuple[str, bytes]]:
    attributes: dict[str, tuple[str, bytes]] = {}
    while True:
        name = reader.name("an attribute name")
        if not name:
            return attributes
        kind = reader.name(f"attribute {name!r}'s type")
        (length,) = struct.unpack("<i", reader.take(4, f"attribute {name!r}'s size"))
        value = reader.take(length, f"attribute {name!r}")
        if _FIXED_SIZES.get(kind, length) != length:
            raise _Damaged(f"damaged header: attribute {name!r} ({kind}) has {length} bytes")
        if name in attributes:
            raise _Damaged(f"damaged header: attribute {name!r} twice")
        attributes[name] = (kind, value)


def _channels(value: bytes) -> tuple[tuple[str, int, int, int], ...]:
    out, at = [], 0
    while at < len(value) and value[at] != 0:
        end = value.find(b"\0", at)
        if end < 0 or end + 17 > len(value):
            raise _Damaged("damaged header: the channel list is cut short")
        kind, _, xs, ys = struct.unpack_from("<iB3xii", value, end + 1)
        out.append((value[at:end].decode("utf-8", errors="replace"), kind, xs, ys))
        at = end + 17
    if at != len(value) - 1:
        raise _Damaged("damaged header: the channel list does not end where its size says")
    return tuple(out)


def _part(header: dict, index: int, flags: int) -> ExrPart:
    where = f"part {index}" if flags & _MULTIPART else "header"
    required = dict(_REQUIRED)
    if flags & _MULTIPART:
        required |= {"name": "string", "type": "string", "chunkCount": "int"}
    for key, kind in required.items():
        if key not in header:
            raise _Damaged(f"damaged {where}: no {key!r} attribute")
        if header[key][0] != kind:
            raise _Damaged(f"damaged {where}: {key!r} is {header[key][0]}, not {kind}")
    present = {key: header[key][1] for key, kind in _OPTIONAL.items() if header.get(key, ("",))[0] == kind}
    storage = "tiledimage" if flags & _TILED else "scanlineimage"
    stated = header["type"][1].decode("utf-8", errors="replace") if "type" in header else storage
    if stated in ("deepscanline", "deeptile"):
        raise _Damaged("deep data is not read (only flat images)")
    if stated == "tiledimage" and not flags & _MULTIPART:
        storage = stated
    elif stated in ("scanlineimage", "tiledimage") and flags & _MULTIPART:
        storage = stated
    elif flags & _MULTIPART:
        raise _Damaged(f"damaged {where}: storage type {stated!r}")
    x0, y0, x1, y1 = struct.unpack("<4i", header["dataWindow"][1])
    windows = [((x0, y0, x1, y1), "data window")]
    if "displayWindow" in present:
        windows.append((struct.unpack("<4i", present["displayWindow"]), "display window"))
    for box, what in windows:
        if box[0] > box[2] or box[1] > box[3] or min(box) <= -_LARGE or max(box) >= _LARGE:
            raise _Damaged(f"damaged {where}: {what} {box}")
    (aspect,) = struct.unpack("<f", present.get("pixelAspectRatio", struct.pack("<f", 1.0)))
    (screen_width,) = struct.unpack("<f", present.get("screenWindowWidth", struct.pack("<f", 1.0)))
    if not (math.isfinite(aspect) and 1e-6 <= aspect <= 1e6) or not screen_width >= 0:
        raise _Damaged(f"damaged {where}: pixel aspect {aspect:g}, screen window width {screen_width:g}")
    compression, line_order = header["compression"][1][0], present.get("lineOrder", b"\0")[0]
    if compression not in _LINES_PER_CHUNK:
        raise _Damaged(f"compression code {compression} is not supported")
    if line_order > 2:
        raise _Damaged(f"damaged {where}: line order {line_order}")
    channels = _channels(header["channels"][1])
    if not channels or len({c[0] for c in channels}) < len(channels):
        raise _Damaged(f"damaged {where}: no channels, or one named twice")
    for name, kind, xs, ys in channels:
        if kind not in _PIXEL_BYTES or xs < 1 or ys < 1 or x0 % xs or y0 % ys or (x1 - x0 + 1) % xs \
                or (y1 - y0 + 1) % ys or (storage == "tiledimage" and (xs, ys) != (1, 1)):
            raise _Damaged(f"damaged {where}: channel {name!r} (type {kind}, sampling {xs} x {ys})")
    tiles = None
    if storage == "tiledimage":
        if header.get("tiles", ("",))[0] != "tiledesc":
            raise _Damaged(f"damaged {where}: a tiled part without a tile description")
        tw, th, mode = struct.unpack("<IIB", header["tiles"][1])
        tiles = (tw, th, mode & 0xF, mode >> 4)
        if not (1 <= tw < _LARGE and 1 <= th < _LARGE) or tiles[2] > 2 or tiles[3] > 1:
            raise _Damaged(f"damaged {where}: tile description {tiles}")
    name = header["name"][1].decode("utf-8", errors="replace") if "name" in header else ""
    return ExrPart(name, storage, (x0, y0, x1, y1), channels, compression, tiles, line_order)


def _levels(extent: int, rounding: int) -> int:
    exponent = math.ceil(math.log2(extent)) if rounding else math.floor(math.log2(extent))
    return int(exponent) + 1


def _level_extent(extent: int, level: int, rounding: int) -> int:
    scaled = -(-extent // (1 << level)) if rounding else extent // (1 << level)
    return max(1, scaled)


def _tile_grid(part: ExrPart) -> list[tuple[int, int, int, int, int, int]]:
    """(level x, level y, tiles across, tiles down, level width, level height), in offset-table order."""
    width, height = part.size
    tw, th, mode, rounding = part.tiles
    if mode == 0:
        pairs = [(0, 0)]
    elif mode == 1:
        pairs = [(lv, lv) for lv in range(_levels(max(width, height), rounding))]
    else:
        pairs = [(lx, ly) for ly in range(_levels(height, rounding)) for lx in range(_levels(width, rounding))]
    grid = []
    for lx, ly in pairs:
        w, h = _level_extent(width, lx, rounding), _level_extent(height, ly, rounding)
        grid.append((lx, ly, -(-w // tw), -(-h // th), w, h))
    return grid


def _chunk_count(part: ExrPart, header: dict) -> int:
    if part.tiles is None:
        count = -(-part.size[1] // _LINES_PER_CHUNK[part.compression])
    else:
        count = sum(across * down for _, _, across, down, _, _ in _tile_grid(part))
    if "chunkCount" in header:
        (stated,) = struct.unpack("<i", header["chunkCount"][1])
        if stated != count:
            raise _Damaged(f"damaged header: chunkCount {stated}, the part's size gives {count}")
    if count > 1 << 24:
        raise _Damaged(f"{count} chunks: more than this reader takes")
    return count


def _fields(data, offsets: np.ndarray, n: int) -> np.ndarray:
    """n little-endian int32 read at each offset (all inside the file): [chunks, n] int64.
    The view of the mapped file lives only here (a mapping with views cannot close)."""
    view = np.frombuffer(data, np.uint8)
    gathered = view[offsets[:, None] + np.arange(4 * n)[None, :]]
    del view
    return gathered.view("<i4").reshape(len(offsets), n).astype(np.int64)


def _check_chunks(data, size: int, first_chunk: int, part: ExrPart, index: int, offsets: np.ndarray,
                  multipart: bool) -> None:
    lead = 2 + (part.tiles is not None) * 3 + multipart  # int32 fields before the data
    outside = (offsets < first_chunk) | (offsets > size - 4 * lead)
    if np.any(outside):
        offsets = _rebuilt(data, size, first_chunk, part, index, offsets, outside, multipart)
    fields = _fields(data, offsets, lead)
    if multipart and np.any(fields[:, 0] != index):
        raise _Damaged(f"part {index}'s chunk {np.flatnonzero(fields[:, 0] != index)[0]} names another part")
    fields = fields[:, multipart:]
    bytes_per_pixel = sum(_PIXEL_BYTES[kind] for _, kind, _, _ in part.channels)
    if part.tiles is None:
        lines = _LINES_PER_CHUNK[part.compression]
        x0, y0, x1, y1 = part.window
        expected = y0 + lines * np.arange(len(offsets), dtype=np.int64)
        unpacked = _scanline_bytes(part, expected, np.minimum(expected + lines, y1 + 1))
        full = bytes_per_pixel * (x1 - x0 + 1) * lines  # the most a chunk unpacks to, any sampling
        wrong = fields[:, 0] != expected
        what = "lines"
    else:
        tw, th = part.tiles[:2]
        expected, unpacked = [], []
        for lx, ly, across, down, w, h in _tile_grid(part):
            for ty in range(down):
                for tx in range(across):
                    expected.append((tx, ty, lx, ly))
                    unpacked.append(min(tw, w - tx * tw) * min(th, h - ty * th) * bytes_per_pixel)
        expected, unpacked = np.array(expected, np.int64), np.array(unpacked, np.int64)
        full = tw * th * bytes_per_pixel
        wrong = np.any(fields[:, :4] != expected, axis=1)
        what = "tile"
    if np.any(wrong):
        raise _Damaged(f"part {index}'s chunk {np.flatnonzero(wrong)[0]} names the wrong {what} (damaged)")
    packed = fields[:, -1]
    ends = offsets + 4 * lead + packed
    problems = (packed < 1) | (packed > full) | (ends > size) | ((part.compression == 0) & (packed != unpacked))
    if np.any(problems):
        k = np.flatnonzero(problems)[0]
        reason = "runs past the end of the file (truncated?)" if ends[k] > size else \
            f"says {packed[k]} bytes of data (damaged)"
        raise _Damaged(f"part {index}'s chunk {k} {reason}")


def _rebuilt(data, size: int, first_chunk: int, part: ExrPart, index: int, offsets: np.ndarray,
             outside: np.ndarray, multipart: bool) -> np.ndarray:
    """The offset table with its entries outside the file replaced by where the chunks lie if
    stored one after another, as the library rebuilds it (silently) for a single-part file
    of increasing lines. Anything else with such an entry is refused."""
    if multipart or part.tiles is not None or part.line_order != 0:
        raise _Damaged(f"part {index}'s chunk {np.flatnonzero(outside)[0]} is recorded outside the file "
                       "(truncated or damaged)")
    rebuilt, end = offsets.copy(), first_chunk
    for k in range(len(rebuilt)):
        if outside[k]:
            rebuilt[k] = end
        packed = struct.unpack_from("<i", data, rebuilt[k] + 4)[0] if rebuilt[k] + 8 <= size else -1
        if packed < 0:
            raise _Damaged(f"part {index}'s chunk {k} is recorded outside the file (truncated or damaged)")
        end = rebuilt[k] + 8 + packed
    return rebuilt


def _scanline_bytes(part: ExrPart, starts: np.ndarray, stops: np.ndarray) -> np.ndarray:
    """Unpacked bytes of the lines [start, stop) of a scanline part, per chunk."""
    x0, _, x1, _ = part.window
    total = np.zeros(len(starts), np.int64)
    for _, kind, xs, ys in part.channels:
        sampled_rows = -(-stops // ys) - -(-starts // ys)  # multiples of ys in [start, stop)
        total += sampled_rows * ((x1 - x0 + 1) // xs) * _PIXEL_BYTES[kind]
    return total
