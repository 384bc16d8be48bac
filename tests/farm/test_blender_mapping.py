"""Proves the conventions against Cycles: equirect mapping, SH projection,
Lambert transport (A_l / pi), camera frame.

A diffuse sphere (albedo 0.5) lit only by an HDR world (Environment Texture,
default mapping, closest-texel lookup, so the map is exactly the
piecewise-constant function relight.lighting.sh projects) is rendered by Cycles and
compared pixel by pixel with albedo * (T . L), T the unoccluded Lambert
transport of the pixel's normal (from Cycles' Normal pass) and L our order-8
projection of the same map.

Error budget, measured with this setup (apartment map, 48x48, 2 x 128 spp),
as fractions of the mean pixel: mean |Cycles - prediction| 0.95 %; Monte
Carlo noise of the two-render mean 0.90 % (mean |.|); SH truncation at
order 8 0.066 % mean, 0.43 % max, against a direct quadrature over every
texel. So the agreement is at the noise level, while a 5-degree turn of the
map gives ~3 % and 90 degrees ~50 %.
"""

import math
import warnings

import bpy  # the farm extra; the test suite runs with it
import numpy as np
import pytest

from cycles_support import lambert_sphere, photo_camera, render_with_normals, sphere_pixels
from relight.lighting import envmap, presets, sh_projection, sh_rotation
from relight.files import exr
from relight.network import prt

ALBEDO = 0.5
ORDER = 8
SIZE = 48
SAMPLES = 128


def downsampled_map():
    """The bundled 'apartment' map (a strong light from -Y, i.e. behind the
    camera, and +X), box-filtered 4x to 128x64 to keep the render cheap."""
    full = envmap.load_equirect(presets.preset_path("apartment")).pixels
    h, w = full.shape[0] // 4, full.shape[1] // 4
    return full.reshape(h, 4, w, 4, 3).mean(axis=(1, 3)).astype(np.float32)


def render_sphere(map_path, out_path, seed):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    world = bpy.data.worlds.new("hdr")
    scene.world = world
    world.use_nodes = True
    nodes = world.node_tree.nodes
    texture = nodes.new("ShaderNodeTexEnvironment")  # default mapping: no Vector input
    texture.image = bpy.data.images.load(str(map_path))
    texture.interpolation = "Closest"
    world.node_tree.links.new(texture.outputs["Color"], nodes["Background"].inputs["Color"])
    lambert_sphere(scene, ALBEDO)
    photo_camera(scene)  # docs/conventions.md: at the origin, looking along +Y
    passes = render_with_normals(scene, out_path, SIZE, SAMPLES, seed)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return passes


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("blender_mapping")
    light_map = downsampled_map()
    map_path = exr.write_exr(tmp / "map.exr", {c: light_map[..., i] for i, c in enumerate("RGB")})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # world.use_nodes, gone in Blender 6
        passes = [render_sphere(map_path, tmp / f"seed{seed}.exr", seed) for seed in (0, 1)]
    return {"map": light_map, **sphere_pixels(*passes)}


def predict(n, L):
    return ALBEDO * prt.shading(prt.lambert_transport(n, ORDER), L)


def test_sphere_matches_sh_prediction(renders):
    n, light_map = renders["n"], renders["map"]
    assert len(n) > 1000
    mean = 0.5 * (renders["r0"] + renders["r1"])
    # (r0 - r1) / 2 has the same distribution as the noise of the mean
    noise = 0.5 * (renders["r0"] - renders["r1"])
    L = sh_projection.project_equirect(light_map, ORDER, precision="float64")
    pred = predict(n, L)

    # truncation: order-8 SH shading vs direct quadrature over every texel
    dirs, omega = sh_projection.equirect_directions(*light_map.shape[:2])
    texel_power = (light_map * omega[:, None, None]).reshape(-1, 3)
    direct = ALBEDO * np.maximum(n @ dirs.reshape(-1, 3).T, 0) @ texel_power / np.pi
    truncation = np.abs(pred - direct)
    assert truncation.max() < 0.01 * direct.mean()

    error = np.abs(mean - pred)
    scale = mean.mean()
    # |mean - pred| <= |noise| + |truncation| per pixel; averaged, with a 20 %
    # margin for the sampling error of mean|noise| over ~4000 values (~1.5 %)
    budget = 1.2 * np.abs(noise).mean() + truncation.mean()
    print(f"mean |error| {error.mean() / scale:.4%}, noise {np.abs(noise).mean() / scale:.4%}, "
          f"truncation {truncation.mean() / scale:.4%} (max {truncation.max() / scale:.4%})")
    assert error.mean() < budget
    # no localised mistake: every pixel within 8 noise sigmas (relative noise
    # is uniform enough here) plus its own truncation error
    sigma = np.std(noise / pred)
    assert np.all(error <= 8 * sigma * pred + truncation)
    # the light's DC term is right to well under the noise: exposure scale ok
    assert abs((mean - pred).mean()) < 4 * noise.std() / math.sqrt(noise.size) + truncation.mean()

    # the test has teeth: wrong mappings fail it by a wide margin
    for degrees in (90.0, -90.0, 180.0, 5.0):
        turned = predict(n, sh_rotation.rotate(L, sh_rotation.z_rotation(degrees)))
        assert np.abs(mean - turned).mean() > 1.5 * budget, degrees
    mirrored = L.copy()  # u = 0.5 + phi / 2pi instead: y -> -y flips every m < 0
    for l in range(ORDER + 1):
        mirrored[l * l : l * l + l] *= -1
    assert np.abs(mean - predict(n, mirrored)).mean() > 10 * budget
    upside_down = sh_rotation.rotate(L, np.diag([1.0, -1.0, -1.0]))  # v flipped and u mirrored
    assert np.abs(mean - predict(n, upside_down)).mean() > 10 * budget


def test_photo_camera_frame(renders):
    # camera at the origin looking along +Y: the sphere's normals point back
    # at it (-Y), X grows to the right, Z to the top (row 0 of the EXR)
    n, rows, cols = renders["n"], renders["rows"], renders["cols"]
    assert np.all(n[:, 1] < 0)
    centre = (SIZE - 1) / 2
    right, top = cols > centre + SIZE / 6, rows < centre - SIZE / 6
    assert n[right, 0].min() > 0 and n[cols < centre - SIZE / 6, 0].max() < 0
    assert n[top, 2].min() > 0 and n[rows > centre + SIZE / 6, 2].max() < 0
    # an orthographic view of a unit sphere: n_x, n_z equal the pixel centre's
    # position; tolerance half a pixel (0.023) for the box-filtered normals
    scale = 2.2 / SIZE  # ortho_scale over the image width
    x = (cols + 0.5 - SIZE / 2) * scale
    z = (SIZE / 2 - rows - 0.5) * scale
    np.testing.assert_allclose(n[:, 0], x, atol=0.02)
    np.testing.assert_allclose(n[:, 2], z, atol=0.02)


def test_radiance_reader_reads_blenders_hdr(tmp_path):
    # a foreign RGBE encoder: Blender writes the bundled map as Radiance .hdr
    bpy.ops.wm.read_factory_settings(use_empty=True)
    source = presets.preset_path("venice")
    image = bpy.data.images.load(str(source))
    scene = bpy.context.scene
    scene.render.image_settings.file_format = "HDR"
    image.save_render(str(tmp_path / "venice.hdr"), scene=scene)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    decoded = envmap.read_radiance_hdr(tmp_path / "venice.hdr")
    planes = exr.read_exr(source)
    original = np.stack([planes[c] for c in "RGB"], axis=-1)
    # RGBE cannot hold the few negative texels of the lossy source: skip them
    ok = (original >= 0).all(axis=-1)
    assert ok.mean() > 0.99
    # a shared 8-bit mantissa: one step is max(R, G, B) / 128 at most, and
    # decoding at the step's centre halves it
    step = original.max(axis=-1, keepdims=True) / 128
    assert np.all(np.abs(decoded - original)[ok] <= 0.5 * step[ok] + 1e-12)
