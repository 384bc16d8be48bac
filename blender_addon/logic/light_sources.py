"""The panel's light sources (World, HDR file, preset, another photo) as relight.lighting.light.SHLight
values, each read and projected once, with the artist's messages when one gives no light;
the World's light with the scene's lamps added (with_lamps). Plain Python."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .messages import first_line


LIGHT_KINDS = ("WORLD", "HDR", "PRESET", "IMAGE")


def light_cache():
    """The add-on's relight.lighting.light.SHLightCache: HDR files projected once per file state and
    the rotation matrices the dials ask for again and again."""
    if not _LIGHT_CACHE:
        from relight.lighting.light import LightCache

        _LIGHT_CACHE.append(LightCache())
    return _LIGHT_CACHE[0]


_LIGHT_CACHE: list = []


def hdr_file_light(path: str, order: int):
    """The HDR file as a relight.lighting.light.SHLight (read and projected here, once per file state)."""
    from relight.lighting.light import SHLight

    if not path:
        raise ValueError("Choose an HDR file for the light.")
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"The HDR file '{path}' does not exist.")
    try:
        return SHLight.resolve(str(p), order, cache=light_cache())
    except (ValueError, OSError) as exc:
        if _is_black_light(exc):
            raise ValueError(f"The HDR file '{p.name}' is black, so it gives no light: "
                             "choose another file.") from None
        raise ValueError(f"The HDR file '{p.name}' cannot be read as an equirectangular map "
                         f"({first_line(exc)}).") from None


def preset_light(name: str, order: int):
    """The preset as a relight.lighting.light.SHLight (loaded and projected once)."""
    from relight.lighting.light import SHLight

    try:
        return SHLight.resolve(name, order, cache=light_cache())
    except (ValueError, OSError) as exc:
        raise ValueError(f"The light preset '{name}' is not available ({first_line(exc)}).") from None


def equirect_light(pixels: np.ndarray, order: int):
    """The World's equirect map (pixels) as a relight.lighting.light.SHLight: a map like an HDR
    file or a preset, so World, HDR file and preset are scaled alike."""
    from relight.lighting.light import SHLight

    h, w = pixels.shape[:2]
    if w != 2 * h:
        raise ValueError(f"The World's environment image is {w}x{h}; an equirectangular map "
                         "is twice as wide as high.")
    rgb = np.ascontiguousarray(pixels[..., :3])
    if not np.all(np.isfinite(rgb)):
        raise ValueError("The World's light has invalid (infinite or NaN) values: "
                         "check its environment image and Background strength.")
    if float(rgb.max(initial=0.0)) <= 0.0:
        raise ValueError(BLACK_WORLD)
    try:
        return SHLight.resolve(rgb, order)
    except ValueError as exc:
        if _is_black_light(exc):
            raise ValueError(BLACK_WORLD) from None
        raise ValueError(f"The World gives no usable light ({first_line(exc)}).") from None


BLACK_WORLD = ("The World is black, so it gives no light: raise its Background colour or Strength, "
               "or choose another light.")


def _is_black_light(exc: BaseException) -> bool:
    # relight.lighting.sh refuses to scale a light whose mean luminance is not positive
    return "mean luminance" in str(exc)


def preset_names() -> list[str]:
    """Bundled presets, then Blender's own studio worlds when bpy is there."""
    from relight.lighting import presets

    return presets.list_presets() + presets.list_blender_presets()


NO_LIGHT = ("The World and the scene's lamps give no light: raise the World's Background strength "
            "or a lamp's power, or choose another light.")


def with_lamps(world, rotation_deg: float, lamps, order: int, at=None):
    """The World's light (a relight.lighting.light.SHLight, or None for no World or a black one) turned by its
    own `rotation_deg`, plus the scene's lamps (relight.lighting.lamps.Lamp) projected to SH at the person
    (photo_light.PERSON_POSITION unless `at`): one SHLight scaled to the reference luminance like
    any map (so a lamp counts against the World as in a render; the level is Exposure's)."""
    from relight.lighting import sh, sh_rotation
    from relight.lighting.lamps import lamps_coeffs
    from relight.lighting.light import REFERENCE_LUMINANCE, SHLight

    from .photo_light import PERSON_POSITION

    n = sh.num_coeffs(order)
    total = lamps_coeffs(lamps, PERSON_POSITION if at is None else at, order)
    if world is not None:
        base = world.base[:n]
        if rotation_deg % 360.0:
            matrix = light_cache().get(("rot", float(rotation_deg), order), lambda: sh_rotation.rotation_matrix(
                sh_rotation.z_rotation(rotation_deg), order))
            base = matrix @ base
        total = total + base
    if not sh.mean_luminance(total) > 0:
        raise ValueError(NO_LIGHT)
    return SHLight(total, REFERENCE_LUMINANCE)
