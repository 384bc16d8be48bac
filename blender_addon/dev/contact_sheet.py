"""Contact sheet of the add-on's output images, for docs/addon.md.

    python -m blender_addon.dev.contact_sheet [--model MODEL.onnx] [--out docs/images/addon_results.png]

Runs the add-on headless (bpy) exactly as the tests do: a synthetic photo of a
figure, the Relight operator in test mode with the 'sunset' preset, then the
rotation dial at 90 degrees. Tiles: photo, relit, relit rotated, albedo,
shading, residual, alpha (linear layers shown sRGB-encoded, clipped to 1).
Without --model it uses a seeded random-weight network (export.random_model):
the pictures then show the plumbing, not a trained model's quality.
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
TILE = 192


def _figure_png(path: Path, h: int = 288, w: int = 192) -> None:
    from PIL import Image

    y, x = np.mgrid[0:h, 0:w]
    head = ((x - w / 2) / (w / 10)) ** 2 + ((y - h * 0.16) / (h / 14)) ** 2 <= 1
    body = ((x - w / 2) / (w / 5)) ** 2 + ((y - h * 0.58) / (h / 2.6)) ** 2 <= 1
    rgb = np.empty((h, w, 3), np.uint8)
    rgb[..., 0] = 60 + (x // 12 % 2) * 30
    rgb[..., 1] = 80 + (y // 12 % 2) * 20
    rgb[..., 2] = 110
    rgb[body] = (70, 90, 160)
    rgb[head] = (225, 180, 150)
    Image.fromarray(rgb).save(path)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=None)
    parser.add_argument("--out", default=str(REPO / "docs" / "images" / "addon_results.png"))
    args = parser.parse_args(argv)

    import bpy
    from PIL import Image, ImageDraw

    import blender_addon
    from relight.imaging.colour import srgb_encode

    tmp = Path(tempfile.mkdtemp(prefix="contact_sheet_"))
    model = args.model
    if model is None:
        model = str(tmp / "random.onnx")
        code = ("from export.random_model import export_random_model; "
                f"export_random_model({model!r}, seed=3, sh_order=4, width=8, depth=3)")
        subprocess.run([sys.executable, "-c", code], cwd=REPO, check=True, capture_output=True)
    _figure_png(tmp / "photo.png")

    blender_addon.register()
    image = bpy.data.images.load(str(tmp / "photo.png"))
    settings = bpy.context.scene.relight_photo
    settings.model_path = model
    settings.light_kind = "PRESET"
    settings.preset = "sunset"
    settings.mask_mode = "NETWORK"  # a drawn figure: the person matte looks for real people
    if bpy.ops.relight_photo.relight(image_name=image.name, synchronous=True) != {"FINISHED"}:
        print("error: the Relight operator failed", file=sys.stderr)
        return 1

    def grab(name: str) -> np.ndarray:
        img = bpy.data.images[name]
        w, h = img.size
        flat = np.empty(w * h * 4, np.float32)
        img.pixels.foreach_get(flat)
        px = flat.reshape(h, w, 4)[::-1]
        if img.colorspace_settings.name == "sRGB" and not img.is_float:
            return px[..., :3]
        return srgb_encode(np.clip(px[..., :3], 0, 1))

    tiles = [("photo", grab(image.name)), ("relit", grab(f"{image.name}.relit"))]
    settings.rotation = math.radians(90.0)
    tiles.append(("relit, light +90 deg", grab(f"{image.name}.relit")))
    for layer in ("albedo", "shading", "residual", "alpha"):
        tiles.append((layer, grab(f"{image.name}.{layer}")))

    h0, w0 = tiles[0][1].shape[:2]
    scale = TILE / h0
    tw = round(w0 * scale)
    sheet = Image.new("RGB", (len(tiles) * (tw + 4) + 4, TILE + 24), (24, 24, 24))
    draw = ImageDraw.Draw(sheet)
    for i, (label, px) in enumerate(tiles):
        tile = Image.fromarray(np.rint(px * 255).astype(np.uint8)).resize((tw, TILE), Image.Resampling.LANCZOS)
        sheet.paste(tile, (4 + i * (tw + 4), 20))
        draw.text((6 + i * (tw + 4), 4), label, fill=(230, 230, 230))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    from relight.files.fileio import atomic_path

    with atomic_path(out, ".png") as partial:
        sheet.save(partial, optimize=True)
    print(f"wrote {out} ({out.stat().st_size // 1024} KiB, {len(tiles)} tiles)")
    blender_addon.unregister()
    return 0


if __name__ == "__main__":
    sys.exit(main())
