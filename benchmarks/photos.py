"""The photos the benchmarks make: a bundled photo enlarged (Pillow, Lanczos) to a size, saved as a JPEG."""

from __future__ import annotations

import argparse
import contextlib
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ASTRONAUT = REPO / "relight" / "data" / "examples" / "astronaut.jpg"


def enlarged_photo(out: Path, *, megapixels: float | None = None, size: tuple[int, int] | None = None,
                   source: Path = ASTRONAUT) -> tuple[int, int]:
    """Write `source` enlarged to about `megapixels`, or to cover `size` (width, height) and
    centre-cropped to it (its aspect kept), to the JPEG `out` (quality 92); returns the size written."""
    from PIL import Image

    with Image.open(source) as im:
        rgb = im.convert("RGB")
    if size is None:
        scale = (megapixels * 1e6 / (rgb.width * rgb.height)) ** 0.5
        size = cover = (round(rgb.width * scale), round(rgb.height * scale))
    else:
        scale = max(size[0] / rgb.width, size[1] / rgb.height)
        cover = (round(rgb.width * scale), round(rgb.height * scale))
    big = rgb.resize(cover, Image.Resampling.LANCZOS)
    x0, y0 = (big.width - size[0]) // 2, (big.height - size[1]) // 2
    big.crop((x0, y0, x0 + size[0], y0 + size[1])).save(out, quality=92)
    return size


def megapixels_parser(doc: str, megapixels: float) -> argparse.ArgumentParser:
    """A benchmark's argument parser (its docstring's first paragraph) with --megapixels, the photo's size."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("--megapixels", type=float, default=megapixels)
    return parser


@contextlib.contextmanager
def photo_in_temporary_folder(prefix: str, megapixels: float):
    """(folder, photo path, (width, height)): the astronaut enlarged to `megapixels` in a temporary
    folder, removed on leaving."""
    with tempfile.TemporaryDirectory(prefix=prefix) as folder:
        path = Path(folder) / "photo.jpg"
        yield Path(folder), path, enlarged_photo(path, megapixels=megapixels)
