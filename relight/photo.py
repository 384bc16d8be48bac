"""Photo files <-> linear float32 arrays.

Reads PNG/JPEG/TIFF/WebP (sRGB-encoded; EXIF orientation applied; 8- and
16-bit; grey expanded to RGB; an alpha channel comes back as the mask) and
EXR (linear). Writes 8-bit sRGB PNG, linear EXR, and a multi-layer EXR whose
channels follow Blender's "<layer>.<pass>.<channel>" naming so its Image node
shows every pass. The declared image size is weighed before any pixel is
decoded (check_declared_size: a pixel limit, the file's size, the memory
free); every failure to read is one ValueError. Writes are atomic.
"""

from __future__ import annotations

import os
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from relight.colour import decode_alpha_codes, decode_srgb_codes, srgb_encode
from relight.fileio import atomic_path

__all__ = ["read_photo", "read_mask", "write_image", "write_png", "write_exr_image",
           "write_layers_exr", "check_declared_size", "check_max_pixels", "memory_available", "MAX_SIDE", "MAX_PIXELS",
           "DEFAULT_MAX_PIXELS", "LAYER_NAME", "PHOTO_SUFFIXES"]

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
STRIP_ROWS = 256             # rows converted at a time: bounds temporaries for huge photos
LAYER_NAME = "Relight"       # render-layer name in multi-layer EXRs
PHOTO_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".webp", ".bmp", ".exr")
EXR_MAGIC = b"\x76\x2f\x31\x01"

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
                        bytes_per_pixel: int = BYTES_PER_PIXEL) -> None:
    """Weigh a size read from a header before anything is allocated for it.

    Refused: an empty size; more than MAX_SIDE a side; more pixels than
    `max_pixels` (default DEFAULT_MAX_PIXELS); by default, more pixels than
    a `file_bytes`-long file of format `fmt` can hold (a forged header: an
    explicit `max_pixels` allows it); and always, more memory than is free.
    """
    if width < 1 or height < 1:
        raise ValueError(f"{path}: image is empty ({width}x{height})")
    pixels = width * height
    if width > MAX_SIDE or height > MAX_SIDE:
        raise ValueError(f"{path}: image is too large ({width}x{height}; limit: {MAX_SIDE} px a side)")
    limit = check_max_pixels(max_pixels)
    if pixels > limit:
        hint = (f"--max-pixels {pixels} allows it" if pixels <= MAX_PIXELS
                else f"{MAX_PIXELS // 1_000_000} MP is the most any setting allows")
        raise ValueError(f"{path}: image is {width}x{height} ({_megapixels(pixels)}), over the limit of "
                         f"{_megapixels(limit)} ({hint})")
    if max_pixels is None and file_bytes is not None and pixels > PLAUSIBLE_FROM:
        per_byte = MAX_PIXELS_PER_BYTE.get(fmt or "", MAX_PIXELS_PER_BYTE_OTHER)
        if pixels > file_bytes * per_byte:
            raise ValueError(f"{path}: header declares {width}x{height} ({_megapixels(pixels)}) in a "
                             f"{file_bytes:,}-byte {fmt or 'image'} file, more than such a file can hold: "
                             f"forged or truncated (--max-pixels {pixels} decodes it anyway)")
    free = memory_available()
    need = pixels * bytes_per_pixel
    if free is not None and need > free:
        raise ValueError(f"{path}: a {width}x{height} image needs about {need / 2**30:.1f} GiB, "
                         f"only {free / 2**30:.1f} GiB of memory is free")


def _check_size(width: int, height: int, path, max_pixels: int | None = None, file_bytes: int | None = None,
                fmt: str | None = None) -> None:
    check_declared_size(width, height, path, max_pixels=max_pixels, file_bytes=file_bytes, fmt=fmt)


def _exists(path: Path) -> None:
    if not path.exists():
        raise ValueError(f"{path}: file not found")
    if not path.is_file():
        raise ValueError(f"{path}: not a file")
    if path.stat().st_size == 0:
        raise ValueError(f"{path}: file is empty")


def read_photo(path: str | os.PathLike, max_pixels: int | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Read a photo as (linear float32 [H, W, 3], mask float32 [H, W] in [0, 1] or None).

    The mask is the file's alpha channel when it has one. `max_pixels`
    (default DEFAULT_MAX_PIXELS, at most MAX_PIXELS) bounds the declared size;
    see check_declared_size.
    """
    path = Path(path)
    check_max_pixels(max_pixels)
    _exists(path)
    with open(path, "rb") as f:
        magic = f.read(4)
    with warnings.catch_warnings():
        # Pillow's warnings (corrupt EXIF, tags past the end, bomb sizes: our check spoke first)
        # would be stray stderr lines; the photo decodes or fails with one ValueError
        warnings.simplefilter("ignore")
        if magic == EXR_MAGIC:
            return _read_exr_photo(path, max_pixels)
        return _read_pillow_photo(path, max_pixels)


# ------------------------------------------------------------------ Pillow


def _open_pillow(path: Path):
    from PIL import Image

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            im = Image.open(path)
    except Image.DecompressionBombError:
        raise ValueError(f"{path}: image is too large (refused before decoding)") from None
    except Exception as exc:  # Pillow raises UnidentifiedImageError, SyntaxError, struct.error...
        if isinstance(exc, MemoryError):
            raise
        raise ValueError(f"{path}: not a readable image ({type(exc).__name__}: {exc})") from None
    return im


def _check_png_chunks(path: Path) -> None:
    """Every chunk's declared length must fit in the file: Pillow reads the rest of a
    damaged IDAT with one read(length), which allocates `length` bytes (up to 4 GiB)
    before finding the file shorter. Walks the 8-byte chunk headers only."""
    import struct

    size = path.stat().st_size
    with open(path, "rb") as f:
        pos = f.seek(len(_PNG_SIGNATURE))
        while pos + 8 <= size:
            length, kind = struct.unpack(">I4s", f.read(8))
            if pos + 12 + length > size:
                raise ValueError(f"{path}: truncated or corrupt PNG (chunk {kind!r} declares {length:,} bytes, "
                                 f"past the end of the {size:,}-byte file)")
            if kind == b"IEND":
                return
            pos = f.seek(pos + 12 + length)


@contextmanager
def _decoder_errors(path: Path, what: str):
    """Whatever a decoder raises (truncated data, bad EXIF, library errors) becomes
    ValueError("PATH: WHAT (Type: message)"); our own ValueErrors, already worded,
    and MemoryError pass unchanged."""
    try:
        yield
    except (ValueError, MemoryError):
        raise
    except Exception as exc:
        raise ValueError(f"{path}: {what} ({type(exc).__name__}: {exc})") from None


def _read_pillow_photo(path: Path, max_pixels: int | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    from PIL import ImageOps

    im = _open_pillow(path)
    try:
        with _decoder_errors(path, "corrupt or truncated image"):
            width, height = im.size
            _check_size(width, height, path, max_pixels, path.stat().st_size, im.format)
            if im.format == "PNG":
                _check_png_chunks(path)
            if getattr(im, "n_frames", 1) > 1:
                im.seek(0)  # animated/multi-page files: the first frame is the photo
            rawmode = im.tile[0][3] if im.tile and len(im.tile[0]) > 3 else ""
            if isinstance(rawmode, tuple):
                rawmode = rawmode[0]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                if im.format == "PNG" and im.mode in ("RGB", "RGBA") and str(rawmode).endswith(";16B"):
                    # Pillow keeps only 8 bits of 16-bit colour PNGs: decode those ourselves
                    decoded = _read_png16(path, max_pixels)
                    if decoded is not None:
                        return _decode_16bit(*decoded)
                im.load()
                im = ImageOps.exif_transpose(im)
                return _pillow_to_linear(im, path)
    finally:
        im.close()


def _pillow_to_linear(im, path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    mode = im.mode
    if mode in ("I;16", "I;16L", "I;16B", "I;16N"):
        grey = np.asarray(im).astype(np.uint16, copy=False)
        return _decode_16bit(np.repeat(grey[..., None], 3, axis=2), None)
    if mode == "I":
        grey = np.asarray(im)
        if grey.min(initial=0) < 0 or grey.max(initial=0) > 65535:
            raise ValueError(f"{path}: 32-bit integer image with values outside 0..65535")
        return _decode_16bit(np.repeat(grey.astype(np.uint16)[..., None], 3, axis=2), None)
    if mode == "F":
        grey = np.asarray(im, dtype=np.float32)
        if not np.all(np.isfinite(grey)):
            raise ValueError(f"{path}: image contains NaN or Inf")
        from relight.colour import srgb_decode

        lin = srgb_decode(grey).astype(np.float32)
        return np.repeat(lin[..., None], 3, axis=2), None
    has_alpha = mode in ("RGBA", "LA", "PA", "La", "RGBa") or (mode == "P" and "transparency" in im.info) \
        or (mode in ("L", "RGB") and "transparency" in im.info)
    rgba = np.asarray(im.convert("RGBA" if has_alpha else "RGB"))
    return decode_srgb_codes(rgba[..., :3]), decode_alpha_codes(rgba[..., 3]) if has_alpha else None


def _decode_16bit(rgb16: np.ndarray, alpha16: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    return decode_srgb_codes(rgb16), decode_alpha_codes(alpha16) if alpha16 is not None else None


# ------------------------------------------------------------------ 16-bit PNG
#
# Why a hand-written decoder (issue 19): Pillow, the core's one image library, opens a 16-bit
# RGB PNG as 8-bit "RGB" (checked with Pillow 11 on a 1024x1024 16-bit file: mode RGB, uint8),
# so the extra 8 bits of a camera export would be lost. The libraries that keep them (imageio
# with a PNG plugin, OpenCV, pypng) are not dependencies of the core, and the Blender add-on
# bundles every binary dependency once per platform (blender_addon/build.py); this decoder is
# numpy + zlib only and reads that 1 MP file in 166 ms (2 loaded cores). It handles only
# non-interlaced 16-bit RGB/RGBA and returns None otherwise (Pillow decodes the rest); its
# sizes are checked against max_pixels and the file's length before anything is allocated.

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _read_png16(path: Path, max_pixels: int | None = None):
    """(rgb uint16 [H, W, 3], alpha uint16 [H, W] | None) of a non-interlaced 16-bit
    RGB/RGBA PNG, or None for anything else (then Pillow decodes it)."""
    import struct
    import zlib

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
    _check_size(width, height, path, max_pixels, len(data), "PNG")
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


# ------------------------------------------------------------------ EXR


def _pick_rgb(channels: dict[str, np.ndarray], path: Path):
    """Choose the colour channels: plain R,G,B; else one "<prefix>.R/G/B" set (Combined first)."""
    for prefix in ("", *sorted({k.rsplit(".", 1)[0] + "." for k in channels if "." in k},
                               key=lambda p: (not p.endswith("Combined."), p))):
        if all(prefix + c in channels for c in "RGB"):
            return [channels[prefix + c] for c in "RGB"], channels.get(prefix + "A")
        if prefix + "Y" in channels and not any(prefix + c in channels for c in "RGB"):
            y = channels[prefix + "Y"]
            return [y, y, y], channels.get(prefix + "A")
    raise ValueError(f"{path}: EXR has no R, G, B (or Y) channels (has {sorted(channels)[:8]})")


def _read_exr_photo(path: Path, max_pixels: int | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    from relight.exr import exr_size, read_exr

    width, height = exr_size(path)
    # an EXR's header can declare what its (zip-compressed) data cannot hold: same weighing as PNG
    _check_size(width, height, path, max_pixels, path.stat().st_size, "EXR")
    with _decoder_errors(path, "corrupt EXR"):
        try:
            channels = read_exr(path)
        except FileNotFoundError:
            raise ValueError(f"{path}: file not found") from None
    rgb, alpha = _pick_rgb(channels, path)
    shapes = {c.shape for c in rgb} | ({alpha.shape} if alpha is not None else set())
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"{path}: EXR colour channels have different sizes {sorted(shapes)}")
    h, w = rgb[0].shape
    _check_size(w, h, path, max_pixels)
    img = np.empty((h, w, 3), np.float32)
    for i, c in enumerate(rgb):
        if c.dtype == np.uint32:
            raise ValueError(f"{path}: EXR colour channels must be half or float, not uint")
        img[..., i] = c
    if not np.all(np.isfinite(img)):
        raise ValueError(f"{path}: EXR contains NaN or Inf pixels")
    np.maximum(img, 0.0, out=img)  # negative radiance is not light: clamp
    mask = None
    if alpha is not None:
        mask = np.asarray(alpha, dtype=np.float32)
        if not np.all(np.isfinite(mask)):
            raise ValueError(f"{path}: EXR alpha contains NaN or Inf")
        mask = np.clip(mask, 0.0, 1.0)
    return img, mask


# ------------------------------------------------------------------ masks


def read_mask(path: str | os.PathLike, shape: tuple[int, int], max_pixels: int | None = None) -> np.ndarray:
    """Read a person mask for a photo of `shape` (H, W): float32 [H, W] in [0, 1].

    A file with an alpha channel gives its alpha; otherwise its grey level as
    stored (code value / max; linear value for EXR): white = person. Refuses
    a size mismatch and an all-zero mask.
    """
    path = Path(path)
    check_max_pixels(max_pixels)
    _exists(path)
    with open(path, "rb") as f:
        is_exr = f.read(4) == EXR_MAGIC
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # as in read_photo: no stray stderr lines
        if is_exr:
            img, alpha = _read_exr_photo(path, max_pixels)
            mask = alpha if alpha is not None else np.clip(img.mean(axis=2), 0.0, 1.0)
        else:
            mask = _read_pillow_mask(path, max_pixels)
    if mask.shape != tuple(shape):
        raise ValueError(f"{path}: mask is {mask.shape[1]}x{mask.shape[0]} but the photo is "
                         f"{shape[1]}x{shape[0]}")
    if not np.any(mask > 0):
        raise ValueError(f"{path}: mask is empty (all zero): it marks no person")
    return mask


def _read_pillow_mask(path: Path, max_pixels: int | None = None) -> np.ndarray:
    from PIL import ImageOps

    im = _open_pillow(path)
    try:
        with _decoder_errors(path, "corrupt or truncated mask image"):
            _check_size(*im.size, path, max_pixels, path.stat().st_size, im.format)
            if im.format == "PNG":
                _check_png_chunks(path)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                im.load()
                im = ImageOps.exif_transpose(im)
                if im.mode in ("I;16", "I;16L", "I;16B", "I;16N", "I"):
                    return np.clip(np.asarray(im, dtype=np.float32) / 65535.0, 0.0, 1.0)
                if im.mode == "F":
                    return np.clip(np.nan_to_num(np.asarray(im, dtype=np.float32), nan=0.0), 0.0, 1.0)
                if "A" in im.mode or "transparency" in im.info:
                    return decode_alpha_codes(np.asarray(im.convert("RGBA"))[..., 3])
                return decode_alpha_codes(np.asarray(im.convert("L")))  # grey as stored: white = person
    finally:
        im.close()


# ------------------------------------------------------------------ writing


def _check_image(image: np.ndarray, name: str = "image") -> np.ndarray:
    a = np.asarray(image)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"{name} must have shape [H, W, 3], got {a.shape}")
    if not np.issubdtype(a.dtype, np.floating):
        raise ValueError(f"{name} must be floating point (linear), got {a.dtype}")
    return a


def _out_dir(path: Path) -> None:
    if not path.parent.is_dir():
        raise ValueError(f"output folder does not exist: {path.parent}")


def write_png(path: str | os.PathLike, linear: np.ndarray, metadata: dict[str, str] | None = None) -> Path:
    """Write linear RGB as an 8-bit sRGB PNG (values clipped to [0, 1]), atomically;
    `metadata` goes into tEXt chunks."""
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    path = Path(path)
    _out_dir(path)
    a = _check_image(linear)
    h, w = a.shape[:2]
    u8 = np.empty((h, w, 3), np.uint8)
    for r0 in range(0, h, STRIP_ROWS):
        strip = a[r0:r0 + STRIP_ROWS]
        if not np.all(np.isfinite(strip)):
            raise ValueError("image to write contains NaN or Inf")
        u8[r0:r0 + STRIP_ROWS] = np.rint(srgb_encode(strip.astype(np.float32, copy=False)) * 255.0)
    info = PngInfo()
    for key, value in (metadata or {}).items():
        info.add_text(key, value)
    with atomic_path(path, ".png") as tmp:
        Image.fromarray(u8, "RGB").save(tmp, format="PNG", compress_level=4, pnginfo=info)
    return path


def _rgb_channels(prefix: str, image: np.ndarray) -> dict[str, np.ndarray]:
    if not np.all(np.isfinite(image)):
        raise ValueError(f"{prefix or 'image'} to write contains NaN or Inf")
    return {f"{prefix}{c}": np.ascontiguousarray(image[..., i], dtype=np.float32) for i, c in enumerate("RGB")}


def write_exr_image(path: str | os.PathLike, linear: np.ndarray, alpha: np.ndarray | None = None,
                    metadata: dict[str, str] | None = None) -> Path:
    """Write linear RGB (+ optional A) as a float32 EXR, atomically; `metadata`: header strings."""
    from relight.exr import write_exr

    path = Path(path)
    _out_dir(path)
    a = _check_image(linear)
    channels = _rgb_channels("", a)
    if alpha is not None:
        channels["A"] = np.ascontiguousarray(alpha, dtype=np.float32)
    return write_exr(path, channels, attributes=metadata)


def write_layers_exr(path: str | os.PathLike, relit: np.ndarray, layers: dict[str, np.ndarray],
                     metadata: dict[str, str] | None = None) -> Path:
    """Multi-layer EXR for Blender: render layer `Relight` with passes Relit (RGBA),
    Albedo, Shading, Residual (RGB) and Alpha (A).

    Channel names are "Relight.<Pass>.<channel>", the naming Blender writes
    and reads back as one render layer whose passes its Image node lists.
    `layers` is Decomposition.layers(): albedo, shading, residual [H, W, 3]
    and alpha [H, W].
    """
    from relight.exr import write_exr

    path = Path(path)
    _out_dir(path)
    relit = _check_image(relit, "relit")
    alpha = np.asarray(layers["alpha"], dtype=np.float32)
    if alpha.shape != relit.shape[:2]:
        raise ValueError(f"alpha layer is {alpha.shape}, relit image is {relit.shape[:2]}")
    channels = _rgb_channels(f"{LAYER_NAME}.Relit.", relit)
    # the relit frame is the whole photo (person composited over it): opaque
    channels[f"{LAYER_NAME}.Relit.A"] = np.ones(relit.shape[:2], np.float32)
    for key, pass_name in (("albedo", "Albedo"), ("shading", "Shading"), ("residual", "Residual")):
        img = _check_image(layers[key], key)
        if img.shape != relit.shape:
            raise ValueError(f"{key} layer is {img.shape}, relit image is {relit.shape}")
        channels.update(_rgb_channels(f"{LAYER_NAME}.{pass_name}.", img))
    channels[f"{LAYER_NAME}.Alpha.A"] = np.ascontiguousarray(alpha)
    return write_exr(path, channels, attributes=metadata)


def write_image(path: str | os.PathLike, linear: np.ndarray, metadata: dict[str, str] | None = None) -> Path:
    """Write by extension: .png (8-bit sRGB) or .exr (linear float); `metadata`: PNG text /
    EXR header strings."""
    suffix = Path(path).suffix.lower()
    if suffix == ".png":
        return write_png(path, linear, metadata)
    if suffix == ".exr":
        return write_exr_image(path, linear, metadata=metadata)
    raise ValueError(f"output must end in .png or .exr, got {Path(path).name}")
