"""The light and the dials of the current settings (preset, HDR file, World, another photo)."""

import math

import bpy

from . import bl_images, bl_world
from ..logic import light_sources
from ..worker import state
from .bl_session import addon_settings


def light_image_key(settings, model_path: str) -> tuple | None:
    if settings.light_kind != "IMAGE" or settings.light_image is None:
        return None
    return (bl_images.photo_id(settings.light_image, create=True), model_path, settings.quality)


def target_light(context, order: int, model_path: str):
    """(light, extra rotation in degrees) for the current settings.

    The light is a relight.lighting.light.SHLight (a preset, an HDR file or the World with the scene's lamps),
    SH coefficients (a restored light transfer) or the Decomposition of another
    photo: engine.coefficients turns any of them into what a relight takes;
    ValueError says what is missing.
    """
    settings = addon_settings(context)
    kind = settings.light_kind
    if kind == "PRESET":
        if settings.preset == "NONE":
            raise ValueError("No light preset is installed.")
        return light_sources.preset_light(settings.preset, order), 0.0
    if kind == "HDR":
        path = bpy.path.abspath(settings.hdr_path) if settings.hdr_path else ""
        return light_sources.hdr_file_light(path, order), 0.0
    if kind == "WORLD":
        world = context.scene.world
        lamps = bl_world.scene_lamps(context.scene)
        if not lamps:
            if world is None:
                raise ValueError("The scene has no World to take the light from.")
            return _world_light(world, order)
        light, rotation = None, 0.0
        try:
            if world is not None:
                light, rotation = _world_light(world, order)
        except ValueError as exc:
            if str(exc) != light_sources.BLACK_WORLD:  # a black World is fine when the lamps light
                raise
        return light_sources.with_lamps(light, rotation, lamps, order), 0.0
    if kind == "IMAGE":
        if settings.light_image is None:
            raise ValueError("Choose the photo to take the light from.")
        light = state.LIGHT_SOURCES.get(light_image_key(settings, model_path))
        if light is None:
            raise ValueError(f"Press Relight to estimate the light of '{settings.light_image.name}'.")
        return light, 0.0
    raise ValueError(f"Unknown light kind {kind!r}.")


def _world_light(world, order: int):
    """(Light, rotation) of the world, read (or baked) and projected once per
    state of its nodes (a hash of them: bl_world.fingerprint)."""
    key = bl_world.fingerprint(world)
    cached = state.WORLDS.get(key)
    if cached is None:
        cached = (bl_world.read_world(world), {})
        state.remember_world(key, cached)
    light, projected = cached
    if order not in projected:
        projected[order] = light_sources.equirect_light(light.equirect, order)
    return projected[order], light.rotation_deg


def current_dials(context, session: state.PhotoSession):
    """(light, rotation degrees, exposure EV, strength) of the current settings."""
    return dials_for(context, session.decomposition.sh_order, session.model_path)


def dials_for(context, order: int, model_path: str):
    settings = addon_settings(context)
    light, extra_rotation = target_light(context, order, model_path)
    return light, math.degrees(settings.rotation) + extra_rotation, settings.exposure, settings.strength
