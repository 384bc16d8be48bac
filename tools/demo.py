"""`make demo`: the main job on a bundled example, and where its output is.

With a shipped model (relight/models/models.json names a default) it
relights the bundled real photo relight/data/examples/astronaut.jpg with
that model (python -m model.evaluate_photos, torch-free): out/demo/
contact_sheet.png shows the photo, its albedo and the person relit by a
directional light from 0, 90, 180 and 270 degrees and by a preset at 0 and
180 degrees; out/demo/photos.md holds the reconstruction and light-motion
numbers. out/demo/faces_sheet.png (issue 37) shows the three bundled real
photos (astronaut, grace_hopper, obama_standing) relit the same way, a
directional white light from 0, 90, 180 and 270 degrees and two presets
(sunset, studio), each photo's row followed by a row of zooms on its face
(the face box: the head of the person matte, `face_box`). While no model is registered it says so and runs
the smallest real farm job instead (one posed, clothed human, path-traced
and baked), relighting that scene's ground-truth decomposition,
albedo * (T . L'), under the presets, next to Cycles' own render.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path


ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "out" / "demo"
PRESETS = ("sunset", "studio", "forest")  # training maps, as model.evaluate_photos.SHEET_PRESETS
EXAMPLE_PHOTO = ROOT / "relight" / "data" / "examples" / "astronaut.jpg"
FACE_PHOTOS = (EXAMPLE_PHOTO, ROOT / "relight" / "data" / "examples" / "grace_hopper.jpg",
               ROOT / "evaluation" / "data" / "matte_eval" / "obama_standing.jpg")
FACE_DIRECTIONS = (0.0, 90.0, 180.0, 270.0)
FACE_PRESETS = ("sunset", "studio")
FACE_TILE = 224


def face_box(matte, threshold: float = 0.5) -> tuple[int, int, int, int]:
    """(y0, y1, x0, x1) of a square around the head of a person matte [H, W]. The neck is the row
    of the matte's top half whose width is smallest against the widest row above it (the head
    narrows into the neck, the shoulders then widen past the head); the head is the matte from
    its top row to the neck, and the box a square of 1.25 x the head's size about its centre. A
    heuristic for upright people (the photos here), not a face detector."""
    import numpy as np

    m = np.asarray(matte) > threshold
    rows = np.flatnonzero(m.any(axis=1))
    if rows.size == 0:
        raise ValueError("face_box: empty matte")
    top, bottom = int(rows[0]), int(rows[-1]) + 1
    widths = m.sum(axis=1).astype(np.float64)
    k = max(1, (bottom - top) // 40)
    smooth = np.convolve(widths, np.ones(2 * k + 1) / (2 * k + 1), mode="same")
    start, stop = top + max(3, (bottom - top) // 20), top + (bottom - top) // 2
    ratio = smooth[start:stop] / np.maximum.accumulate(smooth[top:stop])[start - top:]
    neck = start + int(np.argmin(ratio)) if stop > start else bottom
    cols = np.flatnonzero(m[top:neck].any(axis=0))
    cy, cx = 0.5 * (top + neck), 0.5 * (cols[0] + cols[-1] + 1)
    half = 0.625 * max(neck - top, cols[-1] + 1 - cols[0])
    h, w = m.shape
    return max(int(cy - half), 0), min(int(cy + half), h), max(int(cx - half), 0), min(int(cx + half), w)


def faces_sheet(model: Path, quality: str = "balanced") -> Path:
    """out/demo/faces_sheet.png: per photo, a row of the photo relit (input, a white directional
    light from FACE_DIRECTIONS, FACE_PRESETS) and a row of the same cut to its face box."""
    from evaluation import sheet
    from relight.files import photo as photo_io
    from relight.network import quality as presets
    from relight.lighting.light import directional_light, sh_light
    from relight.network.runtime import Relighter

    preset = presets.preset(quality)
    relighter = Relighter(model, working_size=preset.working_size)
    rows = []
    for path in FACE_PHOTOS:
        image, file_mask = photo_io.read_photo(path)
        dec = relighter.decompose(image, mask=file_mask, **preset.decompose_options())
        lights = [directional_light(a, dec.sh_order) for a in FACE_DIRECTIONS]
        lights += [sh_light(name, dec.sh_order) for name in FACE_PRESETS]
        tiles = [image] + [dec.relight(light) for light in lights]
        y0, y1, x0, x1 = face_box(dec.mask if dec.mask is not None else dec.layer("alpha"))
        rows += [tiles, [t[y0:y1, x0:x1] for t in tiles]]
        print(f"  {path.name}: face box rows {y0}-{y1}, columns {x0}-{x1}", flush=True)
    labels = (["input"] + [f"white light {a:g} deg" for a in FACE_DIRECTIONS] + list(FACE_PRESETS))
    return sheet.write_sheet(OUT / "faces_sheet.png",
                             sheet.contact_sheet(rows, tile=FACE_TILE, gutter=2, backdrop=255, labels=labels))


def relight_photo(model: Path) -> list[Path]:
    from model import evaluate_photos

    print(f"relighting {EXAMPLE_PHOTO.relative_to(ROOT)} with {model}", flush=True)
    evaluate_photos.evaluate_photos(model, [EXAMPLE_PHOTO], OUT, tile=256)
    return [OUT / "contact_sheet.png", OUT / "photos.md", OUT / "photos.json"]


def relight_farm_scene() -> list[Path]:
    from evaluation import sheet
    from relight.files import dataset, photo
    from relight.lighting import light
    from relight.network import prt

    scenes = OUT / "scenes"
    cmd = [sys.executable, "-m", "farm", "--out", str(scenes), "--scenes", "1", "--seed", "7",
           "--res", "192", "--lights", "1", "--samples", "32", "--workers", "1", "--resume"]
    print("rendering one scene:", " ".join(cmd[1:]), flush=True)
    subprocess.run(cmd, check=True, cwd=ROOT)
    scene = dataset.read_scene(dataset.list_finished_scenes(scenes)[0])
    a = scene.alpha
    tiles = [scene.images[0], scene.prt[0] * a]  # Cycles vs albedo * (T . L), same light
    outs = []
    for name in PRESETS:
        L = light.sh_light(name, scene.sh_order)
        relit = prt.render(scene.albedo, scene.transport, None, L) * a
        outs.append(photo.write_png(OUT / f"scene_{name}.png", relit))
        tiles.append(relit)
    outs.append(sheet.write_sheet(OUT / "contact_sheet.png", sheet.contact_sheet([tiles], gutter=4, backdrop=0)))
    return outs


def main() -> int:
    from relight import models

    OUT.mkdir(parents=True, exist_ok=True)
    try:
        model = models.default_model_path()
    except ValueError:
        model = None
        print("no default model is registered in relight/models/models.json: relighting a "
              "rendered farm scene's ground-truth decomposition instead of the bundled photo", flush=True)
    outs = relight_photo(model) + [faces_sheet(model)] if model else relight_farm_scene()
    print("\nwrote:")
    for p in outs:
        print("  ", p.relative_to(ROOT))
    if model is None:
        print("contact sheet: Cycles path-traced | albedo*(T.L) | relit under " + ", ".join(PRESETS))
    else:
        from model import evaluate_photos

        print("contact sheet: " + " | ".join(evaluate_photos.column_labels()))
        print("faces sheet: per photo a row relit (input | white light from 0, 90, 180, 270 deg | "
              + " | ".join(FACE_PRESETS) + ") and a row of zooms on its face")
    return 0


if __name__ == "__main__":
    sys.exit(main())
