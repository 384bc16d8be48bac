"""Per-vertex transport bake (farm/rendering/bake.py): analytic cases, robustness, and Cycles agreement."""

from __future__ import annotations

import math

import numpy as np
import pytest

from farm.rendering import bake
from farm.synthesis.meshops import vertex_normals
from relight.network import prt
from relight.lighting import sh, sh_projection, sh_rotation

trimesh = pytest.importorskip("trimesh")


def icosphere(subdivisions=3, radius=1.0, centre=(0.0, 0.0, 0.0)):
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    v = np.asarray(m.vertices, dtype=np.float64) + np.asarray(centre)
    f = np.asarray(m.faces, dtype=np.int64)
    return v, f, vertex_normals(v, f)


def constant_light(order, radiance=1.0):
    L = np.zeros((sh.num_coeffs(order), 3))
    L[0] = 2.0 * math.sqrt(math.pi) * radiance  # integral of radiance * Y_00
    return L


def quadrature_bound(order, directions):
    """Error bound of the equal-area direction quadrature for a kinked integrand.

    max(0, n.w) Y_lm(w) / pi is continuous with a derivative jump along one
    great circle. Only the ~2 pi / delta strata (delta = sqrt(4 pi / S)) cut by
    it carry an error, each at most its area delta^2 times the integrand's
    variation across it, delta * max|Y| / pi:
    2 pi / delta * delta^3 * Ymax / pi = 2 delta^2 Ymax = 8 pi Ymax / S.
    """
    ymax = np.abs(sh.sh_basis(bake.fibonacci_directions(4096), order)).max()
    return 8.0 * math.pi * ymax / directions


def test_fibonacci_directions_are_unit_and_balanced():
    d = bake.fibonacci_directions(512, np.random.default_rng(3))
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    # Equal-area strata: the mean direction is ~0 (O(1/S)) and the second moment
    # is ~I/3 (the sphere's), both to a few 1/S.
    assert np.abs(d.mean(axis=0)).max() < 4.0 / 512
    assert np.abs(d.T @ d / 512 - np.eye(3) / 3).max() < 4.0 / 512


@pytest.mark.parametrize("directions", [256, 1024])
def test_unoccluded_lambert_matches_analytic_transport(directions):
    v, f, n = icosphere(3)
    result = bake.bake_transport(v, f, n, 4, directions, rng=np.random.default_rng(0))
    expected = prt.lambert_transport(n, 4)  # A_l / pi * Y_lm(n)
    err = np.abs(result.transport - expected).max()
    assert err < quadrature_bound(4, directions)
    # White Lambert point under radiance 1 -> T.L = 1 (to the quadrature bound).
    shade = prt.shading(result.transport, constant_light(4))[:, 0]
    assert np.abs(shade - 1.0).max() < quadrature_bound(0, directions) * 2 * math.sqrt(math.pi)
    assert shade.max() <= 1.0 + 1e-6
    assert result.rays == int((n @ bake.fibonacci_directions(directions, np.random.default_rng(0)).T > 0).sum())


def test_disc_occluder_blocks_the_expected_cosine_fraction():
    """A point facing +Z under a disc of angular radius theta0 keeps cos^2(theta0) of its irradiance.

    Fraction of the cosine-weighted hemisphere inside a cone of half-angle
    theta0 is sin^2(theta0).
    """
    theta0 = math.radians(40.0)
    segments = 256
    ring = np.stack(
        [np.tan(theta0) * np.cos(np.linspace(0, 2 * np.pi, segments, endpoint=False)),
         np.tan(theta0) * np.sin(np.linspace(0, 2 * np.pi, segments, endpoint=False)),
         np.ones(segments)], axis=1)
    # the receiver: a tiny triangle at the origin facing +Z
    receiver = np.array([[0.0, 0.0, 0.0], [1e-3, 0.0, 0.0], [0.0, 1e-3, 0.0]])
    v = np.concatenate([receiver, [[0.0, 0.0, 1.0]], ring])
    fan = [[3, 4 + i, 4 + (i + 1) % segments] for i in range(segments)]
    f = np.array([[0, 1, 2]] + fan)
    n = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    directions = 4096
    result = bake.bake_transport(v, f, n, 2, directions, rng=np.random.default_rng(1), offset=1e-6)
    shade = prt.shading(result.transport[:1], constant_light(2))[0, 0]
    # The disc's edge polygon is inscribed: its solid angle is smaller by the
    # area ratio sin(2 pi / N) N / (2 pi), < 1e-3 for N = 256.
    assert shade == pytest.approx(math.cos(theta0) ** 2, abs=quadrature_bound(0, directions) * 2 * math.sqrt(math.pi) + 1e-3)


def test_fully_enclosed_point_gets_no_light():
    inner_v, inner_f, inner_n = icosphere(2, radius=0.5)
    outer_v, outer_f, _ = icosphere(2, radius=1.0)
    v = np.concatenate([inner_v, outer_v])
    f = np.concatenate([inner_f, outer_f + len(inner_v)])
    n = np.concatenate([inner_n, -vertex_normals(outer_v, outer_f)])
    result = bake.bake_transport(v, f, n, 2, 128, rng=np.random.default_rng(2))
    assert np.abs(result.transport[: len(inner_v)]).max() == 0.0


def test_same_rng_gives_identical_transport_and_threads_do_not_matter():
    v, f, n = icosphere(2)
    a = bake.bake_transport(v, f, n, 4, 128, rng=np.random.default_rng(5), threads=1).transport
    b = bake.bake_transport(v, f, n, 4, 128, rng=np.random.default_rng(5), threads=2).transport
    assert np.array_equal(a, b)


def test_active_mask_bakes_only_the_chosen_vertices_and_they_match_the_full_bake():
    v, f, n = icosphere(2)
    full = bake.bake_transport(v, f, n, 4, 128, rng=np.random.default_rng(5))
    active = v[:, 1] < 0.0
    part = bake.bake_transport(v, f, n, 4, 128, rng=np.random.default_rng(5), active=active)
    # Same rays and weights; only the float32 matmul's blocking differs (other
    # rows in the chunk), so agreement is to float32 rounding of a sum of S
    # terms each < 4 pi / S: S * eps32 * 4 pi / S ~ 1.5e-6.
    assert np.abs(part.transport[active] - full.transport[active]).max() < 2e-6
    assert np.all(part.transport[~active] == 0.0)
    assert part.rays < 0.6 * full.rays
    with pytest.raises(ValueError, match="active"):
        bake.bake_transport(v, f, n, 4, 16, active=active[:-1])


def _materials(count, roughness, metallic, specular=1.0):
    return bake.VertexMaterials(
        roughness=np.full(count, float(roughness)),
        metallic=np.full(count, float(metallic)),
        specular=np.full(count, float(specular)),
    )


@pytest.mark.parametrize("roughness", [0.0, 1e-4, 0.3, 1.0])
@pytest.mark.parametrize("metallic", [0.0, 1.0])
def test_view_dependent_bake_is_finite_and_energy_bounded(roughness, metallic):
    """roughness -> 0, grazing and back-facing views: finite, and white energy <= 1."""
    v, f, n = icosphere(3)
    # A camera close to the sphere sees a cap; every other vertex is grazing or back-facing.
    view_point = np.array([0.0, -1.3, 0.0])
    result = bake.bake_transport(
        v, f, n, 4, 256, view_point=view_point, materials=_materials(len(v), roughness, metallic),
        rng=np.random.default_rng(0),
    )
    assert result.specular and np.all(np.isfinite(result.transport))
    shade = prt.shading(result.transport, constant_light(4))[:, 0]
    assert shade.max() <= 1.0 + 1e-6
    assert shade.min() >= 0.0
    assert result.alpha_floor >= bake.ALPHA_FLOOR


def test_brdf_cos_at_exact_grazing_and_behind():
    normals = np.tile([0.0, 0.0, 1.0], (5, 1))
    views = np.array([[0, 0, 1.0], [1, 0, 0.0], [0, 1, -1e-9], [0, 0, -1.0], [0.6, 0, -0.8]])
    views /= np.linalg.norm(views, axis=1, keepdims=True)
    dirs = np.array([[0, 0, 1.0], [1, 0, 0.0], [-1, 0, 0.0], [0, 0, -1.0], [0.6, 0, 0.8]])
    for rough in (0.0, 0.5, 1.0):
        w = bake.view_dependent_brdf_cos(normals, views, dirs, np.full(5, rough), np.zeros(5), np.ones(5))
        assert np.all(np.isfinite(w)) and np.all(w >= 0.0)
        # Directions at or below the horizon carry no energy (the cosine factor).
        assert np.all(w[:, 1:4] == 0.0)


def test_view_dependent_bake_reduces_to_lambert_when_smooth_diffuse():
    """metallic 0, specular 0, roughness 0 (Oren-Nayar sigma 0 = Lambert) is the Lambert bake."""
    v, f, n = icosphere(2)
    lam = bake.bake_transport(v, f, n, 4, 256, rng=np.random.default_rng(0)).transport
    view = bake.bake_transport(
        v, f, n, 4, 256, rng=np.random.default_rng(0), view_point=np.array([0, -4.0, 0]),
        materials=_materials(len(v), 0.0, 0.0, specular=0.0),
    ).transport
    # The GGX lobe with F0 = 0 is zero and the Fresnel-weighted diffuse is 1 * Lambert.
    assert np.abs(view - lam).max() < 1e-5


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"vertices": np.full((3, 3), np.nan)}, "NaN"),
        ({"faces": np.array([[0, 1, 7]])}, "out of range"),
        ({"normals": np.full((3, 3), 2.0)}, "unit"),
        ({"order": -1}, "order"),
        ({"directions": 0}, "directions"),
        ({"view_point": np.zeros(3)}, "both"),
    ],
)
def test_bad_input_raises_clear_value_error(kwargs, message):
    args = {
        "vertices": np.eye(3), "faces": np.array([[0, 1, 2]]), "normals": np.tile([0, 0, 1.0], (3, 1)),
        "order": 2, "directions": 16,
    }
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        bake.bake_transport(args.pop("vertices"), args.pop("faces"), args.pop("normals"), args.pop("order"),
                            args.pop("directions"), **args)


def test_bad_materials_raise():
    v, f, n = icosphere(1)
    with pytest.raises(ValueError, match="roughness"):
        bake.bake_transport(v, f, n, 2, 16, view_point=np.array([0, -3, 0.0]),
                            materials=_materials(len(v), 1.5, 0.0))
    with pytest.raises(ValueError, match="shape"):
        bake.bake_transport(v, f, n, 2, 16, view_point=np.array([0, -3, 0.0]),
                            materials=_materials(len(v) - 1, 0.5, 0.0))


# ----------------------------------------------------------------- Cycles agreement (bpy)


def _cycles_sphere_scene(tmp_path, meshes, order, directions, materials=None, resolution=48):
    """Reset Blender, add the meshes with their baked T as AOVs, camera at (0, -3, 0) looking +Y.

    The camera frame is then the world frame (rows right=X, forward=Y, up=Z).
    """
    bpy = pytest.importorskip("bpy")
    from farm.rendering import blender_scene, passes

    scene = blender_scene.reset_scene()
    passes.configure_film(scene, (resolution, resolution))
    v = np.concatenate([m[0] for m in meshes])
    offsets = np.cumsum([0] + [len(m[0]) for m in meshes])
    f = np.concatenate([m[1] + offsets[i] for i, m in enumerate(meshes)])
    n = np.concatenate([m[2] for m in meshes])
    kwargs = {}
    if materials is not None:
        kwargs = {"view_point": np.array([0.0, -3.0, 0.0]), "materials": materials}
    T = bake.bake_transport(v, f, n, order, directions, rng=np.random.default_rng(0), **kwargs).transport
    names = [f"t{i}" for i in range((sh.num_coeffs(order) + 2) // 3)]
    spec = blender_scene.AovSpec(names, ["albedo"])
    blender_scene.register_aovs(scene.view_layers[0], spec)
    mats = []
    for i, (mv, mf, mn, params) in enumerate(meshes):
        blocks = blender_scene.pack_vectors(T[offsets[i]:offsets[i + 1]])
        obj = blender_scene.mesh_object(f"m{i}", mv, mf, mn, dict(zip(names, blocks)), scene=scene)
        mat = bpy.data.materials.new(f"mat{i}")
        bsdf = mat.node_tree.nodes["Principled BSDF"]
        for key, value in params.items():
            bsdf.inputs[key].default_value = value
        blender_scene.add_attribute_aovs(mat, names)
        rgb = mat.node_tree.nodes.new("ShaderNodeRGB")
        rgb.outputs[0].default_value = tuple(params["Base Color"])
        mat.node_tree.links.new(rgb.outputs[0], bsdf.inputs["Base Color"])
        blender_scene.add_socket_aov(mat, "albedo", rgb.outputs[0])
        obj.data.materials.append(mat)
        mats.append(mat)
    blender_scene.camera_object(np.array([0.0, -3.0, 0.0]), np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]), 50.0,
                         scene=scene)
    return scene, spec, names


LAMBERT_WHITE = {"Base Color": (1.0, 1.0, 1.0, 1.0), "Roughness": 1.0, "Specular IOR Level": 0.0,
                 "Diffuse Roughness": 0.0}


@pytest.mark.parametrize("k", [0, 1, 2, 3, 4, 6, 8])
def test_cycles_under_one_sh_basis_function_matches_baked_transport(tmp_path, k):
    """World radiance = Y_k (negative allowed), direct light only: each pixel is T_k.

    A white Lambert sphere with a second sphere beside it (so visibility
    matters). With zero bounces Cycles computes exactly
    integral f V max(0, n.w) Y_k(w) dw per shading point. Errors: Monte Carlo
    noise (measured here from two seeds), the bake quadrature bound, and
    interpolating per-vertex T across triangles (edge ~0.03 rad on this mesh,
    second order: < 1e-3 of |T|); the mean absolute error must stay below
    twice the noise plus the bound.
    """
    from cycles_support import sh_world
    from farm.rendering import passes

    sphere = icosphere(4, radius=0.5) + (LAMBERT_WHITE,)
    blocker = icosphere(3, radius=0.35, centre=(0.75, 0.1, 0.2)) + (LAMBERT_WHITE,)
    directions = 1024
    scene, spec, names = _cycles_sphere_scene(tmp_path, [sphere, blocker], 2, directions)
    sh_world(scene, k)
    scene.world.cycles.sampling_method = "NONE"  # negative emission: no importance map
    geo = passes.render_geometry(scene, spec, tmp_path, samples=4)
    t_pix = np.concatenate([geo.aovs[n] for n in names], axis=-1)[..., k]
    renders = []
    for seed in (0, 1):
        scene.cycles.seed = seed
        pt = passes.render_path_traced(scene, tmp_path, f"pt{seed}", samples=128, denoise=False, bounces=0)
        renders.append(pt.image[..., 0])
    inside = geo.alpha > 0.999
    assert inside.sum() > 300
    noise = np.abs(renders[0] - renders[1])[inside].mean() / math.sqrt(2.0)
    err = np.abs(0.5 * (renders[0] + renders[1]) - t_pix)[inside].mean()
    tolerance = 2.0 * noise + quadrature_bound(2, directions)
    assert err < tolerance, (err, noise, tolerance)
    # and the signal is far above that: the comparison is not vacuous
    assert np.abs(t_pix[inside]).mean() > 3.0 * tolerance or k == 6


def _hdr_scene(tmp_path, material, rotation_deg):
    from farm.rendering import blender_scene, passes
    from relight.lighting import presets
    from relight.lighting.envmap import load_equirect

    sphere = icosphere(4, radius=0.6) + (material,)
    order = 8
    mats = None
    if material.get("Metallic", 0.0) > 0 or material["Specular IOR Level"] > 0:
        count = len(sphere[0])
        mats = bake.VertexMaterials(np.full(count, material["Roughness"]), np.full(count, material["Metallic"]),
                                    np.full(count, 2.0 * material["Specular IOR Level"]))
    scene, spec, names = _cycles_sphere_scene(tmp_path, [sphere], order, 512, materials=mats)
    pixels = load_equirect(presets.preset_path("bridge")).pixels
    blender_scene.set_environment_world(scene, None, rotation_deg, 1.0, pixels=pixels)
    geo = passes.render_geometry(scene, spec, tmp_path, samples=4)
    images = []
    for seed in (0, 1):
        scene.cycles.seed = seed
        images.append(passes.render_path_traced(scene, tmp_path, f"pt{seed}", samples=256, denoise=False, bounces=4))
    L = sh_projection.project_equirect(pixels, order)
    t_pix = np.concatenate([geo.aovs[n] for n in names], axis=-1)[..., : sh.num_coeffs(order)]
    inside = geo.alpha > 0.999
    # Mean |I1 - I2| / 2 is the mean absolute noise of the two-render average.
    noise = np.abs(images[0].image - images[1].image)[inside].mean() / 2.0 / np.abs(images[0].image[inside]).mean()
    mean_image = 0.5 * (images[0].image + images[1].image)
    return geo, mean_image, L, t_pix, noise


def _relative_error(geo, image, L, t_pix, rotation_deg):
    predicted = geo.aovs["albedo"] * prt.shading(t_pix, sh_rotation.rotate(L, sh_rotation.z_rotation(rotation_deg)))
    inside = geo.alpha > 0.999
    return np.abs(image - predicted)[inside].mean() / np.abs(image[inside]).mean()


def _exact_lambert_irradiance(normals, pixels, rotation_deg):
    """E(n) = integral of L(R^T w) max(0, n.w) dw / pi by brute force over the map's texels.

    Rotating the light by R equals evaluating the unrotated map at R^T n.
    """
    height, width = pixels.shape[:2]
    dirs, omega = sh_projection.equirect_directions(height, width)
    dirs = dirs.reshape(-1, 3)
    weighted = (pixels * omega[:, None, None]).reshape(-1, 3) / math.pi
    turned = normals @ sh_rotation.z_rotation(rotation_deg)  # rows are R^T n
    out = np.empty((len(normals), 3))
    for start in range(0, len(normals), 128):
        cos = np.maximum(turned[start:start + 128] @ dirs.T, 0.0)
        out[start:start + 128] = cos @ weighted
    return out


def test_convex_diffuse_sphere_path_traced_equals_albedo_times_shading(tmp_path):
    """Convex Lambert sphere under a real HDR map: Cycles image == albedo * (T . L).

    On a convex object there is no self-occlusion and no interreflection, so
    the image differs from albedo * (T . L) only by three things, each
    measured here rather than guessed: Monte Carlo noise (two seeds), SH
    truncation at order 8 (exact irradiance by brute force over every texel
    vs the order-8 Lambert transport, on the vertices the camera sees), and
    the bake's quadrature (baked T vs analytic Lambert T). A 0.5 % allowance
    covers linear interpolation of T across triangles (edges ~0.05 rad,
    second-order error ~ h^2 / 8 of the curvature of a function whose
    highest band is l = 8: 8^2 * 0.05^2 / 8 = 2 %, of the tiny l = 8 part).
    The map is turned by 70 degrees; the opposite turn must fail by far,
    which pins the sign of the world rotation.
    """
    from relight.lighting import presets
    from relight.lighting.envmap import load_equirect

    albedo = np.array([0.8, 0.5, 0.3])
    material = dict(LAMBERT_WHITE, **{"Base Color": (*albedo, 1.0)})
    geo, image, L, t_pix, noise = _hdr_scene(tmp_path, material, 70.0)

    v, f, n = icosphere(4, radius=0.6)
    seen = n[:, 1] < -0.1  # facing the camera at -Y
    baked = bake.bake_transport(v, f, n, 8, 512, rng=np.random.default_rng(0)).transport[seen]
    analytic = prt.lambert_transport(n[seen], 8)
    light = sh_rotation.rotate(L, sh_rotation.z_rotation(70.0))
    pixels = load_equirect(presets.preset_path("bridge")).pixels
    exact = _exact_lambert_irradiance(n[seen], pixels, 70.0) * albedo
    scale = np.abs(exact).mean()
    truncation = np.abs(exact - albedo * prt.shading(analytic, light)).mean() / scale
    quadrature = np.abs(albedo * prt.shading(baked - analytic, light)).mean() / scale
    tolerance = 2.0 * noise + truncation + quadrature + 0.005
    error = _relative_error(geo, image, L, t_pix, 70.0)
    assert error < tolerance, (error, noise, truncation, quadrature)
    assert _relative_error(geo, image, L, t_pix, -70.0) > 4.0 * tolerance


def test_specular_sphere_departs_from_albedo_times_shading(tmp_path):
    """A shiny metal sphere reflects the map: albedo * (T . L) with low-order T cannot match.

    This gap is what the residual transport E learns.
    """
    material = {"Base Color": (0.9, 0.9, 0.9, 1.0), "Roughness": 0.15, "Metallic": 1.0, "Specular IOR Level": 0.5,
                "Diffuse Roughness": 0.0}
    geo, image, L, t_pix, noise = _hdr_scene(tmp_path, material, 70.0)
    # Far beyond what noise could explain (the diffuse case stays within 2 x noise + 1.5 %).
    assert _relative_error(geo, image, L, t_pix, 70.0) > 3.0 * (2.0 * noise + 0.015)


@pytest.mark.parametrize("prefilter", ["fast", "accurate"])
def test_path_traced_pass_uses_the_asked_denoise_prefilter(tmp_path, prefilter):
    """The farm option reaches Cycles: OIDN with that guide prefilter, a finite image."""
    from cycles_support import sh_world
    from farm.rendering import passes

    sphere = icosphere(2, radius=0.5) + (LAMBERT_WHITE,)
    scene, _, _ = _cycles_sphere_scene(tmp_path, [sphere], 1, 64, resolution=16)
    sh_world(scene, 0)
    pt = passes.render_path_traced(scene, tmp_path, "pt", samples=2, denoise=True, prefilter=prefilter)
    assert scene.cycles.use_denoising and scene.cycles.denoiser == "OPENIMAGEDENOISE"
    assert scene.cycles.denoising_prefilter == prefilter.upper()
    assert np.all(np.isfinite(pt.image)) and pt.image.max() > 0


def test_each_light_gets_a_fresh_world_with_an_importance_map_scaled_to_its_resolution(tmp_path):
    """Cycles reads the map settings only when it first syncs a World, so each light
    needs its own World; the old one is freed (no pile-up over a worker's scenes)."""
    from farm.rendering import blender_scene
    import bpy

    sphere = icosphere(1, radius=0.5) + (LAMBERT_WHITE,)
    scene, _, _ = _cycles_sphere_scene(tmp_path, [sphere], 1, 16, resolution=8)
    before = len(bpy.data.worlds)
    for width in (256, 64, 32):
        pixels = np.ones((width // 2, width, 3), np.float32)
        blender_scene.set_environment_world(scene, None, 0.0, 1.0, pixels=pixels, name=f"light{width}")
        world = scene.world
        assert world.name.startswith(f"light{width}")
        assert world.cycles.sampling_method == "MANUAL"
        assert world.cycles.sample_map_resolution == max(width * blender_scene.IMPORTANCE_MAP_OVERSAMPLING, 64)
    assert len(bpy.data.worlds) <= before + 1
    assert blender_scene.importance_map_resolution(20000) == 8192  # Cycles' upper bound for the setting
