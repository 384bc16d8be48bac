"""What the sub-commands that relight a person share: their options, the request values built once
from the parsed options at each command's edge, and the steps they take with them.

`relight image` and `relight video` take the light options (add_relight_parser's) and all three of
`image`, `light` and `video` the photo options (add_photo_options). A command turns its parsed
options into immutable values once (LightRequest, PhotoRequest: each option already checked by its
argparse type) and passes those values on, never the argparse namespace: open_relighter,
read_photo_and_mask, decompose_photo and target_light take them. No command module imports
another's internals: what two of them share is here.
"""

from __future__ import annotations

import argparse
import math
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from relight.network.quality import QualityPreset

__all__ = ["LIGHT_LIMIT", "LightRequest", "PhotoRequest", "add_photo_options", "add_relight_parser", "decompose_photo", "open_relighter", "photo_named", "read_photo_and_mask",
           "relight_options", "relighter_and_light", "target_light"]

# largest SH coefficient (after exposure) relit in float32: shading sums (order+1)^2 terms and the
# detail ratio divides by 1e-3, so results stay far below float32's 3.4e38 (a 3e38 map with
# --no-normalize would overflow: refused, like any light that bright)
LIGHT_LIMIT = 1e18


def add_relight_parser(subparsers, name: str, *, help: str, description: str, source: str,
                       source_help: str) -> argparse.ArgumentParser:
    """The parser of a sub-command that relights a person (`image`, `video`): what it reads
    (`source`), then the options that say what light to relight with (--light or --light-from,
    --rotate, --exposure, --no-normalize: LightRequest) and the photo options (add_photo_options)."""
    from relight.command.cli_args import exposure_ev, rotation_deg
    from relight.lighting.light import EXPOSURE_LIMIT
    from relight.lighting.sh import REFERENCE_LUMINANCE

    p = subparsers.add_parser(name, help=help, description=description)
    p.add_argument(source, help=source_help)
    light = p.add_mutually_exclusive_group(required=True)
    light.add_argument("--light", help="equirect HDR map (.exr/.hdr), preset name (see `relight presets`) or "
                       "sun:AZIMUTH,ELEVATION[,ANGLE] (degrees; relight.lighting.lamps)")
    light.add_argument("--light-from", metavar="PHOTO",
                       help="light transfer: use the light the network estimates in another photo")
    p.add_argument("--rotate", type=rotation_deg, default=0.0, metavar="DEG", help="turn the light about world Z")
    p.add_argument("--exposure", type=exposure_ev, default=0.0, metavar="EV",
                   help=f"scale the light by 2**EV (|EV| <= {EXPOSURE_LIMIT:g})")
    p.add_argument("--no-normalize", dest="normalize", action="store_false",
                   help=f"use the map's radiance as is (default: scale to mean luminance {REFERENCE_LUMINANCE:g})")
    add_photo_options(p)
    return p


def add_photo_options(p) -> None:
    """The options of a sub-command that decomposes a photo (`image`, `light`, `video`): mask,
    matte, person, model, quality, refine, threads, shadows, largest photo (PhotoRequest)."""
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


@dataclass(frozen=True)
class LightRequest:
    """The light options (add_relight_parser's) as their argparse types checked them: a map, preset or
    sun (`light`) or another photo (`light_from`), turned by `rotate` degrees, `exposure` EV, scaled to
    the reference mean luminance unless `normalize` is False. `map_file`: `light` when it names a
    file (a map the command reads, which an output must not replace), else None."""

    light: str | None
    light_from: str | None
    rotate: float
    exposure: float
    normalize: bool
    map_file: str | None

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> "LightRequest":
        light = args.light
        return cls(light, args.light_from, args.rotate, args.exposure, args.normalize,
                   light if light is not None and Path(light).is_file() else None)


@dataclass(frozen=True)
class PhotoRequest:
    """The photo options (add_photo_options) as their argparse types checked them; `preset` the
    quality preset --quality names (relight.network.quality.QualityPreset), looked up once."""

    mask: str | None
    matte: str
    person: int | None
    model: str | None
    quality: str
    refine: int | None
    threads: int | None
    shadows: bool
    max_pixels: int | None
    preset: QualityPreset

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> "PhotoRequest":
        from relight.network.quality import preset

        return cls(args.mask, args.matte, args.person, args.model, args.quality, args.refine, args.threads,
                   args.shadows, args.max_pixels, preset(args.quality))

    def decompose_options(self) -> dict:
        """Relighter.decompose's keyword arguments (--quality's preset, --refine, --matte, --person); the
        working size is the Relighter's own (open_relighter opens it at --quality's)."""
        options = self.preset.decompose_options(working_size=False)
        if self.refine is not None:
            options["refine"] = self.refine
        return dict(options, matte=self.matte, person=self.person)


def relight_options(args: argparse.Namespace) -> tuple[LightRequest, PhotoRequest]:
    """The light and the photo options of a sub-command that relights a person (add_relight_parser's)."""
    return LightRequest.from_args(args), PhotoRequest.from_args(args)


def open_relighter(photo: PhotoRequest):
    """The Relighter of --model / --quality / --threads."""
    from relight.network.runtime import Relighter

    model = photo.model if photo.model is not None else photo.preset.model_file()
    return Relighter(model, threads=photo.threads, working_size=photo.preset.working_size)


def relighter_and_light(light: LightRequest, photo: PhotoRequest):
    """(the Relighter of the photo options, the light of the light options for its model: target_light)."""
    relighter = open_relighter(photo)
    return relighter, target_light(light, photo, relighter)


def decompose_photo(relighter, image, mask, photo: PhotoRequest, named=None):
    """(the largest person's Decomposition, the Group of everyone or None) of a photo under the photo
    options: everyone under the photo's one light (relight.network.group) unless a mask, --matte network
    or --person N says whom; then that one person alone. `named`: the photo's path, which the core's
    refusals of its content then name (photo_named)."""
    options = photo.decompose_options()
    with photo_named(named) if named is not None else nullcontext():
        if mask is None and options["matte"] == "person" and options["person"] is None:
            from relight.network.group import decompose_people

            group = decompose_people(relighter, image,
                                     **{k: v for k, v in options.items() if k not in ("matte", "person")})
            return group.people[0], group
        return relighter.decompose(image, mask, **options), None


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


def target_light(light: LightRequest, photo: PhotoRequest, relighter):
    """The light of the light options as a relight.lighting.light.CheckedLight of the model's order,
    its exposure applied: the map or preset, or the light the network estimates in the --light-from
    photo (decomposed under the photo options); resolved and checked once, before any photo is read
    (a bad map fails first)."""
    from relight.lighting.light import EXPOSURE_LIMIT, SHLight

    source = light.light
    if light.light_from is not None:
        from relight.files.photo import read_photo

        donor, donor_alpha = read_photo(light.light_from, photo.max_pixels)
        options = dict(photo.decompose_options(), person=None)
        with photo_named(light.light_from, "--light-from"):
            source = relighter.decompose(donor, _marks_person(donor_alpha), **options)
    scale = 2.0 ** light.exposure  # checked by its argparse type (relight.command.cli_args.exposure_ev)
    # --no-normalize: as is; otherwise the default (maps scaled, a --light-from photo's light as it is);
    # SHLight checks the light (finite SH of the order) once, where it is made
    made = SHLight.resolve(source, relighter.sh_order, normalize=None if light.normalize else False)
    checked = made.checked_at(light.rotate, scale)
    level = float(np.abs(checked.coeffs).max(initial=0.0))
    peak = level * scale
    if peak > LIGHT_LIMIT:
        most = math.floor(math.log2(LIGHT_LIMIT / level) * 10) / 10  # the highest exposure that fits
        fix = f"give --exposure {most:g} or lower" if most >= -EXPOSURE_LIMIT else "use a dimmer light"
        if not light.normalize:
            fix = f"drop --no-normalize (the map's own radiance is that bright) or {fix}"
        raise ValueError(f"the light is too bright to relight in float32 (SH coefficients up to {peak:.3g} after "
                         f"exposure {light.exposure:g} EV, limit {LIGHT_LIMIT:g}): {fix}")
    return checked
