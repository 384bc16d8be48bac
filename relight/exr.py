"""OpenEXR read/write (OpenEXR >= 3.3 Python API), all parts, atomic writes."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from relight.fileio import atomic_path

__all__ = ["read_exr", "write_exr"]

_COMPRESSIONS = ("zip", "zips", "piz", "none", "rle", "pxr24")


def _openexr():
    import OpenEXR  # imported lazily: only I/O needs it

    return OpenEXR


def read_exr(path) -> dict[str, np.ndarray]:
    """Every channel of every part, as {name: [H, W] array}.

    Half and float channels come back as float32, uint as uint32. In a
    multi-part file (Blender 5 writes one part per pass, e.g.
    "ViewLayer.Combined") a channel is named "<part>.<channel>" unless its
    name already starts with the part name. Raises FileNotFoundError for a
    missing file and ValueError for one that is not a readable EXR.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"EXR file not found: {path}")
    OpenEXR = _openexr()
    try:
        f = OpenEXR.File(str(path), separate_channels=True)
        parts = list(f.parts)
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
                    raise ValueError(f"EXR {path} has two channels named {key!r}")
                pixels = np.asarray(channel.pixels)
                if pixels.dtype != np.uint32:
                    pixels = pixels.astype(np.float32, copy=False)
                channels[key] = pixels
    except ValueError:
        raise
    except Exception as exc:  # OpenEXR raises RuntimeError/others for corrupt data
        raise ValueError(f"cannot read EXR {path}: {exc}") from None
    if not channels:
        raise ValueError(f"EXR {path} has no channels")
    return channels


def write_exr(
    path,
    channels: dict[str, np.ndarray],
    *,
    compression: str = "zip",
    half: bool = False,
) -> Path:
    """Write a single-part scanline EXR atomically (temp file + os.replace).

    `channels` maps names to [H, W] arrays of one common shape; floats are
    stored as float32 (or float16 when `half`), uint32 stays uint32.
    """
    path = Path(path)
    if compression not in _COMPRESSIONS:
        raise ValueError(f"EXR compression must be one of {_COMPRESSIONS}, got {compression!r}")
    if not isinstance(channels, dict) or not channels:
        raise ValueError("EXR needs at least one channel")
    shape = None
    prepared = {}
    for name, arr in channels.items():
        if not isinstance(name, str) or not name:
            raise ValueError(f"EXR channel names must be non-empty strings, got {name!r}")
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
    OpenEXR = _openexr()
    codes = {
        "zip": OpenEXR.ZIP_COMPRESSION,
        "zips": OpenEXR.ZIPS_COMPRESSION,
        "piz": OpenEXR.PIZ_COMPRESSION,
        "none": OpenEXR.NO_COMPRESSION,
        "rle": OpenEXR.RLE_COMPRESSION,
        "pxr24": OpenEXR.PXR24_COMPRESSION,
    }
    header = {"compression": codes[compression], "type": OpenEXR.scanlineimage}
    if not path.parent.is_dir():
        raise FileNotFoundError(f"output folder does not exist: {path.parent}")
    with atomic_path(path, ".exr") as tmp:
        with OpenEXR.File(header, prepared) as f:
            f.write(str(tmp))
    return path
