"""The light as a value: every source of light becomes SH coefficients [n, 3] here, once.

    L = sh_light("studio", 4, rotation_deg=90)   # a bundled preset (relight.lighting.presets)
    L = sh_light("map.hdr", 4)                   # an equirect HDR file (.exr / .hdr)
    L = sh_light(world_pixels, 4)                # equirect pixels [H, 2H, 3] (the add-on's World bake)
    L = sh_light(coeffs, 4, rotation_deg=30)     # SH coefficients [m, 3]: cut or zero-padded to order 4
    L = sh_light(decomposition, 4)               # light transfer: another photo's estimated light
    L = sh_light("sun:30,45,5", 4)               # a sun at azimuth 30, elevation 45, 5 degrees wide, plus ambient

One way to get a light: `SHLight.resolve(source, order)` loads and projects a source
once into an SHLight value (the runtime's light: SH coefficients and the mean luminance
they are scaled to; farm.synthesis.lights.SampledLight is the farm's drawn light, another thing);
`SHLight.at(rotation_deg)` gives the coefficients that `Decomposition.relight` takes,
and `sh_light(source, order, rotation_deg=...)` is the shorthand for both steps.

A map (file, preset or pixels) follows one recipe: project it to SH, rotate it about
world Z, scale it to the reference mean luminance (docs/conventions.md, exposure); the
farm's lights, the training bank, `relight sh`, `relight image` and the add-on all go
through SHLight for it. SH coefficients and another photo's light are light already:
they are only fitted to the order and rotated. `map_file` is the one "file or preset?"
decision. A caller that turns lights again and again (the add-on's dials) passes a
`LightCache`. `directional_light` makes a white sun plus ambient as SH (the light the
evaluations turn about the person, and many tests').
"""

from __future__ import annotations

import math
import os
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from relight.lighting import sh, sh_projection, sh_rotation
from relight.lighting.sh import REFERENCE_LUMINANCE

__all__ = ["EXPOSURE_LIMIT", "REFERENCE_LUMINANCE", "CheckedLight", "SHLight", "LightCache", "checked_light",
           "directional_light", "exposure_scale", "fit_checked", "fit_order", "map_file", "sh_light"]

EXPOSURE_LIMIT = 64.0  # EV either way: 2**64 is far past any sensor; the one bound (the CLI's and the add-on's)


def exposure_scale(exposure_ev) -> float:
    """2 ** exposure_ev, for a finite exposure within +-EXPOSURE_LIMIT EV (ValueError otherwise)."""
    try:
        ev = float(exposure_ev)
    except (TypeError, ValueError):
        raise ValueError(f"exposure must be a number of EV stops, got {exposure_ev!r}") from None
    if not math.isfinite(ev) or abs(ev) > EXPOSURE_LIMIT:
        raise ValueError(f"exposure must be a finite number of EV within +-{EXPOSURE_LIMIT:g}, got {exposure_ev}")
    return 2.0 ** ev


class CheckedLight:
    """A light checked once, where it was made: `coeffs` SH coefficients [(order+1)^2, 3], float64,
    finite, read-only, and `scale` an exposure's 2**EV within +-EXPOSURE_LIMIT. What a relight takes
    without checking again (relight.network.decomposition.Decomposition.relight). Made by
    checked_light (a caller's raw coefficients) or SHLight.checked_at (a light resolved here)."""

    __slots__ = ("coeffs", "scale")

    def __init__(self, coeffs: np.ndarray, scale: float):
        # trusted: only checked_light and SHLight.checked_at construct it, after their checks
        coeffs.flags.writeable = False
        self.coeffs, self.scale = coeffs, float(scale)

    @property
    def order(self) -> int:
        return math.isqrt(self.coeffs.shape[0]) - 1

    def __repr__(self) -> str:
        return f"CheckedLight(order={self.order}, scale={self.scale:g})"


def checked_light(light, exposure_ev=0.0) -> CheckedLight:
    """A light given to a relight, checked once: numeric SH coefficients [m, 3] of an SH order, finite
    (ValueError otherwise), and the exposure exposure_ev (see exposure_scale); a CheckedLight passes as it
    is, its scale times 2**exposure_ev."""
    no_exposure = type(exposure_ev) in (int, float) and exposure_ev == 0
    if isinstance(light, CheckedLight):
        return light if no_exposure else CheckedLight(light.coeffs, light.scale * exposure_scale(exposure_ev))
    if isinstance(light, (str, bytes)) or not hasattr(light, "__len__") or hasattr(light, "sh_order"):
        raise ValueError(f"light must be SH coefficients [n, 3] (relight.lighting.light.sh_light makes them from a "
                         f"map, preset or photo), got {type(light).__name__}")
    arr = np.asarray(light)
    if arr.dtype == object or not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"light must be numeric SH coefficients [n, 3], got dtype {arr.dtype}")
    coeffs = np.array(sh.validate_coeffs(arr))  # a copy: made read-only, the caller's array is not
    return CheckedLight(coeffs, 1.0 if no_exposure else exposure_scale(exposure_ev))

class LightCache:
    """A small LRU of projected maps (per file state and order) and Z-rotation matrices,
    for a caller that resolves the same lights many times (a UI's dials). Thread-safe."""

    def __init__(self, size: int = 32):
        self.size = size
        self.items: OrderedDict = OrderedDict()
        self.lock = threading.Lock()  # a UI thread and a worker may resolve at once

    def get(self, key, make):
        with self.lock:
            if key in self.items:
                self.items.move_to_end(key)
                return self.items[key]
        value = make()  # outside the lock: a slow projection does not block other lights
        value.flags.writeable = False  # shared between callers
        with self.lock:
            self.items[key] = value
            while len(self.items) > self.size:
                self.items.popitem(last=False)
        return value


def _cached(cache: LightCache | None, key, make):
    return make() if cache is None else cache.get(key, make)


def map_file(source) -> Path:
    """The HDR file `source` names: an existing file, else a preset name (relight.lighting.presets).

    ValueError when it is neither."""
    from relight.lighting.presets import preset_file

    if isinstance(source, str) and not source:
        raise ValueError("light is an empty string: give an HDR map path or a preset name")
    path = Path(source)
    if path.is_file():
        return path
    preset = preset_file(source)
    if preset is not None:
        return preset
    raise ValueError(f"{source!s} is neither a file nor a preset name (see `relight presets`) nor a sun "
                     "(sun:AZIMUTH,ELEVATION[,ANGLE])")


def _rotate_z(c: np.ndarray, rotation_deg, cache: LightCache | None = None) -> np.ndarray:
    """SH light [n, 3] (float64, as sh.validate_coeffs returns it) turned by `rotation_deg` about
    world Z (a number of degrees, finite: ValueError otherwise); a whole number of turns returns
    an unrotated copy."""
    try:
        rotation_deg = float(rotation_deg)
    except (TypeError, ValueError):
        raise ValueError(f"rotation must be a number of degrees, got {rotation_deg!r}") from None
    if not math.isfinite(rotation_deg):
        raise ValueError(f"rotation must be finite, got {rotation_deg}")
    if rotation_deg % 360.0 == 0.0:
        return np.array(c, dtype=np.float64)
    order = sh.order_from_num_coeffs(c.shape[0])
    M = _cached(cache, ("rot", rotation_deg, order),
                lambda: sh_rotation.rotation_matrix(sh_rotation.z_rotation(rotation_deg), order))
    return M @ c


def fit_order(coeffs, n: int) -> np.ndarray:
    """SH coefficients [m, 3] (float64) cut or zero-padded to n rows."""
    return fit_checked(sh.validate_coeffs(coeffs), n)


def fit_checked(c: np.ndarray, n: int) -> np.ndarray:
    """fit_order of coefficients already checked (sh.validate_coeffs returned them)."""
    if c.shape[0] >= n:
        return c[:n]
    return np.concatenate([c, np.zeros((n - c.shape[0], 3), c.dtype)], axis=0)


def _file_key(path: Path) -> tuple:
    st = path.stat()
    return str(path.resolve()), st.st_mtime_ns, st.st_size


@dataclass(frozen=True)
class SHLight:
    """The runtime's light, resolved once: its SH [n, 3] before any rotation and scaling, and
    the mean luminance it is scaled to after rotation (None: used as is). `at(rotation_deg)`
    gives the coefficients a relight takes. Both are checked here, once (a black light with a
    target is refused now, not at the first relight); a rotation about Z keeps the mean
    luminance, so the scale to the target is found once too."""

    base: np.ndarray
    target: float | None = None

    def __post_init__(self):
        base = sh.validate_coeffs(self.base, "light")
        object.__setattr__(self, "base", base)
        object.__setattr__(self, "_scale", 1.0 if self.target is None else sh.reference_scale(base, self.target))

    @property
    def order(self) -> int:
        return sh.order_from_num_coeffs(self.base.shape[0])

    def turned(self, rotation_deg: float = 0.0, cache: LightCache | None = None) -> tuple[np.ndarray, float]:
        """(SH light [n, 3], float64, turned by `rotation_deg` about world Z then scaled to
        the target mean luminance, the scale: 1.0 without a target)."""
        rotated = _rotate_z(self.base, rotation_deg, cache)
        if self.target is None:
            return rotated, 1.0
        return rotated * self._scale, float(self._scale)

    def at(self, rotation_deg: float = 0.0, cache: LightCache | None = None) -> np.ndarray:
        """SH light [n, 3], float64: turned by `rotation_deg` about world Z, then scaled."""
        return self.turned(rotation_deg, cache)[0]

    def checked_at(self, rotation_deg: float = 0.0, scale: float = 1.0,
                   cache: LightCache | None = None) -> CheckedLight:
        """at(rotation_deg) as a CheckedLight, checked here once (this light's coefficients when it was
        made), with `scale` the 2**EV of an exposure already checked (exposure_scale; `relight image`'s
        --exposure by its argparse type)."""
        return CheckedLight(self.turned(rotation_deg, cache)[0], scale)

    @classmethod
    def resolve(cls, source, order: int, *, normalize: bool | None = None, target: float = REFERENCE_LUMINANCE,
                cache: LightCache | None = None) -> "SHLight":
        """Any light source (see the module docstring) as an SHLight of SH order `order`.

        A map (path, preset name, equirect pixels [H, W, 3|4] or EnvMap) is loaded
        and projected here, once (a "sun:AZIMUTH,ELEVATION[,ANGLE]" is relight.lighting.lamps.sun_light),
        and scaled to `target` at `at` unless
        normalize=False (a black map fails here). SH coefficients [m, 3], an SHLight
        and a Decomposition's estimated light are light already: cut or zero-padded
        to the order and used as they are (an SHLight keeps its own target), unless
        normalize=True asks for them to be scaled to `target` too (a black light
        fails here): an explicit request is never dropped.
        """
        from relight.lighting.envmap import EnvMap

        # the SH order is checked once, by what makes the light of each kind of source: the
        # projection of a map, sun_light, or sh.num_coeffs for a light given as SH
        goal = float(target) if normalize is not False else None
        if isinstance(source, SHLight):
            return cls._light(fit_checked(source.base, sh.num_coeffs(order)), normalize, goal, source.target)
        if isinstance(source, str) and source.startswith("sun:"):  # a directional light (relight.lighting.lamps)
            from relight.lighting.lamps import parse_sun, sun_light

            base = sun_light(*parse_sun(source), order)
        elif isinstance(source, (str, os.PathLike)):
            from relight.lighting.envmap import load_equirect

            path = map_file(source)
            if cache is None:  # one resolve (the command's): nothing to share, no key to make
                base = sh_projection.project_equirect(load_equirect(path).pixels, order)
            else:  # the key: the file's state, so an edited map is projected again
                base = cache.get(("map", _file_key(path), order),
                                 lambda: sh_projection.project_equirect(load_equirect(path).pixels, order))
            try:
                return cls(base, goal)
            except ValueError as exc:  # a black map: the file (or the preset) named
                raise ValueError(f"{source}: {exc}") from exc
        elif hasattr(source, "light") and hasattr(source, "sh_order"):  # another photo's Decomposition
            return cls._light(fit_order(source.light, sh.num_coeffs(order)), normalize, goal)
        elif isinstance(source, EnvMap):
            base = sh_projection.project_equirect(source.pixels, order)
        else:
            arr = np.asarray(source)
            if arr.dtype == object or not np.issubdtype(arr.dtype, np.number):
                raise ValueError(f"light must be an HDR path, preset name, equirect pixels, SH array [n, 3] or "
                                 f"Decomposition, got {type(source).__name__}")
            if arr.ndim != 3:  # SH coefficients
                return cls._light(fit_order(arr.astype(np.float64), sh.num_coeffs(order)), normalize, goal)
            from relight.lighting.envmap import validate_equirect

            base = sh_projection.project_equirect(validate_equirect(arr).pixels, order)
        return cls(base, goal)

    @classmethod
    def _light(cls, coeffs: np.ndarray, normalize: bool | None, goal: float | None,
               own: float | None = None) -> "SHLight":
        """A light given as SH: as it is (its `own` target), or scaled to `goal` when
        normalize=True was asked for."""
        return cls(coeffs, own if normalize is None else goal)


def sh_light(source, order: int, *, rotation_deg: float = 0.0, normalize: bool | None = None,
             target: float = REFERENCE_LUMINANCE, cache: LightCache | None = None) -> np.ndarray:
    """SH light [(order+1)^2, 3], float64, of any light source turned by `rotation_deg`
    about world Z: SHLight.resolve(source, ...).at(rotation_deg). Maps follow the map
    recipe (project, rotate, scale to `target` unless normalize=False); a light given as
    SH is scaled only when normalize=True is asked for (see SHLight.resolve)."""
    return SHLight.resolve(source, order, normalize=normalize, target=target, cache=cache).at(rotation_deg, cache)


def directional_light(azimuth_deg: float, order: int, elevation_deg: float = 30.0,
                      ambient: float = 0.2, target: float = REFERENCE_LUMINANCE) -> np.ndarray:
    """A white directional light plus a constant ambient term, as SH [n, 3] at mean luminance `target`.

    Azimuth 0 lights the person from the camera's side (the light sits toward -Y
    from the person, docs/conventions.md); positive azimuth turns it about world Z
    like sh_rotation.z_rotation. `ambient` is the constant part's share of the irradiance a
    surface facing the light gets, so the far side is not pure black. A direct
    light's SH is its delta, Y_lm(d), truncated at `order`; the ambient term
    lives in Y_00 only.
    """
    if not (math.isfinite(azimuth_deg) and math.isfinite(elevation_deg) and 0.0 <= ambient < 1.0):
        raise ValueError("directional_light: azimuth and elevation must be finite, ambient in [0, 1)")
    e = math.radians(elevation_deg)
    direction = sh_rotation.z_rotation(azimuth_deg) @ np.array([0.0, -math.cos(e), math.sin(e)])
    delta = sh.sh_basis(direction, order)  # SH of a delta of integral 1 at `direction`
    # a delta of integral 1 gives a facing surface irradiance 1; a constant radiance c
    # gives irradiance pi * c: choose c so the ambient share of a facing surface is `ambient`
    c = ambient / (1.0 - ambient) / math.pi
    coeffs = np.zeros((sh.num_coeffs(order), 3))
    coeffs += delta[:, None]
    coeffs[0] += 2.0 * math.sqrt(math.pi) * c
    return sh.normalize_reference(coeffs, target)[0]
