"""A photo file's header, read once before any pixel is decoded: its size, format, EXIF
orientation and 35 mm-equivalent focal length, and the file's length, the size weighed against
relight.files.image_limits as soon as it is known.

What is wrong with a file is one error naming it, each a kind of image_limits.ImageFileError (a
ValueError): ImageNotFound; ImageUnreadable (the system refuses to read it); NotAnImage (empty,
or no image format knows it); ImageDamaged (an image whose header, EXIF or pixel data is cut
short or broken); image_limits.ImageSizeError (too large for the limits). Their messages are
the command's lines; the add-on words them for the artist from their kinds and attributes.
relight.files.photo decodes from the same open (open_photo), so a photo's header is read once.
"""

from __future__ import annotations

import math
import re
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from relight.files.image_limits import (MAX_PIXELS, ImageFileError, ImageSizeError, check_declared_size,
                                        check_max_pixels)
from relight.files.png_decoder import check_png_chunks

__all__ = ["EXR_MAGIC", "ImageDamaged", "ImageNotFound", "ImageUnreadable", "NotAnImage", "PhotoHeader",
           "open_photo", "read_header"]

EXR_MAGIC = b"\x76\x2f\x31\x01"  # an OpenEXR file's first four bytes
_ORIENTATION = 0x0112            # EXIF Orientation (IFD0)
_EXIF_IFD = 0x8769               # the Exif sub-IFD
_FOCAL_35MM = 0xA405             # FocalLengthIn35mmFilm, in the Exif sub-IFD
FOCAL_35MM_RANGE = (1.0, 2000.0)  # mm: a focal length outside is not one (0 means "unknown" in EXIF)
SWAPPED_ORIENTATIONS = (5, 6, 7, 8)  # EXIF turns that exchange width and height


class ImageNotFound(ImageFileError):
    """No file at the path."""


class ImageUnreadable(ImageFileError):
    """The system refuses to read the file (permissions, an I/O error)."""


class NotAnImage(ImageFileError):
    """An empty file, a folder, or a file no image format knows."""


class ImageDamaged(ImageFileError):
    """An image file whose header, EXIF or pixel data is cut short or broken."""


@dataclass(frozen=True)
class PhotoHeader:
    """What a photo file's header says, read before any pixel is decoded."""

    path: Path
    width: int                       # pixels, as stored (before the EXIF turn)
    height: int
    format: str                      # Pillow's name of the format ("JPEG", "PNG", ...), or "EXR"
    file_bytes: int
    orientation: int = 1             # EXIF orientation 1 - 8: the turn from the stored pixels to upright
    focal_35mm: float | None = None  # mm, EXIF FocalLengthIn35mmFilm; None when absent, unknown or unreadable

    @property
    def upright_size(self) -> tuple[int, int]:
        """(width, height) of the photo turned upright."""
        return (self.height, self.width) if self.orientation in SWAPPED_ORIENTATIONS else (self.width, self.height)


def read_header(path, max_pixels: int | None = None, *, weigh_file_size: bool | None = None,
                weigh: bool = True) -> PhotoHeader:
    """The header of the photo file at `path`, its size weighed (unless not `weigh`) as
    image_limits.check_declared_size weighs it with these `max_pixels` and `weigh_file_size`.
    Raises an ImageFileError (see the module's docstring); MemoryError passes."""
    with open_photo(path, max_pixels, weigh_file_size=weigh_file_size, weigh=weigh) as (header, _):
        return header


@contextmanager
def open_photo(path, max_pixels: int | None = None, *, weigh_file_size: bool | None = None, weigh: bool = True):
    """(PhotoHeader, the file as Pillow opened it, nothing decoded, or None for an EXR), for
    decoding from the same open; Pillow's image is closed on leaving. The size is weighed
    (read_header) before the EXIF is read and, for a PNG, before its chunks are walked."""
    path = Path(path)
    file_bytes = _exists(path)
    try:
        with open(path, "rb") as f:
            magic = f.read(4)
    except OSError as exc:
        raise ImageUnreadable(path, f"{path}: cannot be read ({exc.strerror or exc})") from None
    if magic == EXR_MAGIC:
        header = PhotoHeader(path, *_exr_size(path), "EXR", file_bytes)
        if weigh:
            # an EXR's header can declare what its (zip-compressed) data cannot hold: weighed as a PNG's
            check_declared_size(header.width, header.height, path, max_pixels=max_pixels, file_bytes=file_bytes,
                                fmt="EXR", weigh_file_size=weigh_file_size)
        yield header, None
        return
    im = _open_pillow(path, max_pixels)
    try:
        with _damaged(path, "corrupt or truncated image"):
            width, height = im.size
            if weigh:
                check_declared_size(width, height, path, max_pixels=max_pixels, file_bytes=file_bytes, fmt=im.format,
                                    weigh_file_size=weigh_file_size)
            png_exif = check_png_chunks(path) if im.format == "PNG" else None
        with _damaged(path, "corrupt EXIF"), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # Pillow's complaints about EXIF: a value we do not read
            orientation, focal = _exif_facts(im, png_exif)
        yield PhotoHeader(path, width, height, im.format or "", file_bytes, orientation, focal), im
    finally:
        im.close()


def _exists(path: Path) -> int:
    """The file's length; ImageNotFound or NotAnImage when there is no file or nothing in it."""
    if not path.exists():
        raise ImageNotFound(path, f"{path}: file not found")
    if not path.is_file():
        raise NotAnImage(path, f"{path}: not a file")
    size = path.stat().st_size
    if size == 0:
        raise NotAnImage(path, f"{path}: file is empty")
    return size


def _exr_size(path: Path) -> tuple[int, int]:
    from relight.files.exr import exr_size

    try:
        return exr_size(path)
    except FileNotFoundError:
        raise ImageNotFound(path, f"{path}: file not found") from None
    except ValueError as exc:  # relight.files.exr_layout's line: the framing is cut short or broken
        raise ImageDamaged(path, str(exc)) from None


def _open_pillow(path: Path, max_pixels: int | None):
    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # DecompressionBombWarning: our own check weighs the size
            return Image.open(path)
    except Image.DecompressionBombError as exc:  # over twice Pillow's limit, so over ours too
        said = re.search(r"\((\d+) pixels\)", str(exc))  # Pillow names the pixel count, not the sides
        pixels = int(said.group(1)) if said else None
        count = f"{pixels:,} pixels" if pixels else f"over {2 * Image.MAX_IMAGE_PIXELS:,} pixels"
        raise ImageSizeError(path, f"{path}: image is too large ({count}; at most {MAX_PIXELS:,} can be relit): "
                             "scale it down", "pixels", None, None, pixels,
                             max_pixels=check_max_pixels(max_pixels)) from None
    except UnidentifiedImageError as exc:  # no format knows the file (or its first bytes are cut)
        raise NotAnImage(path, f"{path}: not a readable image ({type(exc).__name__}: {exc})") from None
    except Exception as exc:  # a format knew it, its header is broken: OSError, SyntaxError, struct.error...
        if isinstance(exc, MemoryError):
            raise
        raise ImageDamaged(path, f"{path}: not a readable image ({type(exc).__name__}: {exc})") from None


@contextmanager
def _damaged(path: Path, what: str):
    """Whatever a decoder raises (truncated data, bad EXIF, library errors) becomes
    ImageDamaged("PATH: WHAT (Type: message)"); our own ImageFileErrors and MemoryError pass
    unchanged, and a plain ValueError of ours (a line naming the file) becomes an ImageDamaged
    with its own words."""
    try:
        yield
    except (ImageFileError, MemoryError):
        raise
    except ValueError as exc:
        raise ImageDamaged(path, str(exc)) from None
    except Exception as exc:
        raise ImageDamaged(path, f"{path}: {what} ({type(exc).__name__}: {exc})") from None


def _exif_facts(im, png_exif: bytes | None) -> tuple[int, float | None]:
    """(orientation 1 - 8, focal length in mm or None) from the file's EXIF. A PNG's EXIF, when
    Pillow has not met it before the pixels, is the eXIf chunk the chunk walk found: Pillow's
    getexif would decode the pixels to find it."""
    if im.format != "PNG" or "exif" in im.info:
        exif = im.getexif()
    elif png_exif is not None:
        from PIL import Image

        exif = Image.Exif()
        exif.load(png_exif)
    elif "Raw profile type exif" in im.info:  # ImageMagick's EXIF in a text chunk: Pillow reads it
        exif = im.getexif()
    else:
        return 1, None
    orientation = exif.get(_ORIENTATION, 1)
    try:  # the focal length is optional: a broken Exif sub-IFD or an odd value is no focal length
        focal = float(exif.get_ifd(_EXIF_IFD).get(_FOCAL_35MM, "nan"))
    except Exception as exc:  # Pillow's many types
        if isinstance(exc, MemoryError):
            raise
        focal = math.nan
    low, high = FOCAL_35MM_RANGE
    return (orientation if orientation in range(1, 9) else 1), (focal if low <= focal <= high else None)
