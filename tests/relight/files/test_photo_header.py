"""relight.files.photo_header: a photo file's header read once (size, format, orientation, focal
length), and what is wrong with a file as one error of its kind that names the file (issue 49)."""

from __future__ import annotations

import builtins
import struct
import zlib

import numpy as np
import pytest
from PIL import Image

from fuzz_support import jpeg_bytes, png_bytes
from relight.files import image_limits, photo
from relight.files.exr import write_exr
from relight.files.image_limits import ImageSizeError
from relight.files.photo_header import ImageDamaged, ImageNotFound, ImageUnreadable, NotAnImage, read_header


def _jpeg(path, *, orientation=None, focal=None, size=(20, 12)):
    exif = Image.Exif()
    if orientation is not None:
        exif[0x0112] = orientation
    if focal is not None:
        exif.get_ifd(0x8769)[0xA405] = focal
    rng = np.random.default_rng(0)
    Image.fromarray(rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)).save(path, exif=exif)
    return path


def _png_with_exif_after_the_pixels(path, orientation: int, focal: int | None = None):
    """An 8-bit PNG whose eXIf chunk follows its IDAT (Pillow finds it only by decoding the pixels)."""
    exif = Image.Exif()
    exif[0x0112] = orientation
    if focal is not None:
        exif.get_ifd(0x8769)[0xA405] = focal
    tiff = exif.tobytes()[6:] if exif.tobytes().startswith(b"Exif\x00\x00") else exif.tobytes()
    png = png_bytes(6, 10)
    chunk = struct.pack(">I", len(tiff)) + b"eXIf" + tiff + struct.pack(">I", zlib.crc32(b"eXIf" + tiff))
    path.write_bytes(png[:-12] + chunk + png[-12:])
    return path


def _count_decoders(monkeypatch) -> list:
    """A list that grows by one each time Pillow makes a decoder (one per tile of a decoded image:
    these files have one tile)."""
    made, real = [], Image._getdecoder
    monkeypatch.setattr(Image, "_getdecoder", lambda *a, **k: made.append(a[0]) or real(*a, **k))
    return made


def _raises(kind, path, **kwargs):
    """The error read_header raises for `path`: of `kind`, its message one line naming the file."""
    with pytest.raises(kind) as caught:
        read_header(path, **kwargs)
    exc = caught.value
    assert isinstance(exc, image_limits.ImageFileError) and isinstance(exc, ValueError)
    assert str(path) in str(exc) and "\n" not in str(exc)
    assert str(exc.path) == str(path)
    return exc


# ------------------------------------------------------------------ what a header says


def test_size_format_and_length_of_each_kind_of_file(tmp_path):
    jpeg = _jpeg(tmp_path / "p.jpg")
    png = tmp_path / "p.png"
    png.write_bytes(png_bytes(6, 10))
    exr = tmp_path / "p.exr"
    write_exr(exr, {c: np.full((5, 9), 0.5, np.float32) for c in "RGB"})
    for path, size, fmt in ((jpeg, (20, 12), "JPEG"), (png, (10, 6), "PNG"), (exr, (9, 5), "EXR")):
        header = read_header(path)
        assert (header.width, header.height, header.format) == (*size, fmt)
        assert header.file_bytes == path.stat().st_size and header.path == path
        assert header.orientation == 1 and header.focal_35mm is None and header.upright_size == size


@pytest.mark.parametrize("orientation", range(1, 9))
def test_orientation_and_the_upright_size(tmp_path, orientation):
    header = read_header(_jpeg(tmp_path / "o.jpg", orientation=orientation))
    assert header.orientation == orientation and (header.width, header.height) == (20, 12)
    assert header.upright_size == ((12, 20) if orientation >= 5 else (20, 12))
    # the pixels read_photo returns stand as the header says
    rgb, _, same = photo.read_photo_with_header(tmp_path / "o.jpg")
    assert same == header and rgb.shape[:2] == header.upright_size[::-1]


def test_an_orientation_outside_1_to_8_is_none(tmp_path):
    assert read_header(_jpeg(tmp_path / "o.jpg", orientation=9)).orientation == 1


def test_a_pngs_exif_after_its_pixels_is_read_without_decoding_them(tmp_path, monkeypatch):
    """Pillow's getexif decodes a PNG to find an eXIf chunk after IDAT; the header reader walks
    the chunk headers instead (exif_orientation decoded the whole PNG before)."""
    path = _png_with_exif_after_the_pixels(tmp_path / "late.png", 6, focal=35)
    decodes = _count_decoders(monkeypatch)
    header = read_header(path)
    assert (header.orientation, header.focal_35mm, header.upright_size) == (6, 35.0, (6, 10))
    assert photo.exif_orientation(path) == 6
    assert decodes == []
    rgb, _, _ = photo.read_photo_with_header(path)
    assert len(decodes) == 1 and rgb.shape[:2] == (10, 6)


@pytest.mark.parametrize("focal, expected", [(28, 28.0), (None, None), (0, None), (5000, None)])
def test_the_focal_length_when_present_and_none_when_absent_unknown_or_absurd(tmp_path, focal, expected):
    """EXIF FocalLengthIn35mmFilm; 0 means "unknown" in EXIF; a value over 2000 mm is no lens."""
    assert read_header(_jpeg(tmp_path / "f.jpg", focal=focal)).focal_35mm == expected


def test_a_file_without_exif_has_no_focal_length_and_stands_as_stored(tmp_path):
    path = tmp_path / "plain.png"
    path.write_bytes(png_bytes(4, 4))
    header = read_header(path)
    assert header.focal_35mm is None and header.orientation == 1


# ------------------------------------------------------------------ one read per photo


def test_read_photo_opens_and_decodes_the_file_once(tmp_path, monkeypatch):
    """The header read_photo weighs, turns the pixels by and returns is read in the same open as the
    pixels: Image.open once, one decode (the PNG's EXIF after its pixels included)."""
    path = _png_with_exif_after_the_pixels(tmp_path / "once.png", 8)
    opens, real_open = [], Image.open
    monkeypatch.setattr(Image, "open", lambda *a, **k: opens.append(a[0]) or real_open(*a, **k))
    decodes = _count_decoders(monkeypatch)
    rgb, _, header = photo.read_photo_with_header(path)
    assert len(opens) == 1 and len(decodes) == 1
    assert header.orientation == 8 and rgb.shape[:2] == (10, 6)


# ------------------------------------------------------------------ what is wrong, naming the file


def test_missing_file(tmp_path):
    _raises(ImageNotFound, tmp_path / "gone.jpg")


def test_empty_file_a_folder_and_a_text_file_are_not_images(tmp_path):
    (tmp_path / "empty.png").write_bytes(b"")
    (tmp_path / "folder.png").mkdir()
    (tmp_path / "notes.jpg").write_text("these are notes, not a photo\n")
    assert "file is empty" in str(_raises(NotAnImage, tmp_path / "empty.png"))
    assert "not a file" in str(_raises(NotAnImage, tmp_path / "folder.png"))
    assert "not a readable image" in str(_raises(NotAnImage, tmp_path / "notes.jpg"))


def test_a_file_the_system_refuses_to_read(tmp_path, monkeypatch):
    """The tests run as root (chmod would not stop them): the open itself is refused."""
    path = _jpeg(tmp_path / "locked.jpg")
    real_open = builtins.open

    def refusing(file, *args, **kwargs):
        if str(file) == str(path):
            raise PermissionError(13, "Permission denied", str(file))
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", refusing)
    assert "Permission denied" in str(_raises(ImageUnreadable, path))


@pytest.mark.parametrize("cut", [8, 30])
def test_a_jpeg_cut_inside_its_header_is_damaged(tmp_path, cut):
    path = tmp_path / "cut.jpg"
    path.write_bytes(jpeg_bytes()[:cut])
    _raises(ImageDamaged, path)


def test_a_png_chunk_past_the_end_of_the_file_is_damaged(tmp_path):
    path = tmp_path / "cut.png"
    path.write_bytes(png_bytes(8, 8)[:-30])
    assert "past the end" in str(_raises(ImageDamaged, path))


def test_an_exr_cut_inside_its_header_is_damaged(tmp_path):
    whole = tmp_path / "whole.exr"
    write_exr(whole, {c: np.zeros((4, 4), np.float32) for c in "RGB"})
    path = tmp_path / "cut.exr"
    path.write_bytes(whole.read_bytes()[:40])
    _raises(ImageDamaged, path)


def test_sizes_over_the_limits(tmp_path, monkeypatch):
    """Each refusal of a size says which limit and carries the numbers a caller words otherwise."""
    bomb = tmp_path / "bomb.jpg"
    bomb.write_bytes(jpeg_bytes(declared=(20000, 20000)))  # over Pillow's own limit: its count alone
    exc = _raises(ImageSizeError, bomb)
    assert (exc.limit, exc.width, exc.height, exc.pixels) == ("pixels", None, None, 400_000_000)
    wide = tmp_path / "wide.jpg"
    wide.write_bytes(jpeg_bytes(declared=(10, 45_000)))
    exc = _raises(ImageSizeError, wide)
    assert (exc.limit, exc.width, exc.height) == ("side", 45_000, 10)
    forged = tmp_path / "forged.jpg"
    forged.write_bytes(jpeg_bytes(declared=(3000, 4000)))  # 12 MP in a few hundred bytes
    exc = _raises(ImageSizeError, forged)
    assert (exc.limit, exc.width, exc.height, exc.file_bytes, exc.fmt) == (
        "file", 4000, 3000, forged.stat().st_size, "JPEG")
    read_header(forged, 12_000_000)  # an explicit limit allows what the file cannot hold...
    _raises(ImageSizeError, forged, max_pixels=12_000_000, weigh_file_size=True)  # ...unless told to weigh it
    exc = _raises(ImageSizeError, forged, max_pixels=11_999_999)
    assert (exc.limit, exc.pixels, exc.max_pixels) == ("pixels", 12_000_000, 11_999_999)
    monkeypatch.setattr(image_limits, "memory_available", lambda: 10 * 2**20)
    exc = _raises(ImageSizeError, forged, max_pixels=12_000_000)
    assert (exc.limit, exc.need_bytes, exc.free_bytes) == ("memory", 12_000_000 * image_limits.BYTES_PER_PIXEL,
                                                           10 * 2**20)
    assert read_header(forged, weigh=False).width == 4000  # not weighed: the facts alone


def test_read_photo_raises_the_same_errors(tmp_path):
    """`relight image`'s reader refuses through the header reader: the same kinds and lines."""
    (tmp_path / "notes.png").write_text("notes")
    forged = tmp_path / "forged.jpg"
    forged.write_bytes(jpeg_bytes(declared=(3000, 4000)))
    for path, kind in ((tmp_path / "gone.png", ImageNotFound), (tmp_path / "notes.png", NotAnImage),
                       (forged, ImageSizeError)):
        with pytest.raises(kind) as from_photo:
            photo.read_photo(path)
        assert str(from_photo.value) == str(_raises(kind, path))


def test_pixels_cut_short_after_a_whole_header_are_damaged_when_decoded(tmp_path):
    path = tmp_path / "half.jpg"
    data = jpeg_bytes(64, 64)
    path.write_bytes(data[: len(data) // 2])
    assert read_header(path).width == 64  # the header is whole
    with pytest.raises(ImageDamaged, match=f"^{path}: corrupt or truncated image"):
        photo.read_photo(path)

