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
    """Write `source` resized to `size` (width, height), or to about `megapixels`, to the JPEG `out`
    (quality 92); returns the size written."""
    from PIL import Image

    with Image.open(source) as im:
        rgb = im.convert("RGB")
    if size is None:
        scale = (megapixels * 1e6 / (rgb.width * rgb.height)) ** 0.5
        size = (round(rgb.width * scale), round(rgb.height * scale))
    rgb.resize(size, Image.LANCZOS).save(out, quality=92)
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
