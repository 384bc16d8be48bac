"""PNG files as relight.files.photo needs them beyond Pillow: every chunk's declared length checked
against the file before Pillow reads it, and the 16-bit decoder, which keeps the code values of
a non-interlaced 16-bit RGB/RGBA PNG that Pillow would cut to 8 bits.

Why a hand-written decoder (issue 19): Pillow, the core's one image library, opens a 16-bit
RGB PNG as 8-bit "RGB" (checked with Pillow 11 on a 1024x1024 16-bit file: mode RGB, uint8),
so the extra 8 bits of a camera export would be lost. The libraries that keep them (imageio
with a PNG plugin, OpenCV, pypng) are not dependencies of the core, and the Blender add-on
bundles every binary dependency once per platform (blender_addon/build.py); this decoder is
numpy + zlib only and reads that 1 MP file in 166 ms (2 loaded cores). It handles only
non-interlaced 16-bit RGB/RGBA and returns None otherwise (Pillow decodes the rest); its
sizes are checked against max_pixels and the file's length before anything is allocated.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

from relight.files.image_limits import check_declared_size

__all__ = ["check_png_chunks", "read_png16"]

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def read_png16(path: Path, max_pixels: int | None = None):
    """(rgb uint16 [H, W, 3], alpha uint16 [H, W] | None) of a non-interlaced 16-bit
    RGB/RGBA PNG, or None for anything else (then Pillow decodes it)."""
    data = path.read_bytes()
    if not data.startswith(_PNG_SIGNATURE):
        return None
    pos, header, idat = len(_PNG_SIGNATURE), None, []
    while pos + 8 <= len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        if len(body) != length:
            raise ValueError(f"{path}: truncated PNG chunk {kind!r}")
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body[:13])
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
        pos += 12 + length
    if header is None:
        raise ValueError(f"{path}: PNG without IHDR")
    width, height, depth, colour, _, _, interlace = header
    if depth != 16 or colour not in (2, 6) or interlace != 0:
        return None
    check_declared_size(width, height, path, max_pixels=max_pixels, file_bytes=len(data), fmt="PNG")
    channels = 3 if colour == 2 else 4
    bpp = 2 * channels
    stride = width * bpp
    expected = height * (stride + 1)
    inflater = zlib.decompressobj()
    try:
        raw = inflater.decompress(b"".join(idat), expected + 1)  # bounded: no zip bomb
    except zlib.error as exc:
        raise ValueError(f"{path}: corrupt PNG data ({exc})") from None
    if len(raw) != expected:
        raise ValueError(f"{path}: truncated PNG ({len(raw)} of {expected} bytes of pixel data)")
    rows = np.frombuffer(raw, np.uint8).reshape(height, stride + 1)
    kinds = rows[:, 0]
    if kinds.max(initial=0) > 4:
        raise ValueError(f"{path}: corrupt PNG (unknown row filter {int(kinds.max())})")
    recon = _png_unfilter(rows[:, 1:].reshape(height, width, bpp), kinds)
    values = recon.reshape(height, width * channels * 2).view(">u2").reshape(height, width, channels)
    values = values.astype(np.uint16)
    return values[..., :3], (values[..., 3] if channels == 4 else None)


def _png_unfilter(filtered: np.ndarray, kinds: np.ndarray) -> np.ndarray:
    """Undo PNG row filters; filtered [H, W, bpp] uint8 -> reconstructed bytes."""
    h, w, bpp = filtered.shape
    out = np.zeros((h + 1, w + 1, bpp), np.int16)  # zero row above, zero column left
    f = filtered.astype(np.int16)
    if np.all(kinds <= 2):
        # None/Sub/Up depend on nothing later in the row but the left byte's sum: row by row
        for r in range(h):
            k = kinds[r]
            if k == 0:
                out[r + 1, 1:] = f[r]
            elif k == 1:
                out[r + 1, 1:] = np.cumsum(f[r], axis=0, dtype=np.int64) & 255
            else:
                out[r + 1, 1:] = (f[r] + out[r, 1:]) & 255
        return out[1:, 1:].astype(np.uint8)
    # Average/Paeth read the left, upper and upper-left bytes: sweep anti-diagonals,
    # whose cells depend only on earlier diagonals, so each one is one vector step
    kind_of_row = kinds.astype(np.int16)
    for d in range(h + w - 1):
        r = np.arange(max(0, d - w + 1), min(h - 1, d) + 1)
        p = d - r
        left, up, ul = out[r + 1, p], out[r, p + 1], out[r, p]
        k = kind_of_row[r][:, None]
        pa, pb, pc = np.abs(up - ul), np.abs(left - ul), np.abs(left + up - 2 * ul)
        paeth = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, ul))
        pred = np.choose(k, [np.zeros_like(left), left, up, (left + up) >> 1, paeth])
        out[r + 1, p + 1] = (f[r, p] + pred) & 255
    return out[1:, 1:].astype(np.uint8)


EXIF_CHUNK_LIMIT = 1 << 20  # bytes: an eXIf chunk longer than this is not read (a JPEG's EXIF is under 64 KB)


def check_png_chunks(path: Path) -> bytes | None:
    """Every chunk's declared length must fit in the file: Pillow reads the rest of a
    damaged IDAT with one read(length), which allocates `length` bytes (up to 4 GiB)
    before finding the file shorter. Walks the 8-byte chunk headers only, and returns the
    body of the last eXIf chunk it passes (None when there is none): a PNG's EXIF may follow its
    pixels, where Pillow finds it only by decoding them."""
    size = path.stat().st_size
    exif = None
    with open(path, "rb") as f:
        pos = f.seek(len(_PNG_SIGNATURE))
        while pos + 8 <= size:
            length, kind = struct.unpack(">I4s", f.read(8))
            if pos + 12 + length > size:
                raise ValueError(f"{path}: truncated or corrupt PNG (chunk {kind!r} declares {length:,} bytes, "
                                 f"past the end of the {size:,}-byte file)")
            if kind == b"IEND":
                break
            if kind == b"eXIf" and length <= EXIF_CHUNK_LIMIT:  # the last one, as Pillow keeps
                exif = f.read(length)
            pos = f.seek(pos + 12 + length)
    return exif
