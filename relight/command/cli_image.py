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
import math
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np

EXIT_FAILED = 1
# largest SH coefficient (after exposure) relit in float32: shading sums (order+1)^2 terms and the
# detail ratio divides by 1e-3, so results stay far below float32's 3.4e38 (a 3e38 map with
# --no-normalize would overflow: refused, like any light that bright)
LIGHT_LIMIT = 1e18


def register(subparsers) -> argparse.ArgumentParser:
    """Add the `image` sub-command to the `relight` command's subparsers."""
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


def add_relight_parser(subparsers, name: str, *, help: str, description: str, source: str,
                       source_help: str) -> argparse.ArgumentParser:
    """The parser of a sub-command that relights a person (`image`, `video`): what it reads
    (`source`), then the light options and the photo options."""
    p = subparsers.add_parser(name, help=help, description=description)
    p.add_argument(source, help=source_help)
    add_light_options(p)
    add_photo_options(p)
    return p


def add_light_options(p) -> None:
    """The options that say what light to relight with (`image`, `video`): --light or
    --light-from, --rotate, --exposure, --no-normalize."""
    from relight.command.cli_args import exposure_ev, rotation_deg
    from relight.network.decomposition import EXPOSURE_LIMIT
    from relight.lighting.sh import REFERENCE_LUMINANCE

    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--light", help="equirect HDR map (.exr/.hdr), preset name (see `relight presets`) or "
                        "sun:AZIMUTH,ELEVATION[,ANGLE] (degrees; relight.lighting.lamps)")
    source.add_argument("--light-from", metavar="PHOTO",
                        help="light transfer: use the light the network estimates in another photo")
    p.add_argument("--rotate", type=rotation_deg, default=0.0, metavar="DEG", help="turn the light about world Z")
    p.add_argument("--exposure", type=exposure_ev, default=0.0, metavar="EV",
                   help=f"scale the light by 2**EV (|EV| <= {EXPOSURE_LIMIT:g})")
    p.add_argument("--no-normalize", dest="normalize", action="store_false",
                   help=f"use the map's radiance as is (default: scale to mean luminance {REFERENCE_LUMINANCE:g})")


def add_photo_options(p) -> None:
    """The options of a sub-command that decomposes one photo (`image`, `light`): mask,
    matte, person, model, quality, threads, largest photo."""
    from relight.command.cli_args import bounded_int
    from relight.network.quality import DEFAULT, PRESETS
    from relight.files.image_limits import DEFAULT_MAX_PIXELS, MAX_PIXELS
    from relight.network.runtime import MATTE_SOURCES
    from relight.models.session import cores_available

    p.add_argument("--mask", default=None, help="person mask image (white = person), same size as the photo")
    p.add_argument("--matte", choices=MATTE_SOURCES, default="person",
                   help="where the matte comes from without a mask: the person segmenter (default) or "
                        "the relighting network's own alpha head (for comparison)")
    p.add_argument("--person", type=bounded_int(1, 1000), default=None, metavar="N",
                   help="relight only this person (1 = the largest, 2 = the next, ...); default: everyone, under one light")
    p.add_argument("--model", default=None, help="ONNX model (default: the quality preset's installed model)")
    p.add_argument("--quality", choices=[q.key for q in PRESETS], default=DEFAULT,
                   help="preset of relight/network/quality.py: model and working resolution ("
                        + ", ".join(f"{q.key} {q.working_size}" for q in PRESETS) + " px)")
    p.add_argument("--refine", type=bounded_int(0, 100), default=None, metavar="N",
                   help="iterations refitting the photo's light to its own shading gradients (0: off; default: "
                        "the preset's, " + ", ".join(f"{q.key} {q.refine}" for q in PRESETS) + ")")
    cores = cores_available()  # more intra-op threads than cores only slows onnxruntime down
    p.add_argument("--threads", type=bounded_int(1, cores, " (the CPU cores available)"), default=None,
                   help=f"onnxruntime threads, 1..{cores} (default: all cores)")
    p.add_argument("--shadows", action="store_true",
                   help="the light's directional part (a sun, a lamp, a map's key) casts shadows on the person "
                        "from the relief of its own normals (off by default: it does not pay yet with today's "
                        "model, docs/EVALUATION.md, \"Cast shadows\")")
    p.add_argument("--max-pixels", type=bounded_int(1, MAX_PIXELS), default=None, metavar="N",
                   help=f"largest photo to decode, in pixels (default {DEFAULT_MAX_PIXELS:,}; also allows a "
                        f"header that claims more than its file can hold; at most {MAX_PIXELS:,})")


def open_relighter(args):
    """The Relighter of the parsed options --model / --quality / --threads."""
    from relight.network.quality import model_path, preset
    from relight.network.runtime import Relighter

    model = args.model if args.model is not None else model_path(args.quality)
    return Relighter(model, threads=args.threads, working_size=preset(args.quality).working_size)


def decompose_options(args) -> dict:
    """Relighter.decompose's keyword arguments from --quality / --refine / --matte / --person; the
    working size is the Relighter's own (open_relighter opens it at --quality's)."""
    from relight.network.quality import preset

    options = preset(args.quality).decompose_options(working_size=False)
    if getattr(args, "refine", None) is not None:
        options["refine"] = args.refine
    return dict(options, matte=args.matte, person=getattr(args, "person", None))


def decompose_photo(relighter, image, mask, args):
    """(the largest person's Decomposition, the Group of everyone or None) of a photo under the parsed
    options: everyone under the photo's one light (relight.network.group) unless a mask, --matte network
    or --person N says whom; then that one person alone."""
    options = decompose_options(args)
    if mask is None and options["matte"] == "person" and options["person"] is None:
        from relight.network.group import decompose_people

        group = decompose_people(relighter, image, **{k: v for k, v in options.items() if k not in ("matte", "person")})
        return group.people[0], group
    return relighter.decompose(image, mask, **options), None


def record(args, relighter, d) -> dict:
    """What was done to one photo (plain JSON values): the output's metadata and --json line."""
    stats = d.last_stats
    out = {"format": "relight-image/1", "model_sha256": relighter.sha256, "quality": args.quality,
           "exposure_ev": args.exposure, **d.choices}
    if stats is not None:
        out["relight"] = {"sh_order": stats.sh_order, "residual": stats.residual,
                          "negative_clamped": round(stats.fraction, 6)}
        if getattr(args, "shadows", False):  # what the shadow pass did: the key that cast them, or why none
            out["relight"]["shadows"] = stats.shadow_key.as_json() if stats.shadow_key is not None else \
                "none (the light has no directional part)"
    return out


def read_photo_and_mask(photo_path, mask_path, max_pixels):
    """(linear photo [H, W, 3], mask [H, W] or None): the --mask file, else the photo's own
    alpha when it varies (it marks the person), else None (the matte finds the person)."""
    from relight.files.photo import read_mask, read_photo

    image, alpha = read_photo(photo_path, max_pixels)
    if mask_path is not None:
        return image, read_mask(mask_path, image.shape[:2], max_pixels)
    return image, _marks_person(alpha)


def _marks_person(alpha: np.ndarray | None) -> np.ndarray | None:
    """A photo's alpha channel when it marks a person (it varies: not all 0, not all 1), else None."""
    return alpha if alpha is not None and alpha.min() < 1.0 and alpha.max() > 0.0 else None


def _output_for(photo: Path, out: str | None, layers: bool) -> Path:
    if out is None:
        return photo.with_name(photo.stem + "_relit" + (".exr" if layers else ".png"))
    path = Path(out)
    suffix = path.suffix.lower()
    if suffix not in (".png", ".exr"):
        raise ValueError(f"--out must end in .png or .exr, got {path.name}")
    if layers and suffix != ".exr":
        raise ValueError("--layers writes a multi-layer EXR: give --out NAME.exr")
    if not path.parent.is_dir():
        raise ValueError(f"output folder does not exist: {path.parent}")
    return path


def _process(relighter, photo_path: Path, out_path: Path, args, mask_path: str | None, light,
             read=None) -> Path:
    """Read, decompose, relight and write one photo; nothing is written on failure. `read`: a
    future of read_photo_and_mask already under way (its errors are raised here)."""
    from relight.files.photo import write_image, write_layers_exr

    import json

    image, mask = read.result() if read is not None else read_photo_and_mask(photo_path, mask_path, args.max_pixels)
    # the light and --exposure were checked at the command's boundary (target_light, their argparse type)
    scale = 2.0 ** args.exposure
    shadows = getattr(args, "shadows", False)
    d, group = decompose_photo(relighter, image, mask, args)
    relit = (group or d).relight_checked(light, scale, shadows=shadows)
    stats = d.last_stats
    done = record(args, relighter, d)
    if group is not None:
        done["people"] = group.record()
    metadata = {"relight": json.dumps(done, sort_keys=True)}
    if args.json:
        print(json.dumps(dict(done, photo=str(photo_path), output=str(out_path)), sort_keys=True))
    if stats is not None and stats.fraction > NEGATIVE_WARN_FRACTION:
        print(f"relight image: warning: {Path(out_path).name}: negative light (SH ringing) clamped to 0 "
              f"on {stats.fraction:.1%} of the person", file=sys.stderr)
    if args.layers:
        layers = d.layers_checked(light, scale)
        for other in group.people[1:] if group is not None else ():  # each zero outside its own matte
            for name, layer in other.layers_checked(light, scale).items():
                layers[name] += layer
        return write_layers_exr(out_path, relit, layers, metadata)
    return write_image(out_path, relit, metadata)


# above this share of the person's pixels, clamping is visible: say so (the light is too sharp for the order)
NEGATIVE_WARN_FRACTION = 0.01


@contextmanager
def photo_named(path, option: str = ""):
    """The core's refusals of a photo's content that it raises without knowing the file (no
    person in it, another person asked for than it shows, too small for the person matte)
    as one line naming the file: `PATH: the core's words`; `option` names the option that
    gave the photo (--light-from), whose photo's no-person advice is its own (--mask is the
    other photo's option)."""
    from relight.person.linear_photo import PhotoTooSmall
    from relight.person.matte import NoPersonError, PersonIndexError

    where = f"{option} {path}" if option else str(path)
    try:
        yield
    except NoPersonError as exc:
        if not option:
            raise ValueError(f"{where}: {exc}") from exc
        raise ValueError(f"{where}: no person found in the photo: give a photo where a person is clearly "
                         "visible, or one whose alpha channel marks the person") from exc
    except (PersonIndexError, PhotoTooSmall) as exc:
        raise ValueError(f"{where}: {exc}") from exc


def target_light(args, relighter) -> np.ndarray:
    """The SH light of the parsed light options (add_light_options), of the model's order: the
    map or preset, or the light the network estimates in the --light-from photo; resolved once,
    before any photo is read (a bad map fails first)."""
    from relight.network.decomposition import EXPOSURE_LIMIT
    from relight.lighting.light import sh_light

    source = args.light
    if args.light_from is not None:
        from relight.files.photo import read_photo

        donor, donor_alpha = read_photo(args.light_from, args.max_pixels)
        options = dict(decompose_options(args), person=None)
        with photo_named(args.light_from, "--light-from"):
            source = relighter.decompose(donor, _marks_person(donor_alpha), **options)
    scale = 2.0 ** args.exposure  # checked by its argparse type (relight.command.cli_args.exposure_ev)
    # --no-normalize: as is; otherwise the default (maps scaled, a --light-from photo's light as it is);
    # sh_light checks the light (finite SH of the order) once
    L = sh_light(source, relighter.sh_order, rotation_deg=args.rotate, normalize=None if args.normalize else False)
    level = float(np.abs(L).max(initial=0.0))
    peak = level * scale
    if peak > LIGHT_LIMIT:
        most = math.floor(math.log2(LIGHT_LIMIT / level) * 10) / 10  # the highest exposure that fits
        fix = f"give --exposure {most:g} or lower" if most >= -EXPOSURE_LIMIT else "use a dimmer light"
        if not args.normalize:
            fix = f"drop --no-normalize (the map's own radiance is that bright) or {fix}"
        raise ValueError(f"the light is too bright to relight in float32 (SH coefficients up to {peak:.3g} after "
                         f"exposure {args.exposure:g} EV, limit {LIGHT_LIMIT:g}): {fix}")
    return L


def run_image(args) -> int:
    """Entry point of `relight image` (argparse namespace from register())."""
    from relight.command.cli_output import check_folder_name, check_not_an_input, claim_output, light_inputs
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
    else:
        out = _output_for(source, args.out, args.layers)
    check_not_an_input(out, {"photo": source, **light_inputs(args)})
    with claim_output(out, "relight image"):
        if folder:
            relighter = open_relighter(args)
            return _run_folder(relighter, source, out, args, target_light(args, relighter))
        # the photo is decoded on a thread while the models load (both mostly outside the GIL);
        # its errors still come after the model's and the light's, as when read in turn. Not
        # beside --light-from's photo: two readers at once would race on the warnings filters
        from concurrent.futures import ThreadPoolExecutor

        reader = ThreadPoolExecutor(max_workers=1, thread_name_prefix="relight-read")
        try:
            read = reader.submit(read_photo_and_mask, source, args.mask, args.max_pixels) \
                if args.light_from is None else None
            relighter = open_relighter(args)
            light = target_light(args, relighter)
            with photo_named(source):  # in folder mode each failure's line names its photo
                written = _process(relighter, source, out, args, args.mask, light, read)
        finally:
            reader.shutdown(wait=False, cancel_futures=True)
        print(f"wrote {written}")
        return 0


def _run_folder(relighter, source: Path, out_dir: Path, args, light) -> int:
    from relight.command.cli_output import Progress
    from relight.files.photo import PHOTO_SUFFIXES

    photos = sorted(p for p in source.iterdir() if p.is_file() and p.suffix.lower() in PHOTO_SUFFIXES)
    if not photos:
        raise ValueError(f"{source}: no photos ({', '.join(PHOTO_SUFFIXES)}) in the folder")
    out_dir.mkdir(exist_ok=True)
    suffix = ".exr" if args.layers else ".png"
    stems = [p.stem for p in photos]
    # a.jpg and a.png both present: keep the extension in the output names
    names = {p: (p.stem if stems.count(p.stem) == 1 else p.name.replace(".", "_")) + suffix for p in photos}
    failures: list[tuple[Path, str]] = []
    bar = Progress(len(photos), command="relight image", unit="photo")
    try:
        for photo in photos:
            try:
                _process(relighter, photo, out_dir / names[photo], args, None, light)
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
