"""The World made by Photo Light -> World, rendered by Cycles: a diffuse sphere under it gets
the SH irradiance the runtime computes for the same light (docs/conventions.md).

A light from camera-left (-X, 20 degrees up, a fifth of the irradiance ambient)
is put in a relit photo's session, the operator makes the World, and Cycles
renders a Lambertian sphere seen by the photo camera (orthographic, looking
along +Y) twice with different seeds. Compared per pixel, using Cycles'
Normal pass, with albedo * (T . L), T the unoccluded Lambert transport at the
runtime's order 4 and L the light: relative RMS within 3 % (the issue's
goal). The budget: the map's own irradiance error against the SH (0.7 %,
relight.lighting.light_map.irradiance_error) plus Monte Carlo noise. Against the
irradiance of the map itself (its SH to order 16) the render agrees to the
noise, and a mirrored or turned light fails by far.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import bpy

import blender_addon
from blender_addon.blender import bl_images
from blender_addon.worker import state
from cycles_support import lambert_sphere, photo_camera, render_with_normals, sphere_pixels
from relight.network import prt
from relight.lighting import sh, sh_projection, sh_rotation
from relight.lighting.light import directional_light
from relight.lighting.light_map import irradiance_error
from addon_support import write_person_png
from tiny_model import make_tiny_model

ALBEDO = 0.8
ORDER = 4
SIZE = 48
SAMPLES = 256


def camera_left_light():
    return directional_light(-90.0, ORDER, elevation_deg=20.0, ambient=0.2)


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    folder = tmp_path_factory.mktemp("photo_world_cycles")
    model = make_tiny_model(tmp_path_factory)
    write_person_png(folder / "person.png")
    blender_addon.register()
    try:
        bpy.ops.wm.read_homefile(use_empty=True)
        photo = bpy.data.images.load(str(folder / "person.png"))
        s = bpy.context.scene.relight_photo
        s.model_path, s.quality, s.mask_mode, s.light_kind, s.preset = str(model), "DRAFT", "NETWORK", "PRESET", "studio"
        assert bpy.ops.relight_photo.relight(image_name=photo.name, synchronous=True) == {"FINISHED"}
        session = state.SESSIONS[photo[bl_images.PHOTO_ID]]
        session.decomposition.light = camera_left_light()  # as if the network had estimated it
        # the whole light as one map (no key lamp: tests/blender_addon/test_addon_lamps.py renders the lamp + World)
        assert bpy.ops.relight_photo.light_to_world(image_name=photo.name, lamp_free=True) == {"FINISHED"}
        scene = bpy.context.scene
        texture = next(n for n in scene.world.node_tree.nodes if n.type == "TEX_ENVIRONMENT")
        w, h = texture.image.size
        flat = np.empty(w * h * 4, np.float32)
        texture.image.pixels.foreach_get(flat)
        world_map = flat.reshape(h, w, 4)[::-1, :, :3].copy()
        lambert_sphere(scene, ALBEDO)
        photo_camera(scene)
        passes = [render_with_normals(scene, folder / f"seed{seed}.exr", SIZE, SAMPLES, seed) for seed in (0, 1)]
    finally:
        bpy.ops.wm.read_homefile()
        blender_addon.unregister()
    return {"map": world_map, **sphere_pixels(*passes)}


def predict(n, L):
    order = sh.order_from_num_coeffs(L.shape[0])
    return ALBEDO * prt.shading(prt.lambert_transport(n, order), L)


def relative_rms(a, b):
    return float(np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(np.mean(b ** 2)))


def test_sphere_under_the_world_matches_the_runtimes_sh_irradiance(renders):
    n = renders["n"]
    assert len(n) > 1000
    L = camera_left_light()
    mean = 0.5 * (renders["r0"] + renders["r1"])
    noise = 0.5 * (renders["r0"] - renders["r1"])  # distributed like the noise of the mean
    runtime = predict(n, L)
    map_error = irradiance_error(L, renders["map"])
    error = relative_rms(mean, runtime)
    noise_rms = float(np.sqrt(np.mean(noise ** 2)) / np.sqrt(np.mean(runtime ** 2)))
    # the map's own irradiance, to order 16 (A_16 / A_0 < 0.002): what Cycles integrates
    own = predict(n, sh_projection.project_equirect(renders["map"], 16, precision="float64"))
    print(f"relative RMS vs the runtime's SH: {error:.4f} (map irradiance error {map_error:.4f}, "
          f"noise {noise_rms:.4f}); vs the map's own irradiance {relative_rms(mean, own):.4f}")
    assert error < 0.03  # the goal
    # and its parts: noise and the map's error add in quadrature; 20 % margin on the noise estimate
    assert error < math.hypot(1.2 * noise_rms, map_error) + 0.002
    assert relative_rms(mean, own) < 1.2 * noise_rms + 0.002  # the mapping is exact: only noise is left


def test_a_light_from_camera_left_lights_the_spheres_camera_left_side(renders):
    n = renders["n"]
    luminance = (0.5 * (renders["r0"] + renders["r1"])).mean(axis=-1)
    left, right = luminance[n[:, 0] < -0.3].mean(), luminance[n[:, 0] > 0.3].mean()
    assert left > 3 * right, (left, right)
    # teeth: the light from camera-right (turned 180 degrees about Z) or from the camera's side
    # (turned 90) is far off
    L = camera_left_light()
    mean = 0.5 * (renders["r0"] + renders["r1"])
    assert relative_rms(mean, predict(n, sh_rotation.rotate(L, sh_rotation.z_rotation(180.0)))) > 0.3
    assert relative_rms(mean, predict(n, sh_rotation.rotate(L, sh_rotation.z_rotation(90.0)))) > 0.15
