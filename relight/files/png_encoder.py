"""Linear RGB -> 8-bit sRGB PNG, fast at photo size (relight.files.photo.write_png; docs/BENCHMARKS.md,
"Writing the output").

    codes = encode_srgb8(linear)                 # uint8 sRGB codes, by table
    write_png_file(f, linear, {"relight": "..."})  # the PNG's bytes into an open binary file

The sRGB curve is evaluated by table (a lookup by the float's top bits and one comparison),
not by pow(). The PNG is this module's own: every row "Up"-filtered (the row minus the row above: one
numpy subtraction) and deflated in bands of rows on threads, each band an independent piece of
one deflate stream (a full flush ends each, as pigz does). The deflate is ISA-L's (the `isal`
package, level 1) when it is installed, else zlib's (level 1, run-length strategy), both
chosen by benchmarks/bench_write.py. Metadata goes into tEXt chunks (iTXt when not Latin-1).
"""

from __future__ import annotations

import os
import struct
import zlib
from collections import deque
from concurrent.futures import ThreadPoolExecutor

import numpy as np

__all__ = ["BAND_ROWS", "deflate_module", "encode_srgb8", "write_png_file"]

BAND_ROWS = 256          # rows deflated as one piece: a few MB in flight per thread at 24 MP
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_SHIFT = 12              # a float32's top 20 bits index the table: bins 2^-11 of a value wide, narrower than
                         # the gap between any two rounding thresholds (0.9 % of a value near code 255)
_ENCODE: tuple[np.ndarray, np.ndarray] | None = None


def _encode_tables() -> tuple[np.ndarray, np.ndarray]:
    """(code at the lower edge of each bin of float32 bit patterns >> _SHIFT over [0, 1], the
    linear value where code k + 1 begins, k = 0..255)."""
    global _ENCODE
    if _ENCODE is None:
        from relight.imaging.colour import srgb_decode

        # rint(255 srgb_encode(x)) steps from k to k + 1 where srgb_encode(x) = (k + 0.5) / 255
        steps = srgb_decode((np.arange(255, dtype=np.float64) + 0.5) / 255.0)
        top = int(np.float32(1.0).view(np.uint32)) >> _SHIFT
        edges = (np.arange(top + 1, dtype=np.uint32) << _SHIFT).view(np.float32).astype(np.float64)
        codes = np.searchsorted(steps, edges, side="right").astype(np.uint8)
        _ENCODE = codes, np.append(steps, np.inf).astype(np.float32)
    return _ENCODE


def encode_srgb8(linear: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB codes, clipped to [0, 1] and rounded: a table lookup by the
    float's top bits and one comparison with the next code's threshold, 5x faster than
    evaluating the curve (docs/BENCHMARKS.md). It gives rint(255 srgb_encode(x)) except within
    float32 rounding of a threshold (one code off, 1e-5 of random values); decoded codes
    (relight.files.video_io.decode_srgb) come back exactly. ValueError on NaN or Inf."""
    a = np.asarray(linear)
    if a.dtype != np.float32:
        a = a.astype(np.float32)
    out = np.empty(a.shape, np.uint8) if out is None else out
    codes, steps = _encode_tables()
    rows = max(1, (1 << 18) // max(1, a[0].size)) if a.ndim > 1 else a.shape[0]
    for r0 in range(0, a.shape[0], rows):  # strips: temporaries stay in cache
        x = a[r0:r0 + rows]
        if not np.all(np.isfinite(x)):
            raise ValueError("image to write contains NaN or Inf")
        x = np.clip(x, 0.0, 1.0)  # also -0.0 to +0.0: its sign bit would index past the table
        code = codes[x.view(np.uint32) >> _SHIFT]
        code += x >= steps[code]
        out[r0:r0 + rows] = code
    return out


def deflate_module():
    """(module with zlib's compressobj API, level, strategy): ISA-L's when installed, else zlib's."""
    try:
        from isal import isal_zlib
    except ImportError:
        return zlib, 1, zlib.Z_RLE
    return isal_zlib, 1, isal_zlib.Z_DEFAULT_STRATEGY


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(body, zlib.crc32(kind)))


def write_png_file(f, linear: np.ndarray, metadata: dict[str, str] | None = None, threads: int | None = None) -> None:
    """Write linear RGB [H, W, 3] as an 8-bit sRGB PNG into the open binary file `f`; `metadata`:
    text chunks. Bands of BAND_ROWS rows are encoded, filtered and deflated on `threads` threads
    (default: the cores available, at most 4) and written in order; ValueError on NaN or Inf."""
    h, w = linear.shape[:2]
    module, level, strategy = deflate_module()
    if threads is None:
        threads = min(4, len(os.sched_getaffinity(0))) if hasattr(os, "sched_getaffinity") else 2
    bands = [(r0, min(h, r0 + BAND_ROWS)) for r0 in range(0, h, BAND_ROWS)]

    def piece(i: int) -> tuple[bytes, int]:
        # band i's rows as PNG scanlines: filter byte 2 ("Up") then each row minus the row above
        r0, r1 = bands[i]
        top = max(0, r0 - 1)
        codes = encode_srgb8(linear[top:r1]).reshape(r1 - top, 3 * w)
        filtered = np.empty((r1 - r0, 3 * w + 1), np.uint8)
        filtered[:, 0] = 2
        if r0 == 0:
            filtered[0, 1:] = codes[0]  # the first row has nothing above: Up leaves it as it is
            np.subtract(codes[1:], codes[:-1], out=filtered[1:, 1:])
        else:
            np.subtract(codes[1:], codes[:-1], out=filtered[:, 1:])
        raw = memoryview(filtered).cast("B")
        packer = module.compressobj(level, module.DEFLATED, -15, 9, strategy)
        last = i == len(bands) - 1
        return packer.compress(raw) + packer.flush(module.Z_FINISH if last else module.Z_FULL_FLUSH), \
            zlib.adler32(raw)  # the band's checksum alone (a zlib stream's is over all rows: combined below)

    f.write(PNG_SIGNATURE + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)))
    for key, value in (metadata or {}).items():  # tEXt, or iTXt (UTF-8, uncompressed, no language)
        if not 1 <= len(key) <= 79 or not key.isprintable():
            raise ValueError(f"PNG text keys must be 1-79 printable characters, got {key!r}")
        try:
            f.write(_chunk(b"tEXt", key.encode("latin-1") + b"\0" + value.encode("latin-1")))
        except UnicodeEncodeError:
            f.write(_chunk(b"iTXt", key.encode("latin-1") + b"\0\0\0\0\0" + value.encode("utf-8")))
    checksum, first = 1, True
    with ThreadPoolExecutor(max_workers=max(1, threads), thread_name_prefix="relight-png") as pool:
        pending: deque = deque()
        for i in range(len(bands)):
            pending.append((i, pool.submit(piece, i)))
            while len(pending) > 2 * threads or (i == len(bands) - 1 and pending):
                j, future = pending.popleft()
                data, band_sum = future.result()
                r0, r1 = bands[j]
                checksum = _adler32_combine(checksum, band_sum, (r1 - r0) * (3 * w + 1))
                if first:
                    data = b"\x78\x01" + data  # the zlib header: deflate, 32 KB window, fastest
                    first = False
                if j == len(bands) - 1:
                    data += struct.pack(">I", checksum)
                f.write(_chunk(b"IDAT", data))
    f.write(_chunk(b"IEND", b""))


_ADLER = 65521


def _adler32_combine(a1: int, a2: int, length2: int) -> int:
    """The Adler-32 of two byte strings one after the other, from theirs (zlib's adler32_combine)."""
    rem = length2 % _ADLER
    s1 = a1 & 0xFFFF
    s2 = (rem * s1) % _ADLER
    s1 = (s1 + (a2 & 0xFFFF) + _ADLER - 1) % _ADLER
    s2 = (s2 + ((a1 >> 16) & 0xFFFF) + ((a2 >> 16) & 0xFFFF) + _ADLER - rem) % _ADLER
    return (s2 << 16) | s1
