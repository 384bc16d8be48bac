"""Evaluate a shipped model on real photos: `python -m model.evaluate_photos MODEL.onnx --photos DIR --out DIR`.

Runs the torch-free runtime (relight.network.runtime), as a user would, on every
photo in DIR. Real photos have no ground truth, so the one number is the
reconstruction: the photo re-rendered from its own decomposition,
albedo * (T . L) + E . L with the predicted light L (negative values set to
0, as the runtime returns them), against the photo itself (linear, at the
network's working resolution, weighted by the matte: the file's alpha channel
when it has one, else the person segmenter's (relight.person.matte), else the
network's alpha head). A contact
sheet shows each photo relit under three bundled training presets, each at
0 and 180 degrees. Writes OUT/photos.md, OUT/photos.json and
OUT/contact_sheet.png, each atomically. Needs no torch.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from model.scoring import metrics
from model.scoring.report_cli import run_report
from relight.files import photo as photo_io
from relight.lighting import sh
from evaluation.sheet import LABEL_HEIGHT as _SHEET_LABEL_HEIGHT
from evaluation.sheet import contact_sheet as _contact_sheet
from evaluation.sheet import write_sheet
from relight.files.fileio import atomic_write_text
from relight.lighting.light import directional_light, sh_light
from relight.network import quality as quality_presets
from relight.network.runtime import Relighter

# a directional light turned about the person (relight.lighting.light.directional_light): a viewer
# should see it move across the body; then a training preset (not relight.lighting.presets.HELD_OUT),
# what a user would pick, at two rotations
SHEET_DIRECTIONS = (0.0, 90.0, 180.0, 270.0)
SHEET_PRESETS = ("sunset",)
SHEET_ROTATIONS = (0.0, 180.0)
EXAMPLES_DIR = Path(__file__).resolve().parent.parent / "relight" / "data" / "examples"
TILE = 192          # px: each contact-sheet image is fitted into a TILE x TILE box
GUTTER = 2
LABEL_HEIGHT = _SHEET_LABEL_HEIGHT  # px of the header row naming the columns
BACKDROP = 255      # sheet background (white)


@dataclass
class PhotoResult:
    name: str
    size: tuple[int, int]              # (H, W) of the photo
    working_size: tuple[int, int]      # (h, w) the network saw
    matte: str                         # "file alpha", "person segmenter" or the network's alpha
    coverage: float                    # mean matte over the crop the network saw
    light_luminance: float             # mean luminance of the predicted light
    light_motion: float                # metrics.spatial_change of the person, directional light 0 vs 180 deg
    backlight_ratio: float             # metrics.luminance_ratio of the person lit from 180 deg to lit from 0 deg
    colour_cast: float                 # metrics.colour_cast_deg: relit under white lights against the photo
    reconstruction: dict[str, float] | None  # l1, l2, psnr; None when the matte is empty
    tiles: list[np.ndarray]            # linear [H, W, 3] images for the contact sheet


def find_photos(folder) -> list[Path]:
    """Photo files of `folder` (relight.files.photo.PHOTO_SUFFIXES), sorted by name."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"photo folder not found: {folder}")
    found = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in photo_io.PHOTO_SUFFIXES)
    if not found:
        raise ValueError(f"no photos ({', '.join(photo_io.PHOTO_SUFFIXES)}) in {folder}")
    return found


def column_labels() -> list[str]:
    return (["input", "albedo"] + [f"light from {a:g} deg" for a in SHEET_DIRECTIONS]
            + [f"{p} {r:g} deg" for p in SHEET_PRESETS for r in SHEET_ROTATIONS])


def evaluate_photo(relighter: Relighter, path: Path, options: dict | None = None) -> PhotoResult:
    """Decompose one photo (`options`: Relighter.decompose's keywords, a quality preset's), measure
    its reconstruction and relight it for the sheet."""
    options = dict(options or {})
    image, file_mask = photo_io.read_photo(path)
    # as `relight image` does: the file's alpha, else the person segmenter's matte; where it
    # finds nobody or cannot run (a test card, an image under 32 px), the network's alpha head
    source = "file alpha" if file_mask is not None else "person segmenter"
    try:
        dec = relighter.decompose(image, mask=file_mask, matte="person", **options)
    except ValueError:  # relight.person.matte.NoPersonError, or too small for the segmenter
        options.pop("matte_method", None)
        dec, source = relighter.decompose(image, matte="network", **options), "network alpha (no person found)"
    # the network's own resolution: the full-resolution result borrows the photo's
    # detail (runtime docstring), which would flatter a reconstruction measured there
    rerendered = dec.relit_at_working_size(dec.light)
    try:
        recon = metrics.all_metrics(rerendered, dec.photo_working, dec.alpha)
    except ValueError:  # empty matte: the network found no person
        recon = None
    # as it composites over black: the layer runs past the matte (its grown ring) for the alpha to cut
    albedo = dec.layer("albedo") * dec.layer("alpha")[..., None]
    tiles = [image, albedo]
    working = {}
    for azimuth in SHEET_DIRECTIONS:
        light = directional_light(azimuth, dec.sh_order)
        tiles.append(dec.relight(light))
        working[azimuth] = dec.relit_at_working_size(light)
    motion = metrics.spatial_change(working[0.0], working[180.0], dec.alpha) if dec.alpha.any() else 0.0
    backlight = metrics.luminance_ratio(working[180.0], working[0.0], dec.alpha) if dec.alpha.any() else float("nan")
    cast = (float(np.mean([metrics.colour_cast_deg(working[a], dec.photo_working, dec.alpha) for a in working]))
            if dec.alpha.any() else float("nan"))
    for name in SHEET_PRESETS:
        for rotation in SHEET_ROTATIONS:
            tiles.append(dec.relight(sh_light(name, dec.sh_order, rotation_deg=rotation)))
    return PhotoResult(
        name=path.name, size=image.shape[:2], working_size=dec.working_size,
        matte=source,
        coverage=float(dec.alpha.mean()), light_luminance=float(sh.mean_luminance(dec.light)),
        light_motion=motion, backlight_ratio=backlight, colour_cast=cast,
        reconstruction=recon, tiles=tiles)


def contact_sheet(rows: list[list[np.ndarray]], labels: list[str] | None = None, tile: int = TILE) -> np.ndarray:
    """uint8 sheet: one row of linear images per photo, each fitted into a tile; optional header."""
    return _contact_sheet(rows, tile=tile, gutter=GUTTER, backdrop=BACKDROP, labels=labels)


def markdown_table(results: list[PhotoResult], model: str, working: int) -> str:
    note = ("Reconstruction: the photo re-rendered from its own decomposition, albedo * (T . L) + E . L "
            "with the *predicted* light L (clamped at 0 as the runtime returns it), against the photo; "
            "linear values at the network's working resolution (crop around the person, longest side "
            f"{working} px), each pixel weighted by the matte (the file's alpha, else the person "
            "segmenter's, else the network's). L1 and L2 "
            "x100, PSNR in dB with peak 1.0 (model/scoring/metrics.py). No ground truth exists for these photos: "
            "this measures self-consistency, not relighting accuracy.")
    lines = [f"# Real photos (`{model}`)", "", note, "",
             "| photo | size | matte | matte coverage | light mean luminance | light motion | backlight ratio "
             "| colour cast deg | L1 | L2 | PSNR |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        m = r.reconstruction
        cells = ["-", "-", "- (empty matte)"] if m is None else \
            [f"{100 * m['l1']:.2f}", f"{100 * m['l2']:.3f}", f"{m['psnr']:.2f}"]
        lines.append(f"| {r.name} | {r.size[1]}x{r.size[0]} | {r.matte} | {100 * r.coverage:.0f}% | "
                     f"{r.light_luminance:.3f} | {r.light_motion:.3f} | {r.backlight_ratio:.3f} | "
                     f"{r.colour_cast:.1f} | "
                     + " | ".join(cells) + " |")
    measured = [r.reconstruction for r in results if r.reconstruction is not None]
    if len(measured) > 1:
        means = {k: float(np.mean([m[k] for m in measured])) for k in ("l1", "l2", "psnr")}
        motion = float(np.mean([r.light_motion for r in results]))
        cast = float(np.nanmean([r.colour_cast for r in results]))
        backlight = float(np.nanmean([r.backlight_ratio for r in results]))
        lines.append(f"| mean of {len(measured)} | | | | | {motion:.3f} | {backlight:.3f} | {cast:.1f} | "
                     f"{100 * means['l1']:.2f} | "
                     f"{100 * means['l2']:.3f} | {means['psnr']:.2f} |")
    lines += ["", "Light motion: model.scoring.metrics.spatial_change of the relit person (working resolution, "
              "weighted by the matte) between a directional light at 0 and at 180 degrees "
              "(relight.lighting.light.directional_light), after per-channel gains; `python -m model.evaluate` prints the "
              "same number for ground-truth renders of held-out scenes.", "",
              "Backlight ratio: model.scoring.metrics.luminance_ratio of the relit person's mean luminance lit "
              "from behind (180 degrees) to lit from the camera's side (0 degrees); `python -m "
              "model.evaluate` prints it for ground-truth renders too.", "",
              "Colour cast: model.scoring.metrics.colour_cast_deg, the angle between the person's mean colour "
              "relit under the four white directional lights and in the photo (0: colours kept up to "
              "exposure).", "",
              "Contact sheet columns: " + ", ".join(column_labels()) +
              " (the directional light is white, 30 degrees up, with 20% ambient; presets are bundled "
              "training maps; all lights scaled to mean luminance 0.8; rotations turn the light about the "
              "vertical axis)."]
    return "\n".join(lines) + "\n"


def evaluate_photos(model_path, photos, out, *, quality: str = "balanced", working_size: int | None = None,
                    threads: int | None = None, tile: int = TILE,
                    sheet_name: str = "contact_sheet.png") -> list[PhotoResult]:
    """Evaluate `model_path` on `photos` (a folder or a list of files); write the files into `out`.
    `working_size` (px) replaces the quality preset's."""
    paths = find_photos(photos) if isinstance(photos, (str, Path)) else [Path(p) for p in photos]
    if not paths:
        raise ValueError("no photos to evaluate")
    if not isinstance(tile, int) or not 16 <= tile <= 2048:
        raise ValueError(f"tile must be an integer in [16, 2048], got {tile!r}")
    size = quality_presets.preset(quality).working_size if working_size is None else working_size
    relighter = Relighter(model_path, threads=threads, working_size=size)
    options = quality_presets.preset(quality).decompose_options()
    options["working_size"] = size  # the preset's test-time work, at the size asked for
    results = [evaluate_photo(relighter, p, options) for p in paths]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_sheet(out / sheet_name, contact_sheet([r.tiles for r in results], column_labels(), tile))
    model_label = Path(model_path).name
    atomic_write_text(out / "photos.md", markdown_table(results, model_label, relighter.working_size))
    record = {"model": str(model_path), "model_sha256": relighter.sha256, "working_size": relighter.working_size,
              "presets": list(SHEET_PRESETS), "rotations_deg": list(SHEET_ROTATIONS),
              "photos": [{"name": r.name, "size": list(r.size), "working_size": list(r.working_size),
                          "matte": r.matte, "coverage": r.coverage, "light_mean_luminance": r.light_luminance,
                          "light_motion": r.light_motion, "backlight_ratio": r.backlight_ratio,
                          "colour_cast_deg": r.colour_cast,
                          "reconstruction": r.reconstruction} for r in results]}
    atomic_write_text(out / "photos.json", json.dumps(record, indent=1) + "\n")
    return results


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m model.evaluate_photos", description=__doc__.splitlines()[0])
    p.add_argument("model", help="ONNX model (with its .sha256 beside it, or registered)")
    p.add_argument("--photos", default=str(EXAMPLES_DIR),
                   help="folder of photos (default: the bundled relight/data/examples)")
    p.add_argument("--out", default="evaluation_photos", help="output folder (default: ./evaluation_photos)")
    p.add_argument("--quality", choices=[q.key for q in quality_presets.PRESETS], default="balanced",
                   help="working resolution, as `relight --quality` (relight/network/quality.py; default balanced, "
                        f"{quality_presets.preset('balanced').working_size} px)")
    p.add_argument("--threads", type=int, default=None, help="onnxruntime threads (default: all cores)")
    p.add_argument("--tile", type=int, default=TILE, help=f"contact-sheet tile side in px (default {TILE})")
    args = p.parse_args(argv)
    return run_report(
        "model.evaluate_photos",
        lambda: evaluate_photos(args.model, Path(args.photos), args.out, quality=args.quality,
                                threads=args.threads, tile=args.tile),
        Path(args.out) / "photos.md",
        lambda results: f"{len(results)} photos; wrote {args.out}/photos.md, photos.json, contact_sheet.png")


if __name__ == "__main__":
    sys.exit(main())
