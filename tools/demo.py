"""`make demo`: the main job on a bundled example, and where its output is.

With a shipped model (relight/models/models.json names a default) it
relights the bundled real photo relight/data/examples/astronaut.jpg with
that model (python -m model.evaluate_photos, torch-free): out/demo/
contact_sheet.png shows the photo, its albedo and the person relit by a
directional light from 0, 90, 180 and 270 degrees and by a preset at 0 and
180 degrees; out/demo/photos.md holds the reconstruction and light-motion
numbers. While no model is registered it says so and runs
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


def relight_photo(model: Path) -> list[Path]:
    from model import evaluate_photos

    print(f"relighting {EXAMPLE_PHOTO.relative_to(ROOT)} with {model}", flush=True)
    evaluate_photos.evaluate_photos(model, [EXAMPLE_PHOTO], OUT, tile=256)
    return [OUT / "contact_sheet.png", OUT / "photos.md", OUT / "photos.json"]


def relight_farm_scene() -> list[Path]:
    from evaluation import sheet
    from relight import dataset, light, photo, prt

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
    outs = relight_photo(model) if model else relight_farm_scene()
    print("\nwrote:")
    for p in outs:
        print("  ", p.relative_to(ROOT))
    if model is None:
        print("contact sheet: Cycles path-traced | albedo*(T.L) | relit under " + ", ".join(PRESETS))
    else:
        from model import evaluate_photos

        print("contact sheet: " + " | ".join(evaluate_photos.column_labels()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
