"""bpy image datablocks <-> numpy arrays (top row first), and the stable identity of photos.

Blender stores pixels bottom row first, RGBA float. Byte images hold their
encoded values (/255); float images hold scene-linear values.

Every pixel transfer is one `foreach_get` / `foreach_set` of a preallocated
float32 buffer (a memory copy inside Blender); the conversions around it
(flip, sRGB decode, RGBA packing) are plain numpy in `photo_pixels` and
`pixel_buffers`, so the worker
thread does them. A photo that is an unmodified 8-bit file on disk is even
decoded by the worker from its file, so the main thread does not touch its
pixels at all.

Photos and outputs are found by custom properties, not by name: renaming the
photo in Blender keeps its outputs and its saved decomposition attached.
"""

from __future__ import annotations

import os
import uuid

import bpy
import numpy as np

from ..logic import photo_checks, photo_pixels, pixel_buffers

LINEAR = "Linear Rec.709"
NON_COLOR = "Non-Color"
_SRGB_NAMES = {"sRGB", "sRGB 2.2"}  # Blender names for the sRGB transfer
PHOTO_ID = "relight_photo_id"        # on a photo: its stable identity
OUTPUT_OF = "relight_photo_of"       # on an output: the photo id it belongs to
OUTPUT_LAYER = "relight_photo_layer"  # on an output: which layer it is
UNWRITTEN = "relight_photo_unwritten"  # on an output made but not yet written (bl_images.output_image)
# file types the core's reader (relight.files.photo.read_photo) reads as `relight image` does: sRGB-encoded
# (8 or 16 bits), or linear EXR
_PILLOW_EXTENSIONS = {".png", ".jpg", ".jpeg", ".bmp", ".tga", ".tif", ".tiff", ".webp"}
_LINEAR_NAMES = {LINEAR, "Linear"}  # Blender names for scene-linear Rec.709 (an EXR's own)


# ------------------------------------------------------------------ identity

def photo_id(image, create: bool = False) -> str:
    """The photo's stable id ('' when it has none and `create` is False).

    A duplicated image copies the property: with `create`, a photo whose id
    another photo already carries gets a fresh one, so the copy relights on
    its own.
    """
    pid = str(image.get(PHOTO_ID, ""))
    if create and (not pid or any(other.get(PHOTO_ID) == pid and other != image for other in bpy.data.images)):
        pid = uuid.uuid4().hex
        image[PHOTO_ID] = pid
    if create:
        image.use_fake_user = True  # a relit photo stays in the .blend with its outputs
    return pid


def photo_by_id(pid: str):
    """The photo datablock carrying id `pid`, or None (deleted)."""
    if not pid:
        return None
    for image in bpy.data.images:
        if image.get(PHOTO_ID) == pid and OUTPUT_OF not in image:
            return image
    return None


def output_by_tag(pid: str, layer: str):
    for image in bpy.data.images:
        if image.get(OUTPUT_OF) == pid and image.get(OUTPUT_LAYER) == layer:
            return image
    return None


def sync_output_names() -> int:
    """Rename every output whose photo was renamed ('<photo>.<layer>'); returns how many.

    Idempotent and cheap (one pass over the images), so it runs on every
    dial change, Relight and image update."""
    photos = {image.get(PHOTO_ID): image for image in bpy.data.images
              if PHOTO_ID in image and OUTPUT_OF not in image}
    renamed = 0
    for image in bpy.data.images:
        photo = photos.get(image.get(OUTPUT_OF))
        if photo is None:
            continue
        want = f"{photo.name}.{image.get(OUTPUT_LAYER, '')}"
        if image.name != want and bpy.data.images.get(want) is None:
            image.name = want
            renamed += 1
    return renamed


def owner_of(image) -> str:
    """The photo id an output image belongs to ('' for a photo)."""
    return str(image.get(OUTPUT_OF, ""))


def photo_stamp(image) -> tuple:
    """What tells, without reading a pixel (a 24 MP photo takes a second), that the photo still
    has the pixels it was relit with: its file with the file's size and time (or its packed
    data's size), how Blender decodes it, and whether it has been painted on since it was saved."""
    path, on_disk = "", None
    if image.source == "FILE" and image.packed_file is None:
        path = bpy.path.abspath(image.filepath, library=image.library)
        try:
            st = os.stat(path)
            on_disk = (st.st_size, st.st_mtime_ns)
        except OSError:
            pass
    packed = image.packed_file.size if image.packed_file is not None else 0
    return (image.source, path, on_disk, packed, image.colorspace_settings.name, image.alpha_mode,
            image.is_dirty)


# ------------------------------------------------------------------ reading

def has_pixels(image: bpy.types.Image) -> bool:
    """True when Blender can give the image's pixels (loading its file if needed)."""
    if not image.has_data:
        _load(image)
    return image.has_data and image.size[0] > 0 and image.size[1] > 0


def no_pixels_reason(image) -> str:
    """Why `image` gives no pixels, said as a sentence about its file (has_pixels was False)."""
    if image.source == "FILE" and image.packed_file is None:
        path = bpy.path.abspath(image.filepath, library=image.library)
        if not os.path.isfile(path):
            return f"The photo file of '{image.name}' is missing ({path or 'no path'}): it was moved or deleted."
        return f"'{image.name}' is not an image Blender can read ({os.path.basename(path)})."
    return f"The image '{image.name}' has no pixels."


def file_missing(image) -> str:
    """A sentence when the photo's file is gone from disk ('' when it is there, packed or generated),
    told without loading the image."""
    if image.source != "FILE" or image.packed_file is not None or image.has_data:
        return ""
    path = bpy.path.abspath(image.filepath, library=image.library)
    if os.path.isfile(path):
        return ""
    return f"The photo file of '{image.name}' is missing ({path or 'no path'}): it was moved or deleted."


def rgba_pixels(image: bpy.types.Image) -> np.ndarray:
    """The image's pixels as float32 [H, W, C] (C = image.channels), top row first (a view)."""
    if not has_pixels(image):
        raise ValueError(no_pixels_reason(image))
    width, height = image.size
    channels = image.channels
    flat = np.empty(width * height * channels, dtype=np.float32)
    image.pixels.foreach_get(flat)
    return flat.reshape(height, width, channels)[::-1]


def _load(image: bpy.types.Image) -> None:
    """Ask Blender to read the file behind `image` (a failure shows as no pixels)."""
    try:
        if image.source == "FILE":
            image.reload()
        image.pixels[0:1]  # touching the pixels loads the buffer
    except (RuntimeError, IndexError):
        pass


def _is_srgb_bytes(image) -> bool:
    return not image.is_float and image.colorspace_settings.name in _SRGB_NAMES


def _wants_alpha(image) -> bool:
    return image.channels == 4 and image.alpha_mode != "NONE"


def photo_reader(image, reuse: photo_pixels.PhotoPixels | None = None,
                 max_megapixels: int = photo_checks.DEFAULT_MEGAPIXELS):
    """A function for the worker thread returning photo_pixels.PhotoPixels of `image`, upright.

    An unmodified sRGB or linear EXR file on disk is read from the file by the worker through
    the core's reader, as `relight image` reads it (EXIF orientation, 16 bits); anything else
    (packed, painted, other colour spaces) is copied out of Blender here, in one foreach_get,
    and converted by the worker, turned upright by its file's EXIF orientation. `reuse`: the photo as its last
    Relight decoded it, shared instead of decoded again when the pixels are the same.
    `max_megapixels`: the largest photo decoded (the panel's Max Photo Size); a larger one is
    refused from its file's header, before Blender or the worker decodes it.
    """
    name = image.name
    if not image.has_data:
        file = _file_on_disk(image)
        if file is not None:
            photo_checks.check_photo_file(file, name, max_megapixels)
        # not loaded yet (a reopened file): an 8-bit file is decoded by the worker
        # alone; Blender would decode it here, on the main thread, to tell its size
        path = _plain_file(image, loaded=False)
        if path is not None:
            with_alpha = image.alpha_mode != "NONE"
            return lambda: photo_pixels.read_file(path, None, with_alpha, name, reuse, max_megapixels)
    if not has_pixels(image):
        raise ValueError(no_pixels_reason(image))
    width, height = image.size
    photo_checks.check_photo_size(width, height)
    photo_checks.check_photo_pixels(width, height, name, max_megapixels)
    path = _plain_file(image)
    if path is not None:
        with_alpha = has_alpha(image)

        def read_file():
            return photo_pixels.read_file(path, (height, width), with_alpha, name, reuse, max_megapixels)
        return read_file
    with_alpha = _wants_alpha(image)
    channels = image.channels
    flat = np.empty(width * height * channels, dtype=np.float32)
    image.pixels.foreach_get(flat)
    srgb = _is_srgb_bytes(image)
    orientation = file_orientation(image)

    def convert():
        return photo_pixels.photo_from_blender(flat, (height, width, channels), srgb=srgb,
                                           with_alpha=with_alpha, name=name, reuse=reuse,
                                           orientation=orientation)
    return convert


def file_orientation(image) -> int:
    """The EXIF orientation of the file behind `image` (relight.files.photo.exif_orientation): how its
    stored pixels, which Blender shows, stand upright; 1 for a packed or generated image, or an
    unreadable file."""
    from relight.files.photo import exif_orientation

    path = _file_on_disk(image)
    if path is None:
        return 1
    try:
        return exif_orientation(path)
    except (ValueError, OSError):
        return 1


def has_alpha(image) -> bool:
    # depth: bits per pixel; 32/64/128 are RGBA at 8/16/32 bits per channel
    return image.alpha_mode != "NONE" and image.depth in (16, 32, 64, 128)


def _file_on_disk(image) -> str | None:
    """The file behind an image Blender reads from disk, when it is there; else None."""
    if image.source != "FILE" or image.packed_file is not None:
        return None
    path = bpy.path.abspath(image.filepath, library=image.library)
    return path if os.path.isfile(path) else None


def _plain_file(image, loaded: bool = True) -> str | None:
    """The image's file when the core's reader reads what Blender shows (upright), else None:
    an sRGB file of a type Pillow reads, or an EXR taken as scene-linear, not painted since loaded."""
    if image.source != "FILE" or image.packed_file is not None or image.library is not None:
        return None
    if image.type == "MULTILAYER":  # Blender shows the pass its editor picks, not the file's first
        return None
    if loaded and image.is_dirty:
        return None
    path = bpy.path.abspath(image.filepath)
    suffix = os.path.splitext(path)[1].lower()
    colour = image.colorspace_settings.name
    if not (suffix in _PILLOW_EXTENSIONS and colour in _SRGB_NAMES or suffix == ".exr" and colour in _LINEAR_NAMES):
        return None
    return path if os.path.isfile(path) else None


def linear_rgb_and_alpha(image: bpy.types.Image) -> tuple[np.ndarray, np.ndarray | None]:
    """(linear RGB [H, W, 3] float32, alpha [H, W] or None when the image has no alpha), on this thread."""
    px = rgba_pixels(image)
    flat = np.ascontiguousarray(px[::-1]).reshape(-1)  # back to Blender's layout
    pixels = photo_pixels.photo_from_blender(flat, px.shape, srgb=_is_srgb_bytes(image),
                                         with_alpha=px.shape[2] == 4 and image.alpha_mode != "NONE",
                                         name=image.name)
    return pixels.rgb, pixels.alpha


# ------------------------------------------------------------------ writing

def write_image(name: str, pixels: np.ndarray, *, colorspace: str = LINEAR, owner: str = "",
                layer: str = "") -> bpy.types.Image:
    """Create or overwrite float image `name` with pixels [H, W] or [H, W, 1|3|4] (top row first)."""
    px = np.asarray(pixels, dtype=np.float32)
    height, width = px.shape[:2]
    return write_rgba(name, pixel_buffers.to_blender_rgba(px), width, height, colorspace=colorspace,
                      owner=owner, layer=layer)


def output_image(name: str, width: int, height: int, *, colorspace: str = LINEAR, owner: str = "",
                 layer: str = "") -> tuple:
    """(image, made): the float image `name` of that size to write an output into, found by its
    (owner, layer) tags first, so a renamed photo's outputs are reused and renamed; `made` is True
    when Blender had to allocate its buffer (a new image, or a generated one resized in place, so an
    editor showing it keeps showing it): at 24 MP the longest single step of a write (0.1 s idle,
    0.4-0.5 s on the loaded 2-core machine), which a timer does apart from the pixels' copy."""
    image = output_by_tag(owner, layer) if owner else None
    if image is None:
        image = bpy.data.images.get(name)
        if image is not None and owner and image.get(OUTPUT_OF) not in (None, owner):
            image = None  # that name belongs to another photo's output
    if image is not None and image.name != name and bpy.data.images.get(name) is None:
        image.name = name
    if image is not None and not image.is_float:
        bpy.data.images.remove(image)
        image = None
    if image is not None and tuple(image.size) != (width, height) and image.source != "GENERATED":
        bpy.data.images.remove(image)
        image = None
    if image is None:  # made small and sized below: Blender fills its buffer once, not again after the colour space
        image = bpy.data.images.new(name, 1, 1, alpha=True, float_buffer=True)
    if tuple(image.size) != (width, height):  # a generated image resized in place: an editor keeps showing it
        image.generated_width, image.generated_height = width, height
    if owner:
        image[OUTPUT_OF], image[OUTPUT_LAYER] = owner, layer
        image.use_fake_user = True  # kept in the .blend even when no editor shows it
    if image.colorspace_settings.name != colorspace:
        image.colorspace_settings.name = colorspace  # (frees a generated image's buffer)
    made = not image.has_data  # new, resized, recoloured or reopened from a .blend: its buffer made now
    if made:
        image.update()
        image[UNWRITTEN] = True  # Blender's fill, not an output, until write_rgba writes it
    return image, made


def remove_unwritten(owner: str) -> int:
    """Remove the outputs of photo `owner` made by output_image but never written (a run dropped
    between the two steps): never left black as if they were results. Returns how many."""
    doomed = [image for image in bpy.data.images if image.get(OUTPUT_OF) == owner and image.get(UNWRITTEN)]
    for image in doomed:
        bpy.data.images.remove(image)
    return len(doomed)


def write_rgba(name: str, rgba: np.ndarray, width: int, height: int, *, colorspace: str = LINEAR,
               owner: str = "", layer: str = "") -> bpy.types.Image:
    """Put a buffer already in Blender's layout (RGBA, bottom row first) into image `name`
    (output_image's, made here when it is not there at that size)."""
    image, _ = output_image(name, width, height, colorspace=colorspace, owner=owner, layer=layer)
    image.pixels.foreach_set(rgba)
    image.update()
    if UNWRITTEN in image:
        del image[UNWRITTEN]
    return image
