"""How large an image may be decoded: the declared size of a photo, mask, map or video frame
is weighed here before any pixel is allocated (a pixel limit, what the file's size can hold,
the memory free). relight.files.photo_header, relight.files.png_decoder, relight.lighting.envmap
and relight.files.video_io ask. A refusal is an ImageSizeError: one line naming the file, and
the facts (which limit, the size, the limit, the file's length, the memory) as attributes for
a caller that words it otherwise (the add-on). ImageFileError is the kind of every refusal of
an image file before its pixels are decoded (relight.files.photo_header adds the others)."""

from __future__ import annotations

import numpy as np

__all__ = ["BYTES_PER_PIXEL", "DEFAULT_MAX_PIXELS", "MAX_PIXELS", "MAX_SIDE", "ImageFileError", "ImageSizeError",
           "check_declared_size", "check_max_pixels", "memory_available"]

MAX_SIDE = 40_000            # px: refuse wider/taller images before decoding
MAX_PIXELS = 150_000_000     # hard ceiling, below Pillow's own bomb limit (2 x 89.5 MP) so ours speaks first
DEFAULT_MAX_PIXELS = 50_000_000  # without --max-pixels (a 50 MP camera frame): ~2 GB through `relight image`
BYTES_PER_PIXEL = 40         # peak bytes per photo pixel through `relight image` (24 MP: < 1 GB measured)
PLAUSIBLE_FROM = 1_000_000   # below this many pixels decoding is cheap: no file-size test
# most pixels one byte of file can hold: JPEG's Huffman-coded DC term costs at least 1 bit per
# 8x8 block (512 px/byte; x8 for arithmetic coding), PNG's deflate at most 1032:1 on 1-bit pixels
# (~8,300 px/byte); other formats get a bound 4x above a uniform lossless WebP (23,500 px/byte)
MAX_PIXELS_PER_BYTE = {"JPEG": 4_096, "MPO": 4_096, "PNG": 8_400}
MAX_PIXELS_PER_BYTE_OTHER = 100_000


class ImageFileError(ValueError):
    """An image file refused: the message is one line that starts with the file (`path`)."""

    def __init__(self, path, message: str):
        super().__init__(message)
        self.path = path


class ImageSizeError(ImageFileError):
    """A declared size refused before anything is allocated for it. `limit` says which check:
    "empty" (no pixel), "side" (over MAX_SIDE), "pixels" (over `max_pixels`: the limit applied),
    "file" (more pixels than a `file_bytes`-long file of format `fmt` can hold: forged or
    truncated) or "memory" (`need_bytes` over the `free_bytes` free). `width` and `height` are
    None when only the pixel count is known (Pillow's own bomb check spoke first)."""

    def __init__(self, path, message: str, limit: str, width: int | None, height: int | None, pixels: int, *,
                 max_pixels: int | None = None, file_bytes: int | None = None, fmt: str | None = None,
                 need_bytes: int | None = None, free_bytes: int | None = None):
        super().__init__(path, message)
        self.limit, self.width, self.height, self.pixels = limit, width, height, pixels
        self.max_pixels, self.file_bytes, self.fmt = max_pixels, file_bytes, fmt
        self.need_bytes, self.free_bytes = need_bytes, free_bytes


def memory_available() -> int | None:
    """Bytes this process can still allocate: the kernel's MemAvailable, and the
    headroom under an address-space limit (RLIMIT_AS) when one is set; None if unknown."""
    bounds = []
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    bounds.append(int(line.split()[1]) * 1024)
                    break
    except (OSError, ValueError, IndexError):
        pass
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft != resource.RLIM_INFINITY:
            with open("/proc/self/status") as f:
                vm = next(int(l.split()[1]) * 1024 for l in f if l.startswith("VmSize:"))
            bounds.append(max(0, soft - vm))
    except (ImportError, OSError, ValueError, StopIteration):
        pass
    return min(bounds) if bounds else None


def _megapixels(pixels: int) -> str:
    return f"{pixels / 1e6:.3g} MP"


def check_max_pixels(max_pixels: int | None = None) -> int:
    """Validate a pixel limit (None: DEFAULT_MAX_PIXELS) and return it."""
    if max_pixels is None:
        return DEFAULT_MAX_PIXELS
    if isinstance(max_pixels, bool) or not isinstance(max_pixels, (int, np.integer)) \
            or not 1 <= max_pixels <= MAX_PIXELS:
        raise ValueError(f"max_pixels must be an integer in [1, {MAX_PIXELS}], got {max_pixels!r}")
    return int(max_pixels)


def check_declared_size(width: int, height: int, path, *, max_pixels: int | None = None,
                        file_bytes: int | None = None, fmt: str | None = None,
                        bytes_per_pixel: int = BYTES_PER_PIXEL, weigh_file_size: bool | None = None) -> None:
    """Weigh a size read from a header before anything is allocated for it.

    Refused (ImageSizeError): an empty size; more than MAX_SIDE a side; more
    pixels than `max_pixels` (default DEFAULT_MAX_PIXELS); with
    `weigh_file_size` (by default: when no `max_pixels` is given, which allows
    it), more pixels than a `file_bytes`-long file of format `fmt` can hold (a
    forged header); and always, more memory than is free.
    """
    if width < 1 or height < 1:
        raise ImageSizeError(path, f"{path}: image is empty ({width}x{height})", "empty", width, height,
                             max(0, width) * max(0, height))
    pixels = width * height
    if width > MAX_SIDE or height > MAX_SIDE:
        raise ImageSizeError(path, f"{path}: image is too large ({width}x{height}; limit: {MAX_SIDE} px a side)",
                             "side", width, height, pixels)
    limit = check_max_pixels(max_pixels)
    if pixels > limit:
        hint = (f"--max-pixels {pixels} allows it" if pixels <= MAX_PIXELS
                else f"{MAX_PIXELS // 1_000_000} MP is the most any setting allows")
        raise ImageSizeError(path, f"{path}: image is {width}x{height} ({_megapixels(pixels)}), over the limit of "
                             f"{_megapixels(limit)} ({hint})", "pixels", width, height, pixels, max_pixels=limit)
    if weigh_file_size is None:
        weigh_file_size = max_pixels is None
    if weigh_file_size and file_bytes is not None and pixels > PLAUSIBLE_FROM:
        per_byte = MAX_PIXELS_PER_BYTE.get(fmt or "", MAX_PIXELS_PER_BYTE_OTHER)
        if pixels > file_bytes * per_byte:
            raise ImageSizeError(path, f"{path}: header declares {width}x{height} ({_megapixels(pixels)}) in a "
                                 f"{file_bytes:,}-byte {fmt or 'image'} file, more than such a file can hold: "
                                 f"forged or truncated (--max-pixels {pixels} decodes it anyway)",
                                 "file", width, height, pixels, file_bytes=file_bytes, fmt=fmt)
    free = memory_available()
    need = pixels * bytes_per_pixel
    if free is not None and need > free:
        raise ImageSizeError(path, f"{path}: a {width}x{height} image needs about {need / 2**30:.1f} GiB, "
                             f"only {free / 2**30:.1f} GiB of memory is free", "memory", width, height, pixels,
                             need_bytes=need, free_bytes=free)
