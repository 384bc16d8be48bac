"""`relight light`: the light the network estimates in a photo, as a Blender World map.

    relight light PHOTO --out LIGHT.exr [--width 512] [--json] [--lamp-free]
                  [--mask MASK | --matte person|network] [--person N] [--model PATH]
                  [--quality draft|balanced|best] [--threads N] [--max-pixels N]

Splits the photo's estimated SH light into a key light (a Blender Sun: direction,
colour, strength, angle; relight.lighting.key_light) and a smooth World for the rest, written
as a linear equirectangular EXR in Blender's World mapping (Environment Texture,
default mapping; strength 1), >= 0 everywhere. With --json it prints the key light
("direction": unit vector toward the light in Blender's world axes, azimuth and
elevation, colour, strength in Blender's Sun units, angle), the SH coefficients
and the irradiance error of key + World. --lamp-free writes today's single map
instead (relight.lighting.light_map: the whole light, no lamp). Bad input: one line on
stderr, exit 2, nothing written (the EXR is written atomically, after everything
else succeeded).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from relight.command.request import PhotoRequest


def register(subparsers) -> argparse.ArgumentParser:
    """Add the `light` sub-command to the `relight` command's subparsers."""
    from relight.command.request import add_photo_options
    from relight.lighting.light_map import DEFAULT_WIDTH, MAX_WIDTH, MIN_WIDTH

    p = subparsers.add_parser("light", help="the photo's light as an equirect EXR for a Blender World",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("photo", help="photo file (PNG/JPEG/TIFF/WebP/EXR)")
    p.add_argument("--out", required=True, help="output .exr (linear, Blender's equirect World mapping)")
    p.add_argument("--width", type=_width, default=DEFAULT_WIDTH,
                   help=f"map width in texels, even, {MIN_WIDTH}..{MAX_WIDTH} "
                        f"(height = width / 2; default {DEFAULT_WIDTH})")
    p.add_argument("--json", action="store_true",
                   help="print the key light, the SH coefficients and the irradiance error of what was written "
                        "as JSON")
    p.add_argument("--lamp-free", action="store_true",
                   help="no key light: the whole light as one map (relight.lighting.light_map), as before")
    add_photo_options(p)
    p.set_defaults(func=run_light)
    return p


def _width(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid int value: {text!r}") from None
    from relight.lighting.light_map import check_width

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


@dataclass(frozen=True)
class LightMapRequest:
    """`relight light`'s parsed options, checked once at the command's edge (from_args)."""

    photo: Path
    out: Path
    width: int
    json: bool
    lamp_free: bool
    options: PhotoRequest

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> "LightMapRequest":
        photo = Path(args.photo)
        if not photo.is_file():
            raise ValueError(f"{photo}: no such file")
        return cls(photo, _output(args.out), args.width, args.json, args.lamp_free, PhotoRequest.from_args(args))


def run_light(args) -> int:
    """Entry point of `relight light` (argparse namespace from register()): its request built once, here."""
    from relight.command.cli_output import claim_output

    request = LightMapRequest.from_args(args)
    # as relight image and video: an EXR photo (or mask) named as --out would be replaced, and
    # two runs writing one map hold one lock
    with claim_output(request.out, "relight light", inputs={"photo": request.photo, "--mask": request.options.mask}):
        return _write_light(request)


def _write_light(request: LightMapRequest) -> int:
    """run_light's work once the output is claimed: decompose, split or map the light, write, report."""
    from relight.command.request import decompose_photo, open_relighter, read_photo_and_mask
    from relight.files.exr import write_exr
    from relight.lighting.light_map import irradiance_error, light_map

    photo, out, options = request.photo, request.out, request.options
    relighter = open_relighter(options)
    image, mask = read_photo_and_mask(photo, options.mask, options.max_pixels)
    decomposition, group = decompose_photo(relighter, image, mask, options, photo)  # the light of everyone in it
    if request.lamp_free:
        result = light_map(decomposition.light, request.width)
        pixels, key = result.pixels, None
        error = irradiance_error(result.coeffs, result.pixels)
        world = {"fitted": result.fitted, "coeffs": np.round(result.map_coeffs, 9).tolist()}
    else:
        from relight.lighting.key_light import chroma_spread, split_irradiance_error, split_light

        split = split_light(decomposition.light, request.width)
        pixels, key = split.pixels, split.key
        error = split_irradiance_error(split, sh_order(decomposition.light))
        world = {"chroma_spread": round(chroma_spread(pixels), 6)}
    write_exr(out, {c: pixels[..., i] for i, c in enumerate("RGB")})
    if request.json:
        height, width = pixels.shape[:2]
        print(json.dumps({
            "photo": str(photo), "out": str(out), "order": sh_order(decomposition.light),
            "coeffs": np.round(decomposition.light, 9).tolist(),
            "key": None if key is None else key.as_json(),
            "map": {"width": width, "height": height, "irradiance_error": round(error, 6), **world},
            "decomposition": decomposition.choices, **({"people": group.record()} if group is not None else {}),
        }))
    else:
        lamp = "" if key is None else (f"; key light from azimuth {key.as_json()['azimuth_deg']:.0f}, elevation "
                                       f"{key.as_json()['elevation_deg']:.0f} degrees, strength "
                                       f"{key.blender_strength:.3g}, angle {key.angle_deg:.0f} degrees")
        print(f"wrote {out} (with the key light its irradiance is within {100 * error:.1f}% RMS of the photo's "
              f"SH light{lamp})" if key is not None else
              f"wrote {out} (its irradiance is within {100 * error:.1f}% RMS of the photo's SH light)")
    return 0


def sh_order(coeffs) -> int:
    from relight.lighting.sh import order_from_num_coeffs

    return order_from_num_coeffs(np.asarray(coeffs).shape[0])
