"""Light sampling: HDR maps (bpy's 8 and relight's bundled presets) and Blender's Sky Texture.

Every light is rotated about world Z by a random angle, scaled so its
solid-angle-weighted mean luminance is a reference radiance drawn in
[0.7, 0.9] (relight.lighting.light.SHLight), and stored as SH of order N and
8 in the photo-camera frame. A procedural sky is rendered once to an
equirect image, so the world Cycles sees and the SH we store come from the
same pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relight.lighting import presets, sh, sh_rotation
from relight.lighting.envmap import load_equirect, validate_equirect
from relight.lighting.light import SHLight

SKY = "procedural:sky"  # not "sky": a bundled map has that name
SKY_SIZE = (128, 256)  # equirect rendering of the procedural sky (H, W)


def light_pool(kind: str) -> list[str]:
    """Light names for 'train' (everything but the held-out maps, plus the sky) or 'heldout'."""
    if kind == "train":
        names = presets.training_presets(include_blender=True) + [SKY]
        assert not set(names) & presets.HELD_OUT
        return names
    if kind == "heldout":
        return sorted(presets.HELD_OUT)
    raise ValueError(f"light_pool must be 'train' or 'heldout', got {kind!r}")


@dataclass
class SampledLight:
    """One light the farm drew for a scene: its map (what Cycles' World shows) and its SH
    in the camera frame (what the sidecar records). The runtime's light, SH coefficients
    only, is relight.lighting.light's."""

    name: str
    source: str  # "blender", "bundled" or "sky"
    rotation_deg: float
    scale: float
    reference_luminance: float
    pixels: np.ndarray  # [H, W, 3] linear, unscaled, unrotated (what the world shows)
    sh: np.ndarray  # [(order+1)^2, 3] camera frame, rotated and scaled
    sh8: np.ndarray  # [81, 3]
    sky: dict | None = None
    hard: dict | None = None  # farm.synthesis.hard_lights: kind, lobes, ambient

    def record(self) -> dict:
        out = {
            "name": self.name,
            "source": self.source,
            "rotation_deg": self.rotation_deg,
            "scale": self.scale,
            "reference_luminance": self.reference_luminance,
            "sh": self.sh.tolist(),
            "sh8": self.sh8.tolist(),
        }
        if self.sky is not None:
            out["sky"] = self.sky
        if self.hard is not None:
            out["hard"] = self.hard
        return out


def sample_sky_params(rng: np.random.Generator) -> dict:
    return {
        "sky_type": "MULTIPLE_SCATTERING",
        "sun_elevation_deg": float(rng.uniform(3.0, 75.0)),
        "sun_rotation_deg": float(rng.uniform(0.0, 360.0)),
        "altitude_m": float(rng.uniform(0.0, 2000.0)),
        "air_density": float(rng.uniform(0.5, 2.0)),
        "aerosol_density": float(rng.uniform(0.3, 3.0)),
        "ozone_density": float(rng.uniform(0.5, 2.0)),
        "sun_size_deg": float(rng.uniform(0.5, 2.0)),
    }


def sample_light(
    rng: np.random.Generator,
    pool: list[str],
    order: int,
    world_to_camera: np.ndarray,
    render_sky=None,
) -> SampledLight:
    """Draw a map (or sky), a rotation and a reference radiance; compute its SH.

    `render_sky(params) -> pixels [H, W, 3]` renders the procedural sky
    (farm.scene passes the Cycles-based one).
    """
    name = str(pool[int(rng.integers(len(pool)))])
    rotation = float(rng.uniform(0.0, 360.0))
    target = float(rng.uniform(0.7, 0.9))
    sky = None
    if name == SKY:
        if render_sky is None:
            raise ValueError("the sky light needs a render_sky function")
        sky = sample_sky_params(rng)
        pixels = validate_equirect(render_sky(sky), source="sky").pixels
        source = "sky"
    else:
        pixels = load_equirect(presets.preset_path(name)).pixels
        source = "blender" if name.startswith(presets.BLENDER_PREFIX) else "bundled"
    # the map recipe (relight.lighting.light): project at order max(N, 8), rotate about Z, normalize
    coeffs, scale = SHLight.resolve(pixels, max(order, 8), target=target).turned(rotation)
    coeffs = sh_rotation.rotate(coeffs, world_to_camera)
    return SampledLight(
        name=name,
        source=source,
        rotation_deg=rotation,
        scale=float(scale),
        reference_luminance=target,
        pixels=pixels,
        sh=coeffs[: sh.num_coeffs(order)].copy(),
        sh8=coeffs[:81].copy(),
        sky=sky,
    )
