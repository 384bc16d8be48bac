"""The pixels handed back to Blender: float32 buffers kept for reuse, arrays laid out as
Blender's RGBA (bottom row first), and the Strength blend of the relit photo with the original.
Plain Python."""

from __future__ import annotations

import numpy as np


class BufferPool:
    """Float32 buffers kept for reuse, by length.

    A fresh 24 MP RGBA buffer (384 MB) costs 0.4 to 1.6 s of page faults on
    the 2-core machine (more when the kernel compacts memory for huge pages);
    a reused one costs nothing. The worker takes, the main thread gives back
    after foreach_set has copied the pixels into Blender. Small buffers are
    not pooled.
    """

    MIN_VALUES = 1 << 20

    def __init__(self, keep: int = 1):  # one dial change at a time; each kept buffer holds 384 MB at 24 MP
        import threading

        self.keep = keep
        self._free: list[np.ndarray] = []
        self._lock = threading.Lock()

    def take(self, n: int) -> np.ndarray:
        buf = self.take_pooled(n)
        return np.empty(n, np.float32) if buf is None else buf

    def take_pooled(self, n: int) -> np.ndarray | None:
        """A kept buffer of `n` values, or None (nothing is allocated)."""
        with self._lock:
            for i, buf in enumerate(self._free):
                if buf.size == n:
                    return self._free.pop(i)
        return None

    def give(self, buf: np.ndarray) -> None:
        """Hand back a buffer nobody reads any more."""
        if buf.dtype != np.float32 or buf.ndim != 1 or buf.size < self.MIN_VALUES or not buf.flags.owndata:
            return
        with self._lock:
            if all(b is not buf for b in self._free):
                self._free.append(buf)
                del self._free[:-self.keep]  # the oldest go

    def clear(self) -> None:
        with self._lock:
            self._free.clear()

    def __len__(self) -> int:
        return len(self._free)


BUFFERS = BufferPool()


# ------------------------------------------------------------------ orientation
# Blender shows a photo file as it is stored (it ignores the EXIF orientation); the core reads it
# upright (relight.files.photo.read_photo) and the network sees it so. `orientation` is the file's EXIF
# orientation (relight.files.photo.exif_orientation, 1 - 8): the turn from the stored pixels to the
# upright ones, as PIL.ImageOps.exif_transpose makes it. Every turn is a numpy view (flips and a
# transpose of the first two axes), so writing upright values into upright(stored) writes the
# stored image.

def upright(stored: np.ndarray, orientation: int) -> np.ndarray:
    """The stored image [H, W, ...] (top row first) turned upright by its EXIF orientation (a
    view): relight.files.photo.upright, the core's one table of the eight turns."""
    from relight.files.photo import upright as turn

    return turn(stored, orientation)


def as_stored(upright_image: np.ndarray, orientation: int) -> np.ndarray:
    """The upright image [H, W, ...] turned back to how its file stores it (a view): upright's inverse."""
    from relight.files.photo import as_stored as turn_back

    return turn_back(upright_image, orientation)


def stored_size(size: tuple[int, int], orientation: int) -> tuple[int, int]:
    """(H, W) of the stored image whose upright image is `size` (H, W): sides swapped for 5 - 8."""
    h, w = size
    return (w, h) if orientation >= 5 else (h, w)


def blender_view(rgba: np.ndarray, size: tuple[int, int], orientation: int = 1) -> np.ndarray:
    """A view [H, W, 4] of the upright image `size` (H, W) into a flat RGBA buffer in Blender's layout
    (the stored image, bottom row first): what is written into it lands where Blender shows it."""
    hs, ws = stored_size(size, orientation)
    return upright(rgba.reshape(hs, ws, 4)[::-1], orientation)


def to_blender_rgba(pixels: np.ndarray, out: np.ndarray | None = None,
                    alpha: np.ndarray | None = None, orientation: int = 1) -> np.ndarray:
    """[H, W] or [H, W, 1|3|4] top row first -> flat float32 RGBA, bottom row first (Blender's layout);
    `alpha` [H, W], when given, is the alpha channel. `orientation`: `pixels` is the upright image of
    a file with this EXIF orientation; the buffer holds it as the file stores it (Blender shows that).

    `out` (H * W * 4 float32) is filled when given, else a buffer from BUFFERS:
    the worker prepares it and the main thread only hands it to foreach_set.
    """
    px = np.asarray(pixels, dtype=np.float32)
    if px.ndim == 2:
        px = px[..., None]
    h, w, c = px.shape
    rgba = BUFFERS.take(h * w * 4) if out is None else out
    if orientation != 1:  # a turned view: square tiles of the upright image, one channel at a time
        view = blender_view(rgba, (h, w), orientation)
        tile = 128
        for r0 in range(0, h, tile):
            for c0 in range(0, w, tile):
                src, to = px[r0:r0 + tile, c0:c0 + tile], view[r0:r0 + tile, c0:c0 + tile]
                for k in range(3):
                    to[..., k] = src[..., min(k, c - 1) if c < 3 else k]
                to[..., 3] = alpha[r0:r0 + tile, c0:c0 + tile] if alpha is not None else src[..., 3] if c == 4 else 1.0
        return rgba
    view = rgba.reshape(h, w, 4)
    # blocks of rows that stay in cache, one channel at a time: a single
    # view[..., :3] = px[::-1] loops 3 values at a time over 24 MP, 10x slower
    step = max(1, (1 << 16) // max(1, w))
    for r0 in range(0, h, step):
        r1 = min(h, r0 + step)
        src = px[h - r1:h - r0][::-1]
        for k in range(3):
            view[r0:r1, :, k] = src[..., min(k, c - 1) if c < 3 else k]
        if alpha is not None:  # [H, W], top row first
            view[r0:r1, :, 3] = alpha[h - r1:h - r0][::-1]
        else:
            view[r0:r1, :, 3] = src[..., 3] if c == 4 else 1.0
    return rgba


def blend(relit: np.ndarray, photo: np.ndarray, strength: float) -> np.ndarray:
    """photo + strength * (relit - photo), float32 [H, W, 3].

    `relit` is the runtime's full frame (relit person composited over the
    untouched background), so strength 0 gives the photo back, 1 the relit
    photo, and the background never changes.
    """
    if relit.shape != photo.shape:
        raise ValueError(f"relit image {relit.shape} and photo {photo.shape} differ in size")
    s = float(np.clip(strength, 0.0, 1.0))
    if s == 1.0:
        return np.asarray(relit, dtype=np.float32)
    if s == 0.0:
        return np.array(photo, dtype=np.float32)
    out = np.subtract(relit, photo, dtype=np.float32)
    out *= np.float32(s)
    out += photo
    return out


def blend_into(relit: np.ndarray, photo: np.ndarray, strength: float) -> None:
    """blend() in place: `relit` [H, W, 3] (a strided view too) becomes
    photo + strength * (relit - photo), with the same operations in the same order."""
    s = float(np.clip(strength, 0.0, 1.0))
    if s == 1.0:
        return
    h, w = relit.shape[:2]
    if abs(relit.strides[1]) > abs(relit.strides[0]):
        # a turned view (blender_view of a sideways photo): its rows are the buffer's columns,
        # so square tiles keep what is read and what is written in cache
        rows = cols = 128
    else:
        rows, cols = max(1, (1 << 12) // max(1, w)), w  # rows that stay in cache, one channel at a time
    for r0 in range(0, h, rows):
        for c0 in range(0, w, cols):
            for c in range(3):
                out, p = relit[r0:r0 + rows, c0:c0 + cols, c], photo[r0:r0 + rows, c0:c0 + cols, c]
                if s == 0.0:
                    out[...] = p
                    continue
                out -= p
                out *= np.float32(s)
                out += p
