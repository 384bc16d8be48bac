"""The add-on reads a photo file through the core's one header reader and only words its refusals
(issue 49): the file opened and decoded once, the core's size limits in the artist's words (plain
Python, no bpy; the same messages through Blender are in test_addon_messages.py)."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from PIL import Image

from blender_addon.logic import photo_checks, photo_light, photo_pixels
from fuzz_support import jpeg_bytes, png_bytes
from relight.files import image_limits


def _png_with_exif_after_the_pixels(path, orientation: int):
    exif = Image.Exif()
    exif[0x0112] = orientation
    tiff = exif.tobytes()
    tiff = tiff[6:] if tiff.startswith(b"Exif\x00\x00") else tiff
    png = png_bytes(6, 10)
    chunk = struct.pack(">I", len(tiff)) + b"eXIf" + tiff + struct.pack(">I", zlib.crc32(b"eXIf" + tiff))
    path.write_bytes(png[:-12] + chunk + png[-12:])
    return path


def test_a_photo_file_is_opened_and_decoded_once(tmp_path, monkeypatch):
    """The size check, the orientation and the pixels came from three opens of the file (and the
    orientation of a PNG whose EXIF follows its pixels from a second decode)."""
    path = _png_with_exif_after_the_pixels(tmp_path / "sideways.png", 6)
    opens, real_open = [], Image.open
    monkeypatch.setattr(Image, "open", lambda *a, **k: opens.append(a[0]) or real_open(*a, **k))
    decoders, real_decoder = [], Image._getdecoder
    monkeypatch.setattr(Image, "_getdecoder", lambda *a, **k: decoders.append(a[0]) or real_decoder(*a, **k))
    pixels = photo_pixels.read_file(str(path), (6, 10), False, "sideways.png")
    assert len(opens) == 1 and len(decoders) == 1
    assert pixels.orientation == 6 and pixels.rgb.shape == (10, 6, 3)


def test_the_panels_limit_and_the_cores_refusals_in_the_artists_words(tmp_path, monkeypatch):
    forged = tmp_path / "forged.jpg"
    forged.write_bytes(jpeg_bytes(declared=(4000, 3000)))  # 12 MP in a few hundred bytes
    size = forged.stat().st_size
    with pytest.raises(ValueError) as said:
        photo_pixels.read_file(str(forged), None, False, "forged.jpg")
    assert str(said.value) == (
        f"'forged.jpg' claims 3000 x 4000 pixels (12 MP) in a file of {size:,} bytes, more than such a file can "
        "hold: it is damaged or forged. Open another photo (or, if it is whole, set Max Photo Size above 50 MP "
        "to decode it anyway).")
    assert photo_checks.check_photo_file(str(forged), "forged.jpg", 51).width == 3000  # set above: allowed
    with pytest.raises(ValueError, match=r"^'forged.jpg' is 3000 x 4000 pixels \(12 MP\), over Max Photo Size "
                                         r"\(5 MP\): to relight it, raise Max Photo Size in the panel to 12 MP "
                                         r"\(it will need about 2 GB of memory\), or scale the photo down\.$"):
        photo_checks.check_photo_file(str(forged), "forged.jpg", 5)
    huge = tmp_path / "huge.jpg"
    huge.write_bytes(jpeg_bytes(declared=(20000, 20000)))
    with pytest.raises(ValueError, match=r"^'huge.jpg' is 400 MP: too large to relight \(at most 150 MP and "
                                         r"40,000 pixels a side\)\."):
        photo_checks.check_photo_file(str(huge), "huge.jpg")
    with pytest.raises(ValueError, match=r"^'wide' is 45000 x 10 pixels \(0.45 MP\): too large to relight"):
        photo_checks.check_photo_pixels(45_000, 10, "wide")
    monkeypatch.setattr(image_limits, "memory_available", lambda: 2**30)
    with pytest.raises(ValueError, match=r"^'big' is 6000 x 5000 pixels \(30 MP\) needs about 1.1 GB of memory "
                                         r"to read, and only 1.0 GB is free: close other programs"):
        photo_checks.check_photo_pixels(6000, 5000, "big")


def test_what_is_wrong_with_a_file_in_the_artists_words(tmp_path):
    (tmp_path / "notes.png").write_text("these are notes, not a photo\n")
    with pytest.raises(ValueError, match=r"^'notes' is not an image Blender can read \(notes.png\)\.$"):
        photo_pixels.read_file(str(tmp_path / "notes.png"), None, False, "notes")
    with pytest.raises(ValueError, match=r"^The photo file of 'gone' is missing\.$"):
        photo_pixels.read_file(str(tmp_path / "gone.png"), None, False, "gone")
    half = tmp_path / "half.jpg"
    data = jpeg_bytes(64, 64)
    half.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"^The photo file of 'half' cannot be read \(.*half.jpg: corrupt or "
                                         r"truncated image"):
        photo_pixels.read_file(str(half), None, False, "half")
    assert photo_checks.check_photo_file(str(tmp_path / "notes.png"), "notes") is None  # Blender says why


def test_the_focal_length_is_the_headers(tmp_path):
    exif = Image.Exif()
    exif.get_ifd(0x8769)[0xA405] = 85
    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(tmp_path / "tele.jpg", exif=exif)
    assert photo_light.focal_35mm(str(tmp_path / "tele.jpg")) == 85.0
    huge = tmp_path / "huge.jpg"
    huge.write_bytes(jpeg_bytes(declared=(20000, 20000)))
    assert photo_light.focal_35mm(str(huge)) is None  # Pillow's bomb error escaped before
