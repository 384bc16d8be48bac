"""OpenEXR read/write (OpenEXR >= 3.3 Python API), all parts, atomic writes.

Nothing here touches the process's file descriptors or sys.stdout/sys.stderr
(inside Blender they are everyone's): a file is refused for its framing by
relight.files.exr_layout before the library sees it, since the library would
print about a damaged file on stderr and stdout. Damage the framing cannot show
(inside a chunk's compressed data) is found by the library while it decodes: it
prints its own message, and the read still ends in one ValueError of ours.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from relight.files import exr_zip
from relight.files.exr_layout import read_layout
from relight.files.fileio import atomic_path

__all__ = ["read_exr", "write_exr", "write_exr_bands", "exr_size"]

_COMPRESSIONS = ("zip", "zips", "piz", "none", "rle", "pxr24")
_LIBRARY_NAMES = {name: ("NO" if name == "none" else name.upper()) + "_COMPRESSION" for name in _COMPRESSIONS}
_NAME_BYTES = 255  # the longest channel or attribute name the format allows
# the header's own fields: not for `attributes`
_RESERVED = {"channels", "compression", "dataWindow", "displayWindow", "lineOrder", "pixelAspectRatio",
             "screenWindowCenter", "screenWindowWidth", "type", "tiles", "chunkCount", "name", "version"}


def _openexr():
    import OpenEXR  # imported lazily: only I/O needs it

    return OpenEXR


def exr_size(path) -> tuple[int, int]:
    """(width, height) of the largest data window over all parts, from the headers only
    (read by exr_layout; the library is not called). ValueError for a damaged header."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"EXR file not found: {path}")
    sizes = [part.size for part in read_layout(path, chunks=False)]
    return max(w for w, _ in sizes), max(h for _, h in sizes)


def read_exr(path, parts: Sequence | None = None) -> dict[str, np.ndarray]:
    """Every channel of every part, as {name: [H, W] array}. `parts`: the file's layout when the
    caller read it already (exr_layout.read_layout with its chunks checked), not read again.

    Half and float channels come back as float32, uint as uint32. In a
    multi-part file (Blender 5 writes one part per pass, e.g.
    "ViewLayer.Combined") a channel is named "<part>.<channel>" unless its
    name already starts with the part name. Raises FileNotFoundError for a
    missing file and ValueError for one that is not a readable EXR: damaged
    framing (a truncated file), refused before the library reads it, or damaged
    pixel data the library could not decode (a part it skipped).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"EXR file not found: {path}")
    if parts is None:
        parts = read_layout(path)
    channels, failure = _read_channels(_openexr(), path, len(parts))
    if failure is not None:
        raise ValueError(failure)
    if not channels:
        raise ValueError(f"EXR {path} has no channels")
    return channels


def _read_channels(OpenEXR, path: Path, expected_parts: int) -> tuple[dict[str, np.ndarray], str | None]:
    """(channels, None) or ({}, one-line reason)."""
    channels: dict[str, np.ndarray] = {}
    try:
        f = OpenEXR.File(str(path), separate_channels=True)
        parts = list(f.parts)
        if len(parts) != expected_parts:  # the binding skips a part it could not decode (and says so itself)
            return {}, f"cannot read EXR {path}: damaged pixel data in {expected_parts - len(parts)} part(s)"
        channels: dict[str, np.ndarray] = {}
        for part in parts:
            part_name = part.name() if callable(part.name) else part.name
            prefix = part_name if len(parts) > 1 and part_name else ""
            for name, channel in part.channels.items():
                if prefix and not name.startswith(prefix + "."):
                    key = f"{prefix}.{name}"
                else:
                    key = name
                if key in channels:
                    return {}, f"EXR {path} has two channels named {key!r}"
                pixels = np.asarray(channel.pixels)
                if pixels.dtype != np.uint32:
                    pixels = pixels.astype(np.float32, copy=False)
                channels[key] = pixels
    except Exception as exc:  # OpenEXR raises RuntimeError/others for corrupt data
        if isinstance(exc, MemoryError):
            raise
        said = str(exc).strip().splitlines()
        return {}, f"cannot read EXR {path}: {said[0] if said else type(exc).__name__}"
    return channels, None


def write_exr(
    path,
    channels: dict[str, np.ndarray],
    *,
    compression: str = "zip",
    half: bool = False,
    attributes: dict[str, str] | None = None,
) -> Path:
    """Write a single-part scanline EXR atomically (temp file + os.replace).

    `channels` maps names to [H, W] arrays of one common shape; floats are
    stored as float32 (or float16 when `half`), uint32 stays uint32.
    `attributes`: string attributes added to the header (e.g. what made the image).
    ZIP files of float channels are written by relight.files.exr_zip when ISA-L
    is installed (a third of the CPU), others by the OpenEXR library.
    """
    path = Path(path)
    if compression not in _COMPRESSIONS:
        raise ValueError(f"EXR compression must be one of {_COMPRESSIONS}, got {compression!r}")
    if not isinstance(channels, dict) or not channels:
        raise ValueError("EXR needs at least one channel")
    shape = None
    prepared = {}
    for name, arr in channels.items():
        if not isinstance(name, str) or not name or "\0" in name or len(name.encode()) > _NAME_BYTES:
            raise ValueError(f"EXR channel names must be non-empty strings of at most {_NAME_BYTES} bytes, "
                             f"got {name!r}")
        a = np.asarray(arr)
        if a.ndim != 2 or a.shape[0] < 1 or a.shape[1] < 1:
            raise ValueError(f"EXR channel {name!r} must be a 2D [H, W] array, got shape {a.shape}")
        if shape is None:
            shape = a.shape
        elif a.shape != shape:
            raise ValueError(f"EXR channel {name!r} has shape {a.shape}, others have {shape}")
        if a.dtype == np.uint32:
            prepared[name] = np.ascontiguousarray(a)
        elif np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer):
            prepared[name] = np.ascontiguousarray(a, dtype=np.float16 if half else np.float32)
        else:
            raise ValueError(f"EXR channel {name!r} has unsupported dtype {a.dtype}")
    attributes = _checked_attributes(attributes, _RESERVED)
    if not path.parent.is_dir():
        raise FileNotFoundError(f"output folder does not exist: {path.parent}")
    if compression == "zip" and exr_zip.available() and all(a.dtype != np.uint32 for a in prepared.values()):
        names, rows = list(prepared), exr_zip.TASK_LINES
        bands = (np.stack([prepared[n][y:y + rows] for n in names], axis=-1) for y in range(0, shape[0], rows))
        return _write_zip(path, names, *shape, bands, half, attributes)
    OpenEXR = _openexr()
    header = {"compression": getattr(OpenEXR, _LIBRARY_NAMES[compression]), "type": OpenEXR.scanlineimage}
    header.update(attributes)
    with atomic_path(path, ".exr") as tmp:
        try:
            with OpenEXR.File(header, prepared) as f:
                f.write(str(tmp))
            failure = None
        except Exception as exc:  # RuntimeError from the library, e.g. a full disk (it prints nothing)
            if isinstance(exc, MemoryError):
                raise
            failure = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        if failure is not None:
            raise OSError(f"cannot write EXR {path}: {failure}")
    return path


def _checked_attributes(attributes: dict[str, str] | None, reserved) -> dict[str, str]:
    for key, value in (attributes or {}).items():
        if not isinstance(key, str) or not key or key in reserved or "\0" in key or len(key.encode()) > _NAME_BYTES \
                or not isinstance(value, str) or "\0" in value:
            raise ValueError(f"EXR attributes must map new names to strings, got {key!r}: {type(value).__name__}")
    return dict(attributes or {})


def write_exr_bands(
    path,
    names: Sequence[str],
    height: int,
    width: int,
    bands: Iterable[np.ndarray],
    *,
    compression: str = "zip",
    half: bool = False,
    attributes: dict[str, str] | None = None,
) -> Path:
    """Write a single-part scanline EXR from bands of rows, atomically (temp file + os.replace).

    `bands` yields float arrays [rows, width, len(names)], top band first; channel c
    of every band is stored as `names[c]`. Bands may have any number of rows >= 1
    (they need not match the compression's chunk of 16 lines) and must add up to
    `height`. A few bands are held at a time, so a many-layer image is written
    without holding the layers whole: bands are compressed and written as they
    are drawn (at most one band by the library's writer; at most
    (exr_zip.IN_FLIGHT * threads + 1) * exr_zip.TASK_LINES rows by exr_zip's). Floats are stored as float32 (float16 when `half`), as
    write_exr stores them; `attributes` are string attributes added to the header.

    Nothing is left at `path` (an older file there is kept) when a band is wrong
    (shape, dtype, too many or too few rows), the disk fails (OSError), or `bands`
    itself raises, which is how a caller cancels a write: the exception propagates.

    ZIP is written by relight.files.exr_zip when ISA-L is installed (bands packed
    on threads, the GIL released), else by the OpenEXR module's OutputFile, which
    keeps the GIL while it compresses a band: from a worker thread, bands of a few
    dozen rows keep every stretch the main thread waits short.
    """
    path = Path(path)
    if compression not in _COMPRESSIONS:
        raise ValueError(f"EXR compression must be one of {_COMPRESSIONS}, got {compression!r}")
    names = list(names)
    if not names or len(set(names)) < len(names) or any(
            not isinstance(n, str) or not n or "\0" in n or len(n.encode()) > _NAME_BYTES for n in names):
        raise ValueError(f"EXR channel names must be distinct non-empty strings of at most {_NAME_BYTES} bytes, "
                         f"got {names!r}")
    if any(isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1 for n in (height, width)):
        raise ValueError(f"EXR size must be positive integers, got {height!r} x {width!r}")
    height, width = int(height), int(width)
    attributes = _checked_attributes(attributes, _RESERVED)
    if not path.parent.is_dir():
        raise FileNotFoundError(f"output folder does not exist: {path.parent}")
    checked = _checked_bands(bands, path.name, height, width, len(names))
    if compression == "zip" and exr_zip.available():
        return _write_zip(path, names, height, width, checked, half, attributes)
    import Imath  # shipped with the OpenEXR module

    OpenEXR = _openexr()
    header = OpenEXR.Header(width, height)
    pixel = Imath.PixelType(Imath.PixelType.HALF if half else Imath.PixelType.FLOAT)
    header["channels"] = {name: Imath.Channel(pixel) for name in names}
    header["compression"] = Imath.Compression(getattr(Imath.Compression, _LIBRARY_NAMES[compression]))
    for key, value in attributes.items():
        header[key] = value.encode("utf-8")  # this writer stores bytes as a string attribute
    dtype = np.float16 if half else np.float32
    with atomic_path(path, ".exr") as tmp:
        try:
            out = OpenEXR.OutputFile(str(tmp), header)
        except OSError as exc:
            raise OSError(f"cannot write EXR {path}: {exc}") from None
        try:
            for band in checked:
                planes = {name: np.ascontiguousarray(band[..., c], dtype=dtype) for c, name in enumerate(names)}
                try:
                    out.writePixels(planes, band.shape[0])
                except OSError as exc:
                    raise OSError(f"cannot write EXR {path}: {exc}") from None
        finally:
            out.close()
    return path


def _checked_bands(bands: Iterable[np.ndarray], name: str, height: int, width: int, channels: int):
    """The bands, each checked as it is drawn; ValueError when one is wrong or their rows are
    not `height` (raised when they run out)."""
    done = 0
    for band in bands:
        band = np.asarray(band)
        rows = band.shape[0] if band.ndim == 3 else 0
        if band.ndim != 3 or rows < 1 or band.shape[1:] != (width, channels):
            raise ValueError(f"EXR band for {name} must be [rows, {width}, {channels}], got {band.shape}")
        if not np.issubdtype(band.dtype, np.floating):
            raise ValueError(f"EXR band for {name} must hold floats, got {band.dtype}")
        if done + rows > height:
            raise ValueError(f"EXR bands for {name} hold more than its {height} rows")
        done += rows
        yield band
        del band  # held no longer than the writer holds it
    if done != height:
        raise ValueError(f"EXR bands for {name} hold {done} of its {height} rows")


def _write_zip(path: Path, names: list[str], height: int, width: int, bands, half: bool,
               attributes: dict[str, str]) -> Path:
    with atomic_path(path, ".exr") as tmp, open(tmp, "wb") as f:  # an OS error is named by atomic_path
        exr_zip.write_zip_exr(f, names, height, width, bands, half=half, attributes=attributes)
    return path
