"""Contact sheets: rows of linear images as one sRGB 8-bit picture (evaluations, demo, docs).

    sheet = contact_sheet([[photo, relit], [photo2, relit2]], tile=192, labels=["photo", "relit"])
    write_sheet("out/contact_sheet.png", sheet)

With `tile`, each image is scaled (area filter) to fit a tile x tile cell and
centred on the backdrop; without, cells are the largest image's size and each
image sits in its cell's top-left corner at its own size. Linear values are
clipped to [0, 1] and sRGB-encoded (relight.imaging.colour).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from relight.imaging.colour import srgb_encode

__all__ = ["contact_sheet", "write_sheet"]

LABEL_HEIGHT = 14  # px of the header row naming the columns, when there are labels


def _srgb8(linear: np.ndarray) -> np.ndarray:
    return np.rint(srgb_encode(np.clip(linear, 0.0, 1.0)) * 255.0).astype(np.uint8)


def _cell(linear: np.ndarray, tile: int | None, backdrop: int) -> np.ndarray:
    if tile is None:
        return _srgb8(linear)
    from relight.imaging.resample import resize_linear

    h, w = linear.shape[:2]
    s = tile / max(h, w)
    th, tw = max(1, round(h * s)), max(1, round(w * s))
    out = np.full((tile, tile, 3), backdrop, np.uint8)
    y, x = (tile - th) // 2, (tile - tw) // 2
    out[y:y + th, x:x + tw] = _srgb8(resize_linear(np.clip(linear, 0.0, 1.0), th, tw))
    return out


def contact_sheet(rows: list[list[np.ndarray]], *, tile: int | None = None, gutter: int = 2,
                  backdrop: int = 255, labels: list[str] | None = None) -> np.ndarray:
    """uint8 [H, W, 3]: one row of linear [h, w, 3] images per entry of `rows`, a
    `gutter` px gap right of and below every cell; `labels` name the columns."""
    cells = [[_cell(np.asarray(img, np.float32), tile, backdrop) for img in row] for row in rows]
    ch = max(c.shape[0] for row in cells for c in row)
    cw = max(c.shape[1] for row in cells for c in row)
    cols = max(len(r) for r in rows)
    top = LABEL_HEIGHT if labels else 0
    sheet = np.full((top + len(rows) * (ch + gutter), cols * (cw + gutter), 3), backdrop, np.uint8)
    for i, row in enumerate(cells):
        for j, c in enumerate(row):
            y, x = top + i * (ch + gutter), j * (cw + gutter)
            sheet[y:y + c.shape[0], x:x + c.shape[1]] = c
    if labels:
        from PIL import Image, ImageDraw

        canvas = Image.fromarray(sheet)
        draw = ImageDraw.Draw(canvas)
        for j, text in enumerate(labels[:cols]):
            draw.text((j * (cw + gutter) + 2, 1), text, fill=(0, 0, 0))
        sheet = np.asarray(canvas)
    return sheet


def write_sheet(path, sheet: np.ndarray) -> Path:
    """The uint8 sheet as a PNG, written atomically."""
    from PIL import Image

    from relight.files.fileio import atomic_path

    with atomic_path(path, ".png") as tmp:
        Image.fromarray(sheet, "RGB").save(tmp, format="PNG", compress_level=6)
    return Path(path)
