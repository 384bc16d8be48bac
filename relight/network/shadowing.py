"""Cast shadows in the relighting formula: the key light's share the person's own body blocks.

SH shading cannot cast a shadow: the light's directional part (relight.lighting.directional) is
split off and its shading dimmed by the share of the lamp each pixel sees past the rest of the
person (relight.geometry.shadows over the network's depth when the model has the depth head, scaled
to its normals' slopes by relight.geometry.relief.scaled_to_normals; else over the relief integrated
from the normals, relight.geometry.relief.depth_from_normals):

    shading' = T . L' - (1 - V') max(T . K', 0)        K' the key's SH, V' its visibility

so where nothing blocks the key the formula is the SH one, bit for bit in meaning. The photo's own
light may cast shadows too (`own_light_shadows`): the albedo the network derived from the photo
(albedo = photo / T . L, photo-consistent) then holds them, and is corrected by
T . L / (T . L - (1 - V) (T . K)) at most OWN_SHADOW_GAIN times. All at working resolution, over
the matte's pixels, computed once per decomposition (the relief) and once per key (the visibility).
"""

from __future__ import annotations

import math

import numpy as np

from relight.geometry.relief import depth_from_normals, normals_from_transport, scaled_to_normals
from relight.geometry.shadows import cast_visibility
from relight.lighting import sh
from relight.lighting.directional import directional_part
from relight.lighting.key_light import KeyLight, key_coeffs

__all__ = ["OWN_SHADOW_GAIN", "ShadowCaster", "key_of"]

OWN_SHADOW_GAIN = 4.0   # the most a shadow in the photo's own light may brighten the albedo under it
CACHE = 8               # visibilities kept per decomposition (a lamp dragged in Blender asks many)


def key_of(light: np.ndarray) -> KeyLight | None:
    """The key whose shadows a relight under the SH light [n, 3] casts (None: no directional part)."""
    return directional_part(np.asarray(light, np.float64))


class ShadowCaster:
    """A decomposition's cast shadows: its relief (made on first use) and visibilities per key.

    transport [h, w, n], alpha [h, w] at working resolution; `matte` the flat indices of the pixels
    the relighting formula evaluates (Decomposition's); `network_depth` [h, w] the depth head's
    output (None: the model has none)."""

    def __init__(self, transport: np.ndarray, alpha: np.ndarray, matte: np.ndarray,
                 network_depth: np.ndarray | None = None):
        self.transport, self.alpha, self.matte = transport, alpha, matte
        self.network_depth = network_depth
        self._depth = None
        self.depth_source = None  # "network" or "relief", once the depth is made
        self._visibility: dict = {}

    @property
    def depth(self) -> np.ndarray:
        """The depth [h, w] (working pixels along +Y) the shadows are cast over: the network's, scaled
        to its normals' slopes, when it has one that fits them; else the relief integrated from the
        normals (relight.geometry.relief)."""
        if self._depth is None:
            inside = self.alpha > 0
            normals = normals_from_transport(self.transport)
            depth = None
            if self.network_depth is not None:
                depth = scaled_to_normals(self.network_depth, normals, inside)
            self.depth_source = "relief" if depth is None else "network"
            self._depth = depth_from_normals(normals, inside) if depth is None else depth
            self._depth.setflags(write=False)
        return self._depth

    def visibility(self, key: KeyLight) -> np.ndarray:
        """The share [h, w] of the key each working pixel sees (1 off the person)."""
        cache_key = (tuple(np.round(np.asarray(key.direction, np.float64), 9)), round(float(key.half_angle), 9))
        found = self._visibility.get(cache_key)
        if found is None:
            found = cast_visibility(self.depth, self.alpha > 0, key.direction, math.degrees(key.half_angle))
            found.setflags(write=False)
            if len(self._visibility) >= CACHE:
                self._visibility.pop(next(iter(self._visibility)))
            self._visibility[cache_key] = found
        return found

    def blocked_shading(self, key: KeyLight, transport_m: np.ndarray, order: int) -> np.ndarray:
        """(1 - V) (T . K) [m, 3] over the matte's pixels: the key's shading the body blocks
        (transport_m the matte's transport, order the bands evaluated)."""
        n = sh.num_coeffs(order)
        blocked = 1.0 - self.visibility(key).reshape(-1)[self.matte]
        K = key_coeffs(key, order).astype(np.float32)
        # the key's shading can only be blocked where it is light: its SH ringing below 0 (facing away)
        # is not light a shadow removes
        return blocked[:, None].astype(np.float32) * np.maximum(transport_m[:, :n] @ K[:n], 0.0)

    def own_light_gain(self, light: np.ndarray, transport_m: np.ndarray) -> np.ndarray | None:
        """The albedo's correction [m, 1] for the shadows the photo's own light [n, 3] cast, or
        None when that light has no directional part."""
        key = key_of(light)
        if key is None:
            return None
        order = sh.order_from_num_coeffs(light.shape[0])
        full = transport_m @ np.asarray(light, np.float32)
        lit = full - self.blocked_shading(key, transport_m, order)
        gain = np.where(lit > 1e-6, full / np.maximum(lit, 1e-6), 1.0)
        return np.clip(gain, 1.0, OWN_SHADOW_GAIN).astype(np.float32)
