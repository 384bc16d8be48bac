"""A single-part scanline EXR with ZIP compression, deflated by ISA-L (the `isal` package) on
threads: OpenEXR's own writer takes 3-4x the CPU on a 24 MP float image (docs/BENCHMARKS.md,
"Writing the output"), most of it in its deflate.

The file is laid out as OpenEXR lays out a ZIP file (openexr.com, "OpenEXR File Layout"): the
header, the offset table, then one chunk per 16 lines holding the lines' pixels channel by
channel (channels in sorted name order), its bytes split into those at even and at odd
positions, each byte replaced by its difference to the one before plus 128, deflated in zlib's
format. A chunk that deflate does not shrink is stored as it is, which OpenEXR reads as raw
(a packed size equal to the unpacked size). The OpenEXR library reads these files back bit for
bit (tests/relight/files/test_exr_zip.py). Only float32 or float16 channels, one type for the whole file.
"""

from __future__ import annotations

import os
import struct
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

__all__ = ["LINES", "available", "isal_compress", "write_zip_exr"]

LINES = 16            # lines per ZIP chunk (fixed by the format)
TASK_LINES = 64       # lines one thread task packs: 4 chunks (3 MB of RGB float at 24 MP)
IN_FLIGHT = 2         # tasks queued per thread: what the writer holds is (2 threads + 1) tasks at most
LEVEL = 2             # ISA-L's level: 1-2 cost the same, 2 is 5 % smaller here (docs/BENCHMARKS.md)
_MAGIC = struct.pack("<i", 20000630)


def available() -> bool:
    """Whether ISA-L is installed (else OpenEXR's own writer is the faster one)."""
    try:
        from isal import isal_zlib  # noqa: F401
    except ImportError:
        return False
    return True


def isal_compress(data) -> bytes:
    """zlib-format deflate of `data` by ISA-L at LEVEL (releases the GIL while it runs)."""
    from isal import isal_zlib

    return isal_zlib.compress(data, LEVEL)


def _attribute(name: str, kind: str, value: bytes) -> bytes:
    return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value


def _header(names: Sequence[str], height: int, width: int, half: bool, attributes: dict[str, str]) -> bytes:
    pixel_type = 1 if half else 2
    channels = b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", pixel_type, 0, 1, 1) for n in sorted(names))
    window = struct.pack("<4i", 0, 0, width - 1, height - 1)
    fields = {
        "channels": ("chlist", channels + b"\0"),
        "compression": ("compression", b"\x03"),
        "dataWindow": ("box2i", window),
        "displayWindow": ("box2i", window),
        "lineOrder": ("lineOrder", b"\x00"),
        "pixelAspectRatio": ("float", struct.pack("<f", 1.0)),
        "screenWindowCenter": ("v2f", struct.pack("<2f", 0.0, 0.0)),
        "screenWindowWidth": ("float", struct.pack("<f", 1.0)),
    }
    fields.update({key: ("string", value.encode("utf-8")) for key, value in attributes.items()})
    long_names = max(len(n.encode()) for n in [*names, *fields]) > 31
    version = 2 | (0x400 if long_names else 0)
    return (_MAGIC + struct.pack("<i", version) + b"".join(_attribute(k, *fields[k]) for k in sorted(fields))
            + b"\0")


def _tasks(bands: Iterable[np.ndarray], height: int) -> Iterator[tuple[int, list[np.ndarray]]]:
    """(first line, the pieces of bands covering the next TASK_LINES lines), in order."""
    pieces, held, start = [], 0, 0
    for band in bands:
        while band.shape[0]:
            take = min(band.shape[0], TASK_LINES - held)
            pieces.append(band[:take])
            band, held = band[take:], held + take
            if held == TASK_LINES or start + held == height:
                yield start, pieces
                pieces, start, held = [], start + held, 0
    if pieces:
        yield start, pieces


def _pack(pieces: list[np.ndarray], order: list[int], dtype) -> list[bytes]:
    """The chunks of the lines the pieces hold: each [rows, W, C] piece's channels put in file
    order, line by line, then split, predicted and deflated per 16 lines."""
    lines = sum(p.shape[0] for p in pieces)
    width = pieces[0].shape[1]
    block = np.empty((lines, len(order), width), dtype)
    row = 0
    with np.errstate(over="ignore"):  # float16: beyond 65504 is inf, as the format stores it
        for piece in pieces:
            for slot, channel in enumerate(order):
                block[row:row + piece.shape[0], slot, :] = piece[:, :, channel]
            row += piece.shape[0]
    chunks = []
    for r0 in range(0, lines, LINES):
        raw = block[r0:r0 + LINES].reshape(-1).view(np.uint8)
        split = np.empty_like(raw)
        evens = (raw.size + 1) // 2
        split[:evens], split[evens:] = raw[0::2], raw[1::2]
        predicted = np.empty_like(split)
        predicted[0] = split[0]
        np.subtract(split[1:], split[:-1], out=predicted[1:])
        predicted[1:] += 128  # uint8: modulo 256, as the format's predictor
        packed = isal_compress(predicted)
        chunks.append(packed if len(packed) < raw.size else raw.tobytes())
    return chunks


def write_zip_exr(f, names: Sequence[str], height: int, width: int, bands: Iterable[np.ndarray], *,
                  half: bool = False, attributes: dict[str, str] | None = None, threads: int | None = None) -> None:
    """Write the EXR into `f`, an open, seekable binary file. `bands` yields float arrays
    [rows, width, len(names)] (channel c is `names[c]`), top first, rows adding up to `height`
    (the caller checks the bands; a shortfall raises ValueError here). Stored as float32, or
    float16 when `half`; `attributes`: string attributes of the header. Bands are packed on
    `threads` threads (default: the cores available, at most 4) in tasks of TASK_LINES lines;
    the rows of at most IN_FLIGHT * threads + 1 tasks are held at a time (views of the bands)."""
    order = sorted(range(len(names)), key=lambda c: names[c].encode())
    dtype = np.float16 if half else np.float32
    if threads is None:
        threads = min(4, len(os.sched_getaffinity(0))) if hasattr(os, "sched_getaffinity") else 2
    f.write(_header(names, height, width, half, attributes or {}))
    table = f.tell()
    count = -(-height // LINES)
    f.write(bytes(8 * count))
    offsets: list[int] = []

    def flush(start: int, future) -> None:
        for k, packed in enumerate(future.result()):
            offsets.append(f.tell())
            f.write(struct.pack("<ii", start + k * LINES, len(packed)))
            f.write(packed)

    with ThreadPoolExecutor(max_workers=max(1, threads), thread_name_prefix="relight-exr") as pool:
        pending: deque = deque()
        for start, pieces in _tasks(bands, height):
            pending.append((start, pool.submit(_pack, pieces, order, dtype)))
            while len(pending) > IN_FLIGHT * threads:
                flush(*pending.popleft())
        while pending:
            flush(*pending.popleft())
    if len(offsets) != count:
        raise ValueError(f"EXR bands hold {min(height, LINES * len(offsets))} of its {height} rows")
    end = f.tell()
    f.seek(table)
    f.write(np.asarray(offsets, "<u8").tobytes())
    f.seek(end)
