"""The add-on's logic without bpy: masks, light resolution, model lookup, compositing.

Everything here takes and returns numpy arrays and plain values, so it is
tested without Blender; the bpy layer only moves pixels in and out.
Messages of the ValueErrors raised here are shown to the user as they are:
one sentence each.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np


LAYERS = ("relit", "albedo", "shading", "residual", "alpha", "preview", "matte")
LAYER_ORDER = ("relit", "alpha", "albedo", "shading", "residual", "matte")  # relit first: what the user sees
# preview: screen-sized relit; matte: the photo cut out by the person matte (to check it)
EMPTY_MASK_LEVEL = 1e-3  # a mask whose largest value is below this selects nothing
MIN_PHOTO_SIDE = 32      # pixels: below this on either side a photo cannot show a person
BLACK_LEVEL = 3e-3       # linear luminance (sRGB code ~11/255): a photo whose brightest pixel is below is black
WHITE_LEVEL = 0.98       # a photo whose darkest channel value everywhere is above this is blown out
FLAT_SPREAD = 0.02       # luminance spread (1st to 99th percentile) below this fraction of its level: one colour
CHECK_SAMPLES = 1 << 18  # pixels looked at by check_photo_content (a regular subsample)


# ------------------------------------------------------------------ names

def output_name(source: str, layer: str) -> str:
    """Name of the image datablock holding `layer` of `source`: '<source>.<layer>'."""
    if layer not in LAYERS:
        raise ValueError(f"unknown layer {layer!r}; expected one of {', '.join(LAYERS)}")
    return f"{source}.{layer}"


def source_of(name: str, existing: set[str] | frozenset[str] = frozenset()) -> str:
    """The photo an output image belongs to ('p.png.relit' -> 'p.png'); `name` when it is no output."""
    for layer in LAYERS:
        suffix = "." + layer
        if name.endswith(suffix) and name[: -len(suffix)] in existing:
            return name[: -len(suffix)]
    return name


def saved_relight_path(blend_path: str, photo_id: str) -> str:
    """Where the decomposition of photo `photo_id` is kept for the .blend at `blend_path`:
    a folder next to it, '<name>_relight/<photo id>.npz'."""
    folder, name = os.path.split(blend_path)
    stem = os.path.splitext(name)[0]
    return os.path.join(folder, f"{stem}_relight", f"{photo_id}.npz")


# ------------------------------------------------------------------ photo pixels

@dataclass
class PhotoPixels:
    """A photo as the add-on works on it."""

    rgb: np.ndarray             # linear RGB [H, W, 3] float32, top row first
    alpha: np.ndarray | None    # [H, W] in [0, 1], or None when the image has no alpha
    digest: str                 # hash of the stored pixel values: the key of a saved decomposition


def _digest(*arrays: np.ndarray) -> str:
    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        h.update(repr(a.shape).encode())
        h.update(np.ascontiguousarray(a).data)  # hashlib releases the GIL on large buffers
    return h.hexdigest()


def _from_codes(codes: np.ndarray, alpha_codes: np.ndarray | None,
                reuse: PhotoPixels | None = None) -> PhotoPixels:
    # the digest covers the colour codes only, so it does not depend on how the
    # alpha was read (Blender gives every byte image four channels)
    from relight.colour import decode_alpha_codes, decode_srgb_codes  # the CLI's decoder: the same floats

    digest = _digest(codes)
    # the same pixels as the photo's last decoding (Relight again): its linear copy is shared,
    # not made twice (288 MB at 24 MP)
    rgb = reuse.rgb if reuse is not None and reuse.digest == digest else decode_srgb_codes(codes)
    alpha = None if alpha_codes is None else decode_alpha_codes(alpha_codes)
    return PhotoPixels(rgb, alpha, digest)


_8BIT_MODES = {"1", "L", "LA", "P", "PA", "RGB", "RGBA", "RGBX", "CMYK", "YCbCr"}
_ALPHA_MODES = {"LA", "PA", "RGBA"}


def read_8bit_file(path: str, shape: tuple[int, int] | None, with_alpha: bool, name: str,
                   reuse: PhotoPixels | None = None) -> PhotoPixels:
    """Decode an 8-bit sRGB photo file (worker thread).

    `shape` is (H, W) as Blender loaded it, or None when Blender has not
    loaded the image (then the file's own mode says whether it is 8-bit and
    has alpha). `reuse`: the photo as decoded before, shared when its pixels are the same."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            if shape is None:
                if im.mode not in _8BIT_MODES:
                    raise ValueError(f"'{name}' has more than 8 bits per channel: show it in the Image Editor, "
                                     "then press Relight.")
                with_alpha = with_alpha and (im.mode in _ALPHA_MODES or "transparency" in im.info)
            im = im.convert("RGBA" if with_alpha else "RGB")
            codes = np.asarray(im)
    except UnidentifiedImageError:
        raise ValueError(f"'{name}' is not an image Blender can read ({os.path.basename(path)}).") from None
    except OSError as exc:
        raise ValueError(f"The photo file of '{name}' cannot be read ({_first_line(exc)}).") from None
    if shape is not None and codes.shape[:2] != tuple(shape):
        raise ValueError(f"The photo file of '{name}' changed on disk since Blender loaded it: "
                         "reload the image (Image > Reload) and relight.")
    if with_alpha:
        return _from_codes(np.ascontiguousarray(codes[..., :3]), np.ascontiguousarray(codes[..., 3]), reuse)
    return _from_codes(codes, None, reuse)


def photo_from_blender(flat: np.ndarray, shape: tuple[int, int, int], *, srgb: bool, with_alpha: bool,
                       name: str, reuse: PhotoPixels | None = None) -> PhotoPixels:
    """Pixels copied out of Blender (flat, bottom row first, `shape` = (H, W, C)) as a PhotoPixels.

    8-bit sRGB images hold code / 255: the codes are recovered exactly and
    decoded by table; float images are taken as scene-linear.
    """
    h, w, c = shape
    px = flat.reshape(h, w, c)[::-1]
    rgb = px[..., :3] if c >= 3 else np.repeat(px[..., :1], 3, axis=2)
    alpha = px[..., 3] if c == 4 and with_alpha else None
    if srgb:
        codes = np.rint(np.clip(rgb, 0.0, 1.0) * np.float32(255.0)).astype(np.uint8)
        alpha_codes = None if alpha is None else np.rint(np.clip(alpha, 0.0, 1.0) * 255.0).astype(np.uint8)
        return _from_codes(codes, alpha_codes, reuse)
    rgb = np.ascontiguousarray(rgb, dtype=np.float32)
    if not np.all(np.isfinite(rgb)):
        raise ValueError(f"The image '{name}' contains NaN or infinite pixels.")
    alpha = None if alpha is None else np.ascontiguousarray(alpha)
    return PhotoPixels(rgb, alpha, _digest(rgb))


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
        with self._lock:
            for i, buf in enumerate(self._free):
                if buf.size == n:
                    return self._free.pop(i)
        return np.empty(n, np.float32)

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


def to_blender_rgba(pixels: np.ndarray, out: np.ndarray | None = None,
                    alpha: np.ndarray | None = None) -> np.ndarray:
    """[H, W] or [H, W, 1|3|4] top row first -> flat float32 RGBA, bottom row first (Blender's layout);
    `alpha` [H, W], when given, is the alpha channel.

    `out` (H * W * 4 float32) is filled when given, else a buffer from BUFFERS:
    the worker prepares it and the main thread only hands it to foreach_set.
    """
    px = np.asarray(pixels, dtype=np.float32)
    if px.ndim == 2:
        px = px[..., None]
    h, w, c = px.shape
    rgba = BUFFERS.take(h * w * 4) if out is None else out
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


# ------------------------------------------------------------------ photo checks

def check_photo_size(width: int, height: int) -> None:
    """ValueError in the artist's words when the photo is too small to show a person."""
    if min(width, height) < MIN_PHOTO_SIDE:
        raise ValueError(f"The photo is only {width} x {height} pixels, too small to show a person: "
                         f"use a photo at least {MIN_PHOTO_SIDE} pixels on each side.")


def check_photo_content(photo: np.ndarray) -> None:
    """ValueError when the photo cannot hold a visible person: black, blown-out white, or one flat colour.

    The network would still return layers for such a photo, relit from nothing,
    which would look like a result; these are caught first. A regular subsample
    of about CHECK_SAMPLES pixels is enough for levels and percentiles.
    """
    h, w = photo.shape[:2]
    check_photo_size(w, h)
    step = max(1, int(np.sqrt(h * w / CHECK_SAMPLES)))
    sample = np.asarray(photo[::step, ::step, :3], dtype=np.float32).reshape(-1, 3)
    from relight.colour import LUMINANCE_WEIGHTS

    luminance = sample @ LUMINANCE_WEIGHTS.astype(np.float32)
    if float(luminance.max()) < BLACK_LEVEL:
        raise ValueError("The photo is black: there is no person to see in it. "
                         "Check the photo's exposure, or open another photo.")
    if float(sample.min()) > WHITE_LEVEL:
        raise ValueError("The photo is white (blown out): there is no person to see in it. Open another photo.")
    low, high = np.percentile(luminance, [1.0, 99.0])
    if high - low < FLAT_SPREAD * max(float(high), BLACK_LEVEL):
        raise ValueError("The photo is one flat colour: there is no person to relight in it. Open another photo.")


# ------------------------------------------------------------------ masks

MASK_MODES = ("AUTO", "NETWORK", "IMAGE_ALPHA", "IMAGE")


def choose_mask(mode: str, photo_shape: tuple[int, int], photo_alpha: np.ndarray | None,
                mask_rgb: np.ndarray | None = None, mask_alpha: np.ndarray | None = None,
                mask_name: str = "") -> np.ndarray | None:
    """The mask [H, W] in [0, 1] given to the network, or None when it is made otherwise.

    IMAGE_ALPHA uses the photo's alpha; IMAGE uses another image of the same
    size: its alpha when it has a non-constant one, else its grey level (mean
    of R, G, B as stored, as relight.photo.read_mask reads mask files).
    """
    if mode in ("AUTO", "NETWORK"):
        return None  # AUTO: the person matte, made by the worker; NETWORK: the relighting network's own
    if mode == "IMAGE_ALPHA":
        if photo_alpha is None:
            raise ValueError("The photo has no alpha channel to use as the mask.")
        mask = photo_alpha
    elif mode == "IMAGE":
        if mask_rgb is None:
            raise ValueError("Choose a mask image, or set the mask to Automatic.")
        if mask_rgb.shape[:2] != tuple(photo_shape):
            raise ValueError(f"The mask image '{mask_name}' is {mask_rgb.shape[1]}x{mask_rgb.shape[0]} "
                             f"but the photo is {photo_shape[1]}x{photo_shape[0]}.")
        if mask_alpha is not None and np.ptp(mask_alpha) > 0:
            mask = mask_alpha
        else:
            mask = mask_rgb[..., :3].mean(axis=2)
    else:
        raise ValueError(f"Unknown mask mode {mode!r}.")
    mask = np.clip(np.asarray(mask, dtype=np.float32), 0.0, 1.0)
    if not np.all(np.isfinite(mask)) or float(mask.max(initial=0.0)) < EMPTY_MASK_LEVEL:
        raise ValueError("The mask is empty: it selects no pixel of the photo.")
    return mask


# ------------------------------------------------------------------ lights

LIGHT_KINDS = ("WORLD", "HDR", "PRESET", "IMAGE")


def light_cache():
    """The add-on's relight.light.SHLightCache: HDR files projected once per file state and
    the rotation matrices the dials ask for again and again."""
    if not _LIGHT_CACHE:
        from relight.light import LightCache

        _LIGHT_CACHE.append(LightCache())
    return _LIGHT_CACHE[0]


_LIGHT_CACHE: list = []


def hdr_file_light(path: str, order: int):
    """The HDR file as a relight.light.SHLight (read and projected here, once per file state)."""
    from relight.light import SHLight

    if not path:
        raise ValueError("Choose an HDR file for the light.")
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"The HDR file '{path}' does not exist.")
    try:
        return SHLight.resolve(str(p), order, cache=light_cache())
    except (ValueError, OSError) as exc:
        if _is_black_light(exc):
            raise ValueError(f"The HDR file '{p.name}' is black, so it gives no light: "
                             "choose another file.") from None
        raise ValueError(f"The HDR file '{p.name}' cannot be read as an equirectangular map "
                         f"({_first_line(exc)}).") from None


def preset_light(name: str, order: int):
    """The preset as a relight.light.SHLight (loaded and projected once)."""
    from relight.light import SHLight

    try:
        return SHLight.resolve(name, order, cache=light_cache())
    except (ValueError, OSError) as exc:
        raise ValueError(f"The light preset '{name}' is not available ({_first_line(exc)}).") from None


def equirect_light(pixels: np.ndarray, order: int):
    """The World's equirect map (pixels) as a relight.light.SHLight: a map like an HDR
    file or a preset, so World, HDR file and preset are scaled alike."""
    from relight.light import SHLight

    h, w = pixels.shape[:2]
    if w != 2 * h:
        raise ValueError(f"The World's environment image is {w}x{h}; an equirectangular map "
                         "is twice as wide as high.")
    rgb = np.ascontiguousarray(pixels[..., :3])
    if not np.all(np.isfinite(rgb)):
        raise ValueError("The World's light has invalid (infinite or NaN) values: "
                         "check its environment image and Background strength.")
    if float(rgb.max(initial=0.0)) <= 0.0:
        raise ValueError(BLACK_WORLD)
    try:
        return SHLight.resolve(rgb, order)
    except ValueError as exc:
        if _is_black_light(exc):
            raise ValueError(BLACK_WORLD) from None
        raise ValueError(f"The World gives no usable light ({_first_line(exc)}).") from None


BLACK_WORLD = ("The World is black, so it gives no light: raise its Background colour or Strength, "
               "or choose another light.")


def _is_black_light(exc: BaseException) -> bool:
    # relight.sh refuses to scale a light whose mean luminance is not positive
    return "mean luminance" in str(exc)


def preset_names() -> list[str]:
    """Bundled presets, then Blender's own studio worlds when bpy is there."""
    from relight import presets

    return presets.list_presets() + presets.list_blender_presets()


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0].rstrip(".") if text else type(exc).__name__


# ------------------------------------------------------------------ model

def model_path_for(quality_key: str, override: str = "") -> Path:
    """The ONNX file to run: `override` when given, else the preset's registered model.

    A preset whose model is not registered falls back to the registry's
    default model (the working resolution still follows the preset).
    """
    if override:
        p = Path(override)
        if not p.is_file():
            raise ValueError(f"The model file '{override}' does not exist.")
        return p
    from relight import quality as core_quality

    core_quality.preset(quality_key)  # an unknown key is its own error
    try:
        p = core_quality.model_path(quality_key)  # the registry looked up now: tests point it elsewhere
    except ValueError:
        raise ValueError("No relighting model is installed: choose a model file (.onnx) in the panel.") from None
    if not p.is_file():
        raise ValueError(f"The relighting model '{p.name}' is missing from the installation.")
    return p


# ------------------------------------------------------------------ compositing

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
    step = max(1, (1 << 12) // max(1, w))  # rows that stay in cache, one channel at a time
    for r0 in range(0, h, step):
        for c in range(3):
            out, p = relit[r0:r0 + step, :, c], photo[r0:r0 + step, :, c]
            if s == 0.0:
                out[...] = p
                continue
            out -= p
            out *= np.float32(s)
            out += p


def layers_in_order(buffers) -> list[str]:
    """The layers of `buffers` in the order they are handed to Blender (LAYER_ORDER)."""
    return [layer for layer in LAYER_ORDER if layer in buffers]


def mask_channels(stored: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """(rgb [H, W, 3], alpha [H, W] or None) of a mask image's stored pixels [H, W, C]:
    one channel is repeated to three; alpha only when there are four."""
    rgb = stored[..., :3] if stored.shape[2] >= 3 else np.repeat(stored[..., :1], 3, axis=2)
    return rgb, stored[..., 3] if stored.shape[2] == 4 else None


def saved_mask_inputs(mask_key) -> dict:
    """The mask inputs of a saved decomposition's mask key (mode, name); an IMAGE mask's
    pixels are filled in by the caller, which reads them from Blender."""
    mode, name = mask_key
    return dict(mode=mode, rgb=None, alpha=None, name=name, use_photo_alpha=mode == "IMAGE_ALPHA",
                person=int(name) if mode == "AUTO" else 1)


def env_flag(name: str) -> bool:
    """True when environment variable `name` is set to 1/true/yes/on."""
    return os.environ.get(name, "").strip().lower() in {"1", "true", "yes", "on"}
