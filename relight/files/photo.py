"""Photo files <-> linear float32 arrays.

Reads PNG/JPEG/TIFF/WebP (sRGB-encoded; EXIF orientation applied; 8- and
16-bit; grey expanded to RGB; an alpha channel comes back as the mask) and
EXR (linear). Writes 8-bit sRGB PNG, linear EXR, and a multi-layer EXR whose
channels follow Blender's "<layer>.<pass>.<channel>" naming so its Image node
shows every pass. The header is read once, by relight.files.photo_header (size,
format, orientation), and the declared size weighed before any pixel is decoded
(relight.files.image_limits: a pixel limit, the file's size, the memory free);
16-bit colour PNGs, which Pillow cuts to 8 bits, go through relight.files.png_decoder.
Every failure to read is one ValueError (an ImageFileError when the file is at fault).
Writes are atomic.
"""

from __future__ import annotations

import os
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from relight.imaging.colour import decode_alpha_codes, decode_srgb_codes
from relight.files.fileio import atomic_path
from relight.files.image_limits import check_declared_size
from relight.files.photo_header import EXR_MAGIC, ImageDamaged, PhotoHeader, open_photo, read_header
from relight.files.png_decoder import read_png16

__all__ = ["read_photo", "read_photo_with_header", "read_mask", "exif_orientation", "upright", "as_stored",
           "write_image", "write_png", "write_exr_image", "write_layers_exr", "EXR_MAGIC", "LAYER_NAME",
           "PHOTO_SUFFIXES"]

LAYER_NAME = "Relight"       # render-layer name in multi-layer EXRs
# lossless; on a relit photo's float32 values (not the 256 levels of a decoded JPEG) ZIP is smaller
# and cheaper than PIZ, RLE and ZIPS (docs/BENCHMARKS.md, "Writing the output")
EXR_COMPRESSION = "zip"
PHOTO_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".webp", ".bmp", ".exr")


def read_photo(path: str | os.PathLike, max_pixels: int | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Read a photo as (linear float32 [H, W, 3], mask float32 [H, W] in [0, 1] or None).

    The mask is the file's alpha channel when it has one. `max_pixels`
    (default DEFAULT_MAX_PIXELS, at most MAX_PIXELS) bounds the declared size;
    see check_declared_size.
    """
    rgb, alpha, _ = read_photo_with_header(path, max_pixels)
    return rgb, alpha


def read_photo_with_header(path: str | os.PathLike, max_pixels: int | None = None, *,
                           weigh_file_size: bool | None = None) -> tuple[np.ndarray, np.ndarray | None, PhotoHeader]:
    """read_photo's (rgb, mask), upright, and the file's header (relight.files.photo_header: its
    size as stored, format, EXIF orientation, focal length), from one read of the header.
    `weigh_file_size`: check_declared_size's (by default: only without `max_pixels`)."""
    with warnings.catch_warnings():
        # Pillow's warnings (corrupt EXIF, tags past the end, bomb sizes: our check spoke first)
        # would be stray stderr lines; the photo decodes or fails with one ValueError
        warnings.simplefilter("ignore")
        with open_photo(path, max_pixels, weigh_file_size=weigh_file_size) as (header, im):
            if im is None:
                rgb, alpha = _read_exr_photo(header.path, max_pixels)
            else:
                rgb, alpha = _read_pillow_photo(im, header, max_pixels)
    return rgb, alpha, header


# ------------------------------------------------------------------ Pillow


@contextmanager
def _decoder_errors(path: Path, what: str):
    """Whatever a decoder raises (truncated data, library errors) becomes
    ImageDamaged("PATH: WHAT (Type: message)"); our own ValueErrors, already worded,
    and MemoryError pass unchanged."""
    try:
        yield
    except (ValueError, MemoryError):
        raise
    except Exception as exc:
        raise ImageDamaged(path, f"{path}: {what} ({type(exc).__name__}: {exc})") from None


def _read_pillow_photo(im, header: PhotoHeader, max_pixels: int | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """The photo Pillow opened (open_photo: its size weighed, a PNG's chunks checked), decoded upright."""
    path = header.path
    with _decoder_errors(path, "corrupt or truncated image"):
        if getattr(im, "n_frames", 1) > 1:
            im.seek(0)  # animated/multi-page files: the first frame is the photo
        rawmode = im.tile[0][3] if im.tile and len(im.tile[0]) > 3 else ""
        if isinstance(rawmode, tuple):
            rawmode = rawmode[0]
        if im.format == "PNG" and im.mode in ("RGB", "RGBA") and str(rawmode).endswith(";16B"):
            # Pillow keeps only 8 bits of 16-bit colour PNGs: decode those ourselves
            decoded = read_png16(path, max_pixels)
            if decoded is not None:
                rgb, alpha = _decode_16bit(*decoded)
                return (np.ascontiguousarray(upright(rgb, header.orientation)),
                        None if alpha is None else np.ascontiguousarray(upright(alpha, header.orientation)))
        im.load()
        return _pillow_to_linear(_upright(im, header.orientation), path)


# Pillow's turn for each EXIF orientation, as PIL.ImageOps.exif_transpose makes it
_TRANSPOSE = {2: "FLIP_LEFT_RIGHT", 3: "ROTATE_180", 4: "FLIP_TOP_BOTTOM", 5: "TRANSPOSE", 6: "ROTATE_270",
              7: "TRANSVERSE", 8: "ROTATE_90"}


def _upright(im, orientation: int):
    """The image turned as its header's EXIF orientation says; itself when it says nothing
    (exif_transpose would copy it, 72 MB at 24 MP, and read the EXIF again)."""
    from PIL import Image

    method = _TRANSPOSE.get(orientation)
    return im if method is None else im.transpose(getattr(Image.Transpose, method))


# The EXIF orientation (1 - 8) is the turn from a file's stored pixels to the upright ones, as
# PIL.ImageOps.exif_transpose makes it; each turn is a numpy view (flips and a transpose of the
# first two axes), so writing upright values into upright(stored) writes the stored image.
_UPRIGHT = {1: lambda s: s, 2: lambda s: s[:, ::-1], 3: lambda s: s[::-1, ::-1], 4: lambda s: s[::-1],
            5: lambda s: s.swapaxes(0, 1), 6: lambda s: s.swapaxes(0, 1)[:, ::-1],
            7: lambda s: s[::-1, ::-1].swapaxes(0, 1), 8: lambda s: s.swapaxes(0, 1)[::-1]}
_INVERSE = {1: 1, 2: 2, 3: 3, 4: 4, 5: 5, 6: 8, 7: 7, 8: 6}  # 6 and 8 turn opposite ways


def upright(stored: np.ndarray, orientation: int) -> np.ndarray:
    """The stored image [H, W, ...] (top row first) turned upright by its EXIF orientation (a
    view; orientations outside 1 - 8 count as 1, as read_photo treats them)."""
    return _UPRIGHT.get(orientation, _UPRIGHT[1])(stored)


def as_stored(upright_image: np.ndarray, orientation: int) -> np.ndarray:
    """The upright image [H, W, ...] turned back to how its file stores it (a view): upright's inverse."""
    return _UPRIGHT[_INVERSE.get(orientation, 1)](upright_image)


def exif_orientation(path: str | os.PathLike) -> int:
    """The EXIF orientation (1 - 8) of a photo file, the turn read_photo gives its pixels to stand
    them upright: 1 when it says none (and for EXR). For a caller that shows the file as stored
    (Blender) and must turn read_photo's upright pixels back: its header's
    (relight.files.photo_header.read_header), its size not weighed."""
    return read_header(path, weigh=False).orientation


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
        from relight.imaging.colour import srgb_decode

        lin = srgb_decode(grey).astype(np.float32)
        return np.repeat(lin[..., None], 3, axis=2), None
    has_alpha = mode in ("RGBA", "LA", "PA", "La", "RGBa") or (mode == "P" and "transparency" in im.info) \
        or (mode in ("L", "RGB") and "transparency" in im.info)
    mode = "RGBA" if has_alpha else "RGB"
    rgba = np.asarray(im if im.mode == mode else im.convert(mode))  # convert() to its own mode copies
    return decode_srgb_codes(rgba[..., :3]), decode_alpha_codes(rgba[..., 3]) if has_alpha else None


def _decode_16bit(rgb16: np.ndarray, alpha16: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    return decode_srgb_codes(rgb16), decode_alpha_codes(alpha16) if alpha16 is not None else None


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
    """The EXR whose header open_photo read and weighed, decoded."""
    from relight.files.exr import read_exr

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
    check_declared_size(w, h, path, max_pixels=max_pixels)
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
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # as in read_photo: no stray stderr lines
        with open_photo(path, max_pixels) as (header, im):
            if im is None:
                img, alpha = _read_exr_photo(path, max_pixels)
                mask = alpha if alpha is not None else np.clip(img.mean(axis=2), 0.0, 1.0)
            else:
                mask = _read_pillow_mask(im, header)
    if mask.shape != tuple(shape):
        raise ValueError(f"{path}: mask is {mask.shape[1]}x{mask.shape[0]} but the photo is "
                         f"{shape[1]}x{shape[0]}")
    if not np.any(mask > 0):
        raise ValueError(f"{path}: mask is empty (all zero): it marks no person")
    return mask


def _read_pillow_mask(im, header: PhotoHeader) -> np.ndarray:
    """The mask Pillow opened (open_photo: its size weighed, a PNG's chunks checked), decoded upright."""
    with _decoder_errors(header.path, "corrupt or truncated mask image"):
        im.load()
        im = _upright(im, header.orientation)
        if im.mode in ("I;16", "I;16L", "I;16B", "I;16N", "I"):
            return np.clip(np.asarray(im, dtype=np.float32) / 65535.0, 0.0, 1.0)
        if im.mode == "F":
            return np.clip(np.nan_to_num(np.asarray(im, dtype=np.float32), nan=0.0), 0.0, 1.0)
        if "A" in im.mode or "transparency" in im.info:
            return decode_alpha_codes(np.asarray(im.convert("RGBA"))[..., 3])
        return decode_alpha_codes(np.asarray(im.convert("L")))  # grey as stored: white = person


# ------------------------------------------------------------------ writing


def _check_image(image: np.ndarray, name: str = "image") -> np.ndarray:
    a = np.asarray(image)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"{name} must have shape [H, W, 3], got {a.shape}")
    if not np.issubdtype(a.dtype, np.floating):
        raise ValueError(f"{name} must be floating point (linear), got {a.dtype}")
    return a


@contextmanager
def _output_folder(path: Path):
    """A write into `path`'s folder: when the folder is missing (the command has refused that
    already, at its arguments; a library caller learns it here), the write's FileNotFoundError
    becomes ValueError("output folder does not exist: ..."). No check before the write."""
    try:
        yield
    except FileNotFoundError:
        if path.parent.is_dir():
            raise
        raise ValueError(f"output folder does not exist: {path.parent}") from None


def write_png(path: str | os.PathLike, linear: np.ndarray, metadata: dict[str, str] | None = None) -> Path:
    """Write linear RGB as an 8-bit sRGB PNG (values clipped to [0, 1]), atomically;
    `metadata` goes into text chunks (relight.files.png_encoder: the sRGB curve by table, rows
    deflated in bands on threads)."""
    from relight.files.png_encoder import write_png_file

    path = Path(path)
    a = _check_image(linear)
    with _output_folder(path), atomic_path(path, ".png") as tmp:
        with open(tmp, "wb") as f:
            write_png_file(f, a, metadata)
    return path


def exr_threads() -> None:
    """Let OpenEXR compress (and decompress) a file's blocks on threads: its global pool is
    empty until set (docs/BENCHMARKS.md, "Writing the output"); set once, to the cores
    available (at most 4)."""
    from relight.files.exr import _openexr

    OpenEXR = _openexr()
    if hasattr(OpenEXR, "set_global_thread_count") and OpenEXR.global_thread_count() == 0:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        OpenEXR.set_global_thread_count(min(4, cores))


def _check_finite(image: np.ndarray, name: str) -> None:
    """ValueError on NaN or Inf: min and max carry both (no [H, W, 3] mask allocated)."""
    if image.size and not (np.isfinite(image.min()) and np.isfinite(image.max())):
        raise ValueError(f"{name} to write contains NaN or Inf")


EXR_BAND_ROWS = 64  # rows of the image handed to the EXR writer at a time (views: nothing copied whole)


def write_exr_image(path: str | os.PathLike, linear: np.ndarray, alpha: np.ndarray | None = None,
                    metadata: dict[str, str] | None = None) -> Path:
    """Write linear RGB (+ optional A) as a float32 EXR, atomically; `metadata`: header strings.
    The image goes to the writer in bands of its own rows (relight.files.exr.write_exr_bands):
    no per-channel copy of the whole image is made."""
    from relight.files.exr import write_exr_bands

    path = Path(path)
    a = _check_image(linear)
    _check_finite(a, "image")
    if alpha is not None:
        alpha = np.asarray(alpha, dtype=np.float32)
        if alpha.shape != a.shape[:2]:
            raise ValueError(f"alpha is {alpha.shape}, the image is {a.shape[:2]}")

    def bands():
        for y in range(0, a.shape[0], EXR_BAND_ROWS):
            band = a[y:y + EXR_BAND_ROWS]
            yield band if alpha is None else np.concatenate([band, alpha[y:y + EXR_BAND_ROWS, :, None]], axis=2)

    names = ["R", "G", "B"] + (["A"] if alpha is not None else [])
    exr_threads()
    with _output_folder(path):
        return write_exr_bands(path, names, a.shape[0], a.shape[1], bands(), compression=EXR_COMPRESSION,
                               attributes=metadata)


def write_layers_exr(path: str | os.PathLike, relit: np.ndarray, layers: dict[str, np.ndarray],
                     metadata: dict[str, str] | None = None) -> Path:
    """Multi-layer EXR for Blender: render layer `Relight` with passes Relit (RGBA),
    Albedo, Shading, Residual (RGB) and Alpha (A).

    Channel names are "Relight.<Pass>.<channel>", the naming Blender writes
    and reads back as one render layer whose passes its Image node lists.
    `layers` is Decomposition.layers(): albedo, shading, residual [H, W, 3]
    and alpha [H, W]. They go to the writer in bands of their rows (no copy of
    a whole layer).
    """
    from relight.files.exr import write_exr_bands

    path = Path(path)
    relit = _check_image(relit, "relit")
    _check_finite(relit, "relit")
    alpha = np.asarray(layers["alpha"], dtype=np.float32)
    if alpha.shape != relit.shape[:2]:
        raise ValueError(f"alpha layer is {alpha.shape}, relit image is {relit.shape[:2]}")
    passes = [(relit, "Relit")]
    for key, pass_name in (("albedo", "Albedo"), ("shading", "Shading"), ("residual", "Residual")):
        img = _check_image(layers[key], key)
        if img.shape != relit.shape:
            raise ValueError(f"{key} layer is {img.shape}, relit image is {relit.shape}")
        _check_finite(img, key)
        passes.append((img, pass_name))
    # the relit frame is the whole photo (person composited over it): opaque
    names = [f"{LAYER_NAME}.Relit.{c}" for c in "RGBA"] + [
        f"{LAYER_NAME}.{pass_name}.{c}" for _, pass_name in passes[1:] for c in "RGB"] + [f"{LAYER_NAME}.Alpha.A"]

    def bands():  # the passes side by side, EXR_BAND_ROWS rows at a time: no whole-image copy of any
        for y in range(0, relit.shape[0], EXR_BAND_ROWS):
            rows = slice(y, y + EXR_BAND_ROWS)
            band = [relit[rows], np.ones((*relit[rows].shape[:2], 1), np.float32)]
            band += [img[rows] for img, _ in passes[1:]] + [alpha[rows, :, None]]
            yield np.concatenate(band, axis=2, dtype=np.float32)

    exr_threads()
    with _output_folder(path):
        return write_exr_bands(path, names, relit.shape[0], relit.shape[1], bands(), compression=EXR_COMPRESSION,
                               attributes=metadata)


def write_image(path: str | os.PathLike, linear: np.ndarray, metadata: dict[str, str] | None = None) -> Path:
    """Write by extension: .png (8-bit sRGB) or .exr (linear float); `metadata`: PNG text /
    EXR header strings."""
    suffix = Path(path).suffix.lower()
    if suffix == ".png":
        return write_png(path, linear, metadata)
    if suffix == ".exr":
        return write_exr_image(path, linear, metadata=metadata)
    raise ValueError(f"output must end in .png or .exr, got {Path(path).name}")
