"""`relight image`: relight the person in a photo (or every photo in a folder).

    relight image PHOTO (--light HDR_OR_PRESET | --light-from PHOTO2) [--rotate DEG] [--exposure EV]
                  [--mask MASK | --matte person|network] [--person N] [--no-normalize] [--model PATH]
                  [--out OUT.png|OUT.exr]
                  [--layers] [--quality draft|balanced|best] [--refine N] [--json] [--threads N] [--max-pixels N]
    relight image DIR --light ... --out OUTDIR

A photo with an alpha channel uses it as the mask unless --mask is given;
otherwise the person segmenter (relight.person.matte) finds the person: the largest
one, or --person N (1 = largest). No person found: one line, exit 2.
Bad input is one line on stderr and a non-zero exit; nothing partial is
written (each output is written atomically, after everything succeeded).
In folder mode every photo is tried, failures are listed at the end and the
exit status is 1 if any failed.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

from relight.command.request import LightRequest, PhotoRequest

EXIT_FAILED = 1
# above this share of the person's pixels, clamping is visible: say so (the light is too sharp for the order)
NEGATIVE_WARN_FRACTION = 0.01


def register(subparsers) -> argparse.ArgumentParser:
    """Add the `image` sub-command to the `relight` command's subparsers."""
    from relight.command.request import add_relight_parser

    p = add_relight_parser(subparsers, "image", help="relight the person in a photo (or a folder of photos)",
                           description=__doc__.split("\n\n")[0], source="photo",
                           source_help="photo file (PNG/JPEG/TIFF/WebP/EXR) or a folder of them")
    p.add_argument("--out", default=None,
                   help="output .png (8-bit sRGB) or .exr (linear); a folder in folder mode "
                        "(default: PHOTO_relit.png beside the photo)")
    p.add_argument("--layers", action="store_true",
                   help="write a multi-layer EXR (Relit, Albedo, Shading, Residual, Alpha) for Blender")
    p.add_argument("--json", action="store_true",
                   help="print what was done to each photo (working size, augmentations, refinement, SH order, "
                        "residual) as one JSON line; the output file's metadata holds the same")
    p.set_defaults(func=run_image)
    return p


@dataclass(frozen=True)
class ImageRequest:
    """`relight image`'s parsed options, checked once at the command's edge (from_args): the photo or
    folder `source`, the output `out` (a file, or a folder in folder mode), and the light and photo
    options as values."""

    source: Path
    out: Path
    folder: bool
    layers: bool
    json: bool
    light: LightRequest
    photo: PhotoRequest

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> "ImageRequest":
        """The request of the parsed options; ValueError in one line for a photo that is not there or
        an output that cannot be written (argparse's types checked each option's value before)."""
        from relight.command.cli_output import check_folder_name
        from relight.command.request import relight_options
        from relight.files.fileio import same_file

        source = Path(args.photo)
        if not source.exists():
            raise ValueError(f"{source}: no such file or folder")
        folder = source.is_dir()
        if folder:
            if args.mask is not None:
                raise ValueError("--mask applies to one photo; in folder mode give each photo an alpha channel")
            if args.out is None:
                raise ValueError("folder mode needs --out OUTPUT_FOLDER")
            out = Path(args.out)
            if out.exists() and not out.is_dir():
                raise ValueError(f"--out {out} exists and is not a folder")
            if out.exists() and same_file(out, source):
                raise ValueError("--out must differ from the input folder")
            check_folder_name(out, "in folder mode, a folder of .png or .exr")
            if not out.parent.is_dir():
                raise ValueError(f"output folder does not exist: {out.parent}")
        elif args.out is None:  # beside the photo
            out = source.with_name(source.stem + "_relit" + (".exr" if args.layers else ".png"))
        else:
            out = Path(args.out)
            suffix = out.suffix.lower()
            if suffix not in (".png", ".exr"):
                raise ValueError(f"--out must end in .png or .exr, got {out.name}")
            if args.layers and suffix != ".exr":
                raise ValueError("--layers writes a multi-layer EXR: give --out NAME.exr")
            if not out.parent.is_dir():
                raise ValueError(f"output folder does not exist: {out.parent}")
        return cls(source, out, folder, args.layers, args.json, *relight_options(args))

    def inputs(self) -> dict:
        """The files the request reads ({what: path or None}): an output must be none of them."""
        return {"photo": self.source, "--light map": self.light.map_file, "--light-from photo": self.light.light_from,
                "--mask": self.photo.mask}


def record(request: ImageRequest, relighter, d) -> dict:
    """What was done to one photo (plain JSON values): the output's metadata and --json line."""
    stats = d.last_stats
    out = {"format": "relight-image/1", "model_sha256": relighter.sha256, "quality": request.photo.quality,
           "exposure_ev": request.light.exposure, **d.choices}
    if stats is not None:
        out["relight"] = {"sh_order": stats.sh_order, "residual": stats.residual,
                          "negative_clamped": round(stats.fraction, 6)}
        if request.photo.shadows:  # what the shadow pass did: the key that cast them, or why none
            out["relight"]["shadows"] = stats.shadow_key.as_json() if stats.shadow_key is not None else \
                "none (the light has no directional part)"
    return out


def _process(relighter, request: ImageRequest, photo_path: Path, out_path: Path, light, mask_path: str | None,
             read=None, named: bool = False) -> Path:
    """Read, decompose, relight (under `light`, a relight.lighting.light.CheckedLight: request's light,
    resolved once) and write one photo; nothing is written on failure. `read`: a future of
    read_photo_and_mask already under way (its errors are raised here). `named`: the core's refusals
    of the photo's content name its file (in folder mode the failure's line names it)."""
    import json

    from relight.command.request import decompose_photo, read_photo_and_mask
    from relight.files.photo import write_image, write_layers_exr

    image, mask = read.result() if read is not None else \
        read_photo_and_mask(photo_path, mask_path, request.photo.max_pixels)
    d, group = decompose_photo(relighter, image, mask, request.photo, photo_path if named else None)
    relit = (group or d).relight(light, shadows=request.photo.shadows)
    stats = d.last_stats
    done = record(request, relighter, d)
    if group is not None:
        done["people"] = group.record()
    metadata = {"relight": json.dumps(done, sort_keys=True)}
    if request.json:
        print(json.dumps(dict(done, photo=str(photo_path), output=str(out_path)), sort_keys=True))
    if stats is not None and stats.fraction > NEGATIVE_WARN_FRACTION:
        print(f"relight image: warning: {Path(out_path).name}: negative light (SH ringing) clamped to 0 "
              f"on {stats.fraction:.1%} of the person", file=sys.stderr)
    if request.layers:
        layers = d.layers(light)
        for other in group.people[1:] if group is not None else ():  # each zero outside its own matte
            for name, layer in other.layers(light).items():
                layers[name] += layer
        return write_layers_exr(out_path, relit, layers, metadata)
    return write_image(out_path, relit, metadata)


def run_image(args) -> int:
    """Entry point of `relight image` (argparse namespace from register()): its request built once,
    here, and only that request passed on."""
    from relight.command.cli_output import claim_output

    request = ImageRequest.from_args(args)
    with claim_output(request.out, "relight image", inputs=request.inputs()):
        return _run_folder(request) if request.folder else _run_photo(request)


def _run_photo(request: ImageRequest) -> int:
    """run_image for one photo, once the output is claimed."""
    from concurrent.futures import ThreadPoolExecutor

    from relight.command.request import read_photo_and_mask, relighter_and_light

    # the photo is decoded on a thread while the models load (both mostly outside the GIL);
    # its errors still come after the model's and the light's, as when read in turn. Not
    # beside --light-from's photo: two readers at once would race on the warnings filters
    reader = ThreadPoolExecutor(max_workers=1, thread_name_prefix="relight-read")
    try:
        read = reader.submit(read_photo_and_mask, request.source, request.photo.mask, request.photo.max_pixels) \
            if request.light.light_from is None else None
        relighter, light = relighter_and_light(request.light, request.photo)
        written = _process(relighter, request, request.source, request.out, light, request.photo.mask, read, named=True)
    finally:
        reader.shutdown(wait=False, cancel_futures=True)
    print(f"wrote {written}")
    return 0


def _run_folder(request: ImageRequest) -> int:
    """run_image for a folder of photos, once the output folder is claimed."""
    from relight.command.cli_output import Progress
    from relight.command.request import relighter_and_light
    from relight.files.photo import PHOTO_SUFFIXES

    relighter, light = relighter_and_light(request.light, request.photo)
    source, out_dir = request.source, request.out
    photos = sorted(p for p in source.iterdir() if p.is_file() and p.suffix.lower() in PHOTO_SUFFIXES)
    if not photos:
        raise ValueError(f"{source}: no photos ({', '.join(PHOTO_SUFFIXES)}) in the folder")
    out_dir.mkdir(exist_ok=True)
    suffix = ".exr" if request.layers else ".png"
    stems = [p.stem for p in photos]
    # a.jpg and a.png both present: keep the extension in the output names
    names = {p: (p.stem if stems.count(p.stem) == 1 else p.name.replace(".", "_")) + suffix for p in photos}
    failures: list[tuple[Path, str]] = []
    bar = Progress(len(photos), command="relight image", unit="photo")
    try:
        for photo in photos:
            try:
                _process(relighter, request, photo, out_dir / names[photo], light, None)
            except (ValueError, OSError, MemoryError) as exc:
                failures.append((photo, str(exc) or "out of memory"))
                bar.write(f"relight image: failed: {photo.name}: {exc}")
            bar.update(1)
    finally:
        bar.close()
    done = len(photos) - len(failures)
    print(f"relit {done} of {len(photos)} photos into {out_dir}")
    if failures:
        print(f"relight image: error: {len(failures)} of {len(photos)} photos failed: "
              + ", ".join(p.name for p, _ in failures), file=sys.stderr)
        return EXIT_FAILED
    return 0
