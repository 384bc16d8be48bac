"""Equirectangular HDR maps: load (OpenEXR or Radiance .hdr) and validate.

Turning a map into SH light (project, rotate, normalize) is relight.lighting.light's job."""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np


__all__ = ["EnvMap", "validate_equirect", "load_equirect", "read_radiance_hdr", "MAX_MAP_PIXELS"]

log = logging.getLogger(__name__)

MAX_MAP_PIXELS = 16384 * 8192  # a "16k" equirect map; SH lighting needs far less (order 4: 64 x 32)
MAP_BYTES_PER_PIXEL = 48       # peak while loading and projecting: RGBE, float32 copies, float32 strips
_HDR_STRIP_ROWS = 256          # rows converted from RGBE to float at a time


def _check_map_size(width: int, height: int, source, file_bytes: int | None = None) -> None:
    """Refuse a declared map size before anything is allocated for it."""
    from relight.files.image_limits import memory_available

    if width < 1 or height < 1:
        raise ValueError(f"{source}: empty map {width}x{height}")
    if width * height > MAX_MAP_PIXELS:
        raise ValueError(f"{source}: map is {width}x{height}, over the limit of {MAX_MAP_PIXELS:,} pixels "
                         "(16384x8192); SH lighting needs far less: downsample it")
    free = memory_available()
    need = width * height * MAP_BYTES_PER_PIXEL
    if free is not None and need > free:
        raise ValueError(f"{source}: a {width}x{height} map needs about {need / 2**30:.1f} GiB, "
                         f"only {free / 2**30:.1f} GiB of memory is free")


@dataclass(frozen=True)
class EnvMap:
    """A validated equirect map: linear RGB float32 [H, W, 3], H * 2 == W."""

    pixels: np.ndarray
    negatives_clamped: int  # texel channels < 0 that were set to 0
    source: str

    @property
    def shape(self) -> tuple[int, int]:
        return self.pixels.shape[:2]


def validate_equirect(pixels, source: str = "array") -> EnvMap:
    """Check an equirect map and clamp negative texels to zero (counted and logged).

    ValueError for: rank other than 3, channel count other than 3 or 4 (alpha
    is dropped), width != 2 * height, NaN or Inf texels.
    """
    a = np.asarray(pixels)
    if a.ndim != 3:
        raise ValueError(f"{source}: equirect map must be [H, W, 3|4], got rank {a.ndim} (shape {a.shape})")
    if a.shape[2] not in (3, 4):
        raise ValueError(f"{source}: equirect map must have 3 or 4 channels, got {a.shape[2]}")
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise ValueError(f"{source}: equirect map must be numeric, got dtype {a.dtype}")
    h, w = a.shape[:2]
    if h < 1 or w != 2 * h:
        raise ValueError(f"{source}: equirect map must be 2:1 (width = 2 * height), got {w}x{h}")
    bad = ~np.isfinite(a[..., :3])
    if bad.any():
        raise ValueError(f"{source}: equirect map has {int(bad.sum())} NaN or Inf texel values")
    with np.errstate(over="ignore"):
        rgb = np.array(a[..., :3], dtype=np.float32)
    if not np.all(np.isfinite(rgb)):
        raise ValueError(f"{source}: equirect map has values beyond float32 range")
    negative = rgb < 0
    count = int(negative.sum())
    if count:
        rgb[negative] = 0.0
        log.info("%s: clamped %d negative texel values to zero", source, count)
    rgb.flags.writeable = False
    return EnvMap(pixels=rgb, negatives_clamped=count, source=source)


def _rgb_from_exr_channels(channels: dict, source: str) -> np.ndarray:
    """Pick the R, G, B (optionally A) planes; in multi-part files prefer the
    unprefixed layer, then one named '...Combined'."""
    groups: dict[str, dict[str, np.ndarray]] = {}
    for name, plane in channels.items():
        prefix, _, last = name.rpartition(".")
        groups.setdefault(prefix, {})[last] = plane
    rgb_groups = [p for p, g in groups.items() if {"R", "G", "B"} <= set(g)]
    if not rgb_groups:
        raise ValueError(
            f"{source}: EXR has no R, G, B channels (channels: {sorted(channels)[:8]})"
        )
    if len(rgb_groups) > 1:
        preferred = [p for p in rgb_groups if p == ""] or [p for p in rgb_groups if p.endswith("Combined")]
        if len(preferred) != 1:
            raise ValueError(f"{source}: EXR has several RGB layers {sorted(rgb_groups)}; cannot choose")
        rgb_groups = preferred
    g = groups[rgb_groups[0]]
    return np.stack([g["R"], g["G"], g["B"]], axis=-1)


_RESOLUTION_RE = re.compile(rb"^-Y (\d+) \+X (\d+)$")
_RLE_RUN = 127  # most pixels one two-byte run of the RLE scheme can cover


def _min_scanline_bytes(width: int) -> int:
    """Fewest bytes one scanline of `width` texels can take: flat 4 per texel, or
    new-style RLE with 4 header bytes and at least one 2-byte run per 127 texels
    of each of the 4 components."""
    flat = 4 * width
    if 8 <= width < 32768:
        return min(flat, 4 + 4 * 2 * -(-width // _RLE_RUN))
    return flat


# Why a hand-written Radiance reader (issue 19): neither OpenEXR nor Pillow (the core's image
# libraries) reads .hdr; imageio needs a FreeImage binary for it and OpenCV is a large binary
# wheel per platform that the add-on would have to bundle (blender_addon/build.py). RGBE is a
# small format; this reader (numpy only) reads a flat 2048x1024 map in 219 ms (2 loaded cores).
# It is bounded before allocating: the file's size (4 bytes per texel of the largest map), the
# declared size against MAX_MAP_PIXELS and free memory, and the bytes the declared size needs
# (tests/relight/command/test_hostile_inputs.py, tests/relight/files/test_fuzz_loaders.py).
def read_radiance_hdr(path) -> np.ndarray:
    """Read a Radiance RGBE (.hdr/.pic) file into float32 [H, W, 3].

    Supports flat and new-style run-length scanlines in the standard
    "-Y H +X W" orientation; texel = (mantissa + 0.5) * 2^(exponent - 136).
    """
    path = Path(path)
    size = path.stat().st_size
    if size > 4 * MAX_MAP_PIXELS + (1 << 20):  # flat RGBE of the largest map, plus a header
        raise ValueError(f"{path}: {size:,} bytes is larger than any map within the size limit")
    data = path.read_bytes()
    if not (data.startswith(b"#?RADIANCE") or data.startswith(b"#?RGBE")):
        raise ValueError(f"{path}: not a Radiance HDR file (missing #?RADIANCE header)")
    end = data.find(b"\n\n")
    if end < 0:
        raise ValueError(f"{path}: Radiance header is not terminated")
    header = data[:end].split(b"\n")
    for line in header:
        if line.startswith(b"FORMAT=") and line.strip() != b"FORMAT=32-bit_rle_rgbe":
            raise ValueError(f"{path}: unsupported Radiance format {line.decode(errors='replace')}")
    nl = data.find(b"\n", end + 2)
    if nl < 0:
        raise ValueError(f"{path}: Radiance resolution line missing")
    m = _RESOLUTION_RE.match(data[end + 2 : nl].strip())
    if not m:
        raise ValueError(f"{path}: only the standard '-Y H +X W' orientation is supported")
    if max(len(m.group(1)), len(m.group(2))) > 9:
        raise ValueError(f"{path}: Radiance resolution line declares an impossible size")
    height, width = int(m.group(1)), int(m.group(2))
    if height < 1 or width < 1:
        raise ValueError(f"{path}: empty image {width}x{height}")
    pixel_bytes, least = len(data) - (nl + 1), height * _min_scanline_bytes(width)
    if pixel_bytes < least:  # checked before allocating: a forged size costs nothing
        raise ValueError(f"{path}: Radiance pixel data is truncated or corrupt: the header declares "
                         f"{width}x{height}, at least {least:,} bytes, the file holds {pixel_bytes:,}")
    _check_map_size(width, height, path)
    buf = np.frombuffer(data, dtype=np.uint8, offset=nl + 1)
    rgbe = np.empty((height, width, 4), dtype=np.uint8)
    pos = 0
    truncated = ValueError(f"{path}: Radiance pixel data is truncated or corrupt")
    for y in range(height):
        if (
            8 <= width < 32768
            and pos + 4 <= buf.size
            and buf[pos] == 2
            and buf[pos + 1] == 2
            and (int(buf[pos + 2]) << 8 | int(buf[pos + 3])) == width
            and not buf[pos + 2] & 0x80
        ):
            pos += 4
            for c in range(4):  # each component is run-length coded separately
                x = 0
                while x < width:
                    if pos >= buf.size:
                        raise truncated
                    count = int(buf[pos])
                    pos += 1
                    if count > 128:
                        count -= 128
                        if x + count > width or pos >= buf.size:
                            raise truncated
                        rgbe[y, x : x + count, c] = buf[pos]
                        pos += 1
                    else:
                        if count == 0 or x + count > width or pos + count > buf.size:
                            raise truncated
                        rgbe[y, x : x + count, c] = buf[pos : pos + count]
                        pos += count
                    x += count
        else:
            if pos + 4 * width > buf.size:
                raise truncated
            rgbe[y] = buf[pos : pos + 4 * width].reshape(width, 4)
            pos += 4 * width
    out = np.empty((height, width, 3), dtype=np.float32)
    for r0 in range(0, height, _HDR_STRIP_ROWS):  # strips bound the float64 temporaries
        strip = rgbe[r0:r0 + _HDR_STRIP_ROWS]
        exponent = strip[..., 3].astype(np.int32)
        scale = np.where(exponent > 0, np.ldexp(1.0, exponent - 136), 0.0)
        out[r0:r0 + _HDR_STRIP_ROWS] = (strip[..., :3] + 0.5) * scale[..., None]
    return out


def load_equirect(path) -> EnvMap:
    """Load and validate an equirect HDR map from an OpenEXR or Radiance .hdr file."""
    from relight.files.exr import read_exr
    from relight.files.exr_layout import read_layout

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"HDR map not found: {path}")
    with open(path, "rb") as f:
        magic = f.read(10)
    if magic[:4] == b"\x76\x2f\x31\x01":  # OpenEXR magic number
        parts = read_layout(path)  # the headers and chunk tables, read once: the size, then the read
        sizes = [part.size for part in parts]
        _check_map_size(max(w for w, _ in sizes), max(h for _, h in sizes), path)
        pixels = _rgb_from_exr_channels(read_exr(path, parts), str(path))
    elif magic.startswith(b"#?"):
        pixels = read_radiance_hdr(path)
    else:
        raise ValueError(f"{path}: not an OpenEXR or Radiance HDR file")
    return validate_equirect(pixels, source=str(path))
