"""`relight light`: the light the network estimates in a photo, as a Blender World map.

    relight light PHOTO --out LIGHT.exr [--width 512] [--json]
                  [--mask MASK | --matte person|network] [--person N] [--model PATH]
                  [--quality draft|balanced|best] [--threads N] [--max-pixels N]

Writes the photo's estimated SH light as a linear equirectangular EXR in
Blender's World mapping (Environment Texture, default mapping; strength 1),
>= 0 everywhere (relight.light_map), and with --json prints the SH
coefficients, the map's own coefficients and its irradiance error. Bad input:
one line on stderr, exit 2, nothing written (the EXR is written atomically,
after everything else succeeded).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def register(subparsers) -> argparse.ArgumentParser:
    """Add the `light` sub-command to the `relight` command's subparsers."""
    from relight import light_map
    from relight.cli_image import add_photo_options

    p = subparsers.add_parser("light", help="the photo's light as an equirect EXR for a Blender World",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("photo", help="photo file (PNG/JPEG/TIFF/WebP/EXR)")
    p.add_argument("--out", required=True, help="output .exr (linear, Blender's equirect World mapping)")
    p.add_argument("--width", type=_width, default=light_map.DEFAULT_WIDTH,
                   help=f"map width in texels, even, {light_map.MIN_WIDTH}..{light_map.MAX_WIDTH} "
                        f"(height = width / 2; default {light_map.DEFAULT_WIDTH})")
    p.add_argument("--json", action="store_true",
                   help="print the SH coefficients (the photo's light and the map's) and the map's irradiance "
                        "error as JSON")
    add_photo_options(p)
    p.set_defaults(func=run_light)
    return p


def _width(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid int value: {text!r}") from None
    from relight.light_map import check_width

    try:
        return check_width(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _output(out: str) -> Path:
    path = Path(out)
    if path.suffix.lower() != ".exr":
        raise ValueError(f"--out must end in .exr, got {path.name}")
    if not path.parent.is_dir():
        raise ValueError(f"output folder does not exist: {path.parent}")
    if path.is_dir():
        raise ValueError(f"--out {path} is a folder")
    return path


def run_light(args) -> int:
    """Entry point of `relight light` (argparse namespace from register())."""
    from relight.cli_image import decompose_options, open_relighter, read_photo_and_mask
    from relight.exr import write_exr
    from relight.light_map import irradiance_error, light_map

    photo = Path(args.photo)
    if not photo.is_file():
        raise ValueError(f"{photo}: no such file")
    out = _output(args.out)
    relighter = open_relighter(args)
    image, mask = read_photo_and_mask(photo, args.mask, args.max_pixels)
    decomposition = relighter.decompose(image, mask, **decompose_options(args))
    result = light_map(decomposition.light, args.width)
    error = irradiance_error(result.coeffs, result.pixels)
    write_exr(out, {c: result.pixels[..., i] for i, c in enumerate("RGB")})
    if args.json:
        height, width = result.pixels.shape[:2]
        print(json.dumps({
            "photo": str(photo), "out": str(out), "order": result.order,
            "coeffs": np.round(result.coeffs, 9).tolist(),
            "map": {"width": width, "height": height, "fitted": result.fitted,
                    "coeffs": np.round(result.map_coeffs, 9).tolist(),
                    "irradiance_error": round(error, 6)},
            "decomposition": decomposition.choices,
        }))
    else:
        print(f"wrote {out} (its irradiance is within {100 * error:.1f}% RMS of the photo's SH light)")
    return 0
