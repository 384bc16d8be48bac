"""The person in the 3D scene (issue 46): Compositing Setup's relief proxy under headless bpy.

The proxy (blender_addon.blender.bl_proxy) is two objects of one relief mesh parented to the photo
camera: `<photo>.person`, a shadow catcher seen only by the camera, and `<photo>.person_shadow`, seen
only by shadow rays. Checked here as a user's clicks make them: every vertex projects, through the
camera Blender renders with, onto a corner of a working pixel the matte covers; the person stands on
the floor; pressing again replaces them and a new Relight updates them; and Cycles renders (48 x 72,
8 samples) show the person's shadow on the CG floor beside them under a sun from the front-left, and
a CG cube between that sun and the person darkening the person in the composite.
"""

from __future__ import annotations

import types
import warnings

import numpy as np
import pytest

import bpy
import mathutils

from blender_addon.blender import bl_images
from blender_addon.logic import person_proxy
from relight.files import exr
from relight.lighting.light import directional_light
from addon_support import H, W, cube, draft_photo, photo_session, write_person_png

SAMPLES = 8
SUN = dict(azimuth_deg=-45.0, elevation_deg=30.0)  # from the camera's left, in front of the person


def _proxies(name: str) -> dict:
    pid = photo_session(name).photo_id
    found = {}
    for obj in bpy.data.objects:
        if obj.get(bl_images.OUTPUT_OF) == pid and obj.get(bl_images.OUTPUT_LAYER) in ("person", "person_shadow"):
            assert obj.get(bl_images.OUTPUT_LAYER) not in found, "a duplicate proxy"
            found[obj.get(bl_images.OUTPUT_LAYER)] = obj
    return found


def _setup(name: str, light=None) -> dict:
    if light is not None:
        photo_session(name).decomposition.light = light  # as if the network had estimated it
    assert bpy.ops.relight_photo.compositing_setup(image_name=name) == {"FINISHED"}
    return _proxies(name)


def _photo_pixels(obj) -> np.ndarray:
    """Where each vertex of `obj` lands in the rendered image, in photo pixels (x right, y down)."""
    from bpy_extras.object_utils import world_to_camera_view

    scene = bpy.context.scene
    bpy.context.view_layer.update()
    matrix = obj.matrix_world
    out = np.array([tuple(world_to_camera_view(scene, scene.camera, matrix @ v.co))
                    for v in obj.data.vertices])
    return np.stack([out[:, 0] * W, (1.0 - out[:, 1]) * H, out[:, 2]], -1)


def _on_corners(points: np.ndarray, decomposition, tol: float) -> bool:
    """Whether the points [n, 2] (photo pixels x, y) are the corners of the working pixels the
    matte covers at least half of, each once (to `tol` photo pixels)."""
    h, w = decomposition.working_size
    y0, y1, x0, x1 = decomposition.box
    inside = decomposition.alpha >= person_proxy.COVERAGE
    used = np.zeros((h + 1, w + 1), bool)
    for dr in (0, 1):
        for dc in (0, 1):
            used[dr:dr + h, dc:dc + w] |= inside
    sx, sy = (x1 - x0) / w, (y1 - y0) / h
    col, row = (points[:, 0] - x0) / sx, (points[:, 1] - y0) / sy
    ci, ri = np.round(col).astype(np.int64), np.round(row).astype(np.int64)
    if np.abs(col - ci).max() * sx > tol or np.abs(row - ri).max() * sy > tol:
        return False
    found = np.zeros_like(used)
    found[ri, ci] = True
    return len(points) == int(used.sum()) and bool(np.array_equal(found, used))


def _relit_person(model, folder) -> str:
    """The person photo relit with its ellipse as the mask (Other Image, a grey PNG): the person's
    matte ends inside the photo (the random-weight network's own matte covers it all)."""
    from PIL import Image

    write_person_png(folder / "mask.png", with_alpha=True)
    alpha = np.asarray(Image.open(folder / "mask.png"))[..., 3]
    Image.fromarray(alpha, "L").save(folder / "mask.png")
    name = draft_photo(model, folder)
    s = bpy.context.scene.relight_photo
    s.mask_mode, s.mask_image = "IMAGE", bpy.data.images.load(str(folder / "mask.png"))
    assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
    return name


def test_the_proxy_lies_on_the_persons_pixels_and_stands_on_the_floor(addon, model):
    name = _relit_person(model, addon)
    objects = _setup(name)
    assert set(objects) == {"person", "person_shadow"}
    person, caster = objects["person"], objects["person_shadow"]
    camera = bpy.context.scene.camera
    assert person.parent == camera and caster.parent == camera
    # the catcher: only the camera sees it; the caster: only shadow rays
    assert person.is_shadow_catcher and person.visible_camera and not person.visible_shadow
    assert not caster.is_shadow_catcher and not caster.visible_camera and caster.visible_shadow
    assert not (person.visible_diffuse or person.visible_glossy or caster.visible_diffuse or caster.visible_glossy)
    d = photo_session(name).decomposition
    for obj in (person, caster):
        at = _photo_pixels(obj)
        # float32 vertices a few metres away: ~1e-6 relative, a thousandth of a pixel here
        assert _on_corners(at[:, :2], d, 2e-3), obj.name
        assert np.all(at[:, 2] > 0)  # in front of the camera
    inside = d.alpha >= person_proxy.COVERAGE
    assert len(person.data.polygons) == int(inside.sum()) == len(caster.data.polygons)
    # the caster is the catcher scaled about the camera (the same rays), wholly behind it along the view
    dist = np.array([(person.matrix_world @ v.co - camera.matrix_world.translation).length for v in person.data.vertices])
    dist_c = np.array([(caster.matrix_world @ v.co - camera.matrix_world.translation).length
                       for v in caster.data.vertices])
    ratio = dist_c / dist
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-5)
    view = camera.matrix_world.to_3x3() @ mathutils.Vector((0.0, 0.0, -1.0))
    near, far = ([(obj.matrix_world @ v.co - camera.matrix_world.translation).dot(view) for v in obj.data.vertices]
                 for obj in (person, caster))
    near, far = np.array(near), np.array(far)
    assert far.min() > near.max() or ratio[0] == pytest.approx(person_proxy.MAX_CASTER_SCALE, rel=1e-5)
    # the matte ends above the photo's bottom edge: the person's lowest point is on the floor (z = 0)
    lowest = min((person.matrix_world @ v.co).z for v in person.data.vertices)
    assert abs(lowest) < 1e-4, lowest
    # the catcher's faces look at the camera (counter-clockwise from it): their normals point back to it
    normals = np.array([tuple(person.matrix_world.to_3x3() @ p.normal) for p in person.data.polygons])
    centres = np.array([tuple(person.matrix_world @ p.center) for p in person.data.polygons])
    to_camera = np.array(camera.matrix_world.translation)[None] - centres
    assert np.mean(np.sum(normals * to_camera, -1) > 0) > 0.9


def test_pressing_again_replaces_the_proxy_and_a_new_relight_updates_it(addon, model):
    name = _relit_person(model, addon)
    first = _setup(name)
    meshes = len(bpy.data.meshes)
    again = _setup(name)
    assert {k: v.name for k, v in again.items()} == {k: v.name for k, v in first.items()}
    assert len(bpy.data.meshes) == meshes  # the old meshes were removed, not orphaned
    before = np.array([tuple(v.co) for v in again["person"].data.vertices])
    # the photo relit with another mask: a new decomposition, a new matte; the proxy follows at once
    bpy.context.scene.relight_photo.mask_mode = "NETWORK"
    assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
    after = _proxies(name)
    assert {k: v.name for k, v in after.items()} == {k: v.name for k, v in first.items()}
    assert len(bpy.data.meshes) == meshes
    assert _on_corners(_photo_pixels(after["person"])[:, :2], photo_session(name).decomposition, 2e-3)
    now = np.array([tuple(v.co) for v in after["person"].data.vertices])
    assert now.shape != before.shape or not np.allclose(now, before)


def test_another_photos_setup_takes_this_photos_proxy_out_of_the_render(addon, model):
    import shutil

    first = _relit_person(model, addon)
    shutil.copy(addon / "person.png", addon / "other.png")
    other = bpy.data.images.load(str(addon / "other.png")).name
    assert bpy.ops.relight_photo.relight(image_name=other, synchronous=True) == {"FINISHED"}
    mine, theirs = _setup(first), _setup(other)
    assert all(o.hide_render for o in mine.values()) and not any(o.hide_render for o in theirs.values())
    assert all(o.parent == bpy.data.objects[f"{other}.camera"] for o in theirs.values())
    mine = _setup(first)  # back to the first photo: its person renders, the other's does not
    assert not any(o.hide_render for o in mine.values()) and all(o.hide_render for o in theirs.values())


# ------------------------------------------------------------------ rendered

def _render(folder, tag: str) -> np.ndarray:
    scene = bpy.context.scene
    scene.cycles.samples = SAMPLES
    scene.cycles.use_denoising = False
    scene.cycles.device = "CPU"
    scene.cycles.seed = 0
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.filepath = str(folder / f"{tag}.exr")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        bpy.ops.render.render(write_still=True)
    planes = exr.read_exr(folder / f"{tag}.exr")
    return np.stack([planes[c] for c in "RGB"], -1)




def _ellipsoid_relief(alpha: np.ndarray) -> np.ndarray:
    """The relief of a half ellipsoid over the matte [h, w] (working pixels, nearer in the middle),
    half as deep as it is wide, its mean 0: what a person's relief looks like, where the
    random-weight model's normals give one metres deep."""
    inside = alpha >= person_proxy.COVERAGE
    rows, cols = np.nonzero(inside)
    rc, cc = (rows.min() + rows.max() + 1) / 2, (cols.min() + cols.max() + 1) / 2
    b, a = (rows.max() + 1 - rows.min()) / 2, (cols.max() + 1 - cols.min()) / 2
    r, c = np.mgrid[0:alpha.shape[0], 0:alpha.shape[1]] + 0.5
    depth = -0.5 * a * np.sqrt(np.clip(1.0 - ((c - cc) / a) ** 2 - ((r - rc) / b) ** 2, 0.0, None))
    depth -= depth[inside].mean()
    return np.where(inside, depth, 0.0).astype(np.float32)


def _under_a_sun(model, folder):
    """The person relit, given a body's relief, and Compositing Setup under a sun from the
    front-left (the key lamp of that light); (proxy objects, the unit vector toward the sun)."""
    name = _relit_person(model, folder)
    d = photo_session(name).decomposition
    d.shadows = types.SimpleNamespace(depth=_ellipsoid_relief(d.alpha))  # as if the relief were estimated
    objects = _setup(name, directional_light(SUN["azimuth_deg"], 4, elevation_deg=SUN["elevation_deg"], ambient=0.1))
    key = next(o for o in bpy.context.scene.objects if o.type == "LIGHT")
    assert key.data.type == "SUN"
    return objects, key.matrix_world.to_3x3() @ mathutils.Vector((0.0, 0.0, 1.0))


def _pixel(point) -> tuple[int, int]:
    """(row, column) of the rendered pixel a world point lands in."""
    from bpy_extras.object_utils import world_to_camera_view

    scene = bpy.context.scene
    at = world_to_camera_view(scene, scene.camera, point)
    return int(np.floor((1.0 - at.y) * H)), int(np.floor(at.x * W))


def _ratio(image, photo) -> np.ndarray:
    return image.sum(-1) / photo.sum(-1)


def test_the_person_casts_a_shadow_on_the_floor_beside_them(addon, model):
    """The floor where the proxy's shadow falls (each vertex cast along the sun onto z = 0), off the
    person and a pixel inside that footprint, is darker with the proxy than without; the rest of the
    floor is not."""
    objects, toward_sun = _under_a_sun(model, addon)
    caster = objects["person_shadow"]
    footprint = np.zeros((H, W), bool)
    for v in caster.data.vertices:
        p = caster.matrix_world @ v.co
        r, c = _pixel(p - (p.z / toward_sun.z) * toward_sun)
        if 0 <= r < H and 0 <= c < W:
            footprint[r, c] = True
    person = np.zeros((H, W), bool)
    for v in objects["person"].data.vertices:
        r, c = _pixel(objects["person"].matrix_world @ v.co)
        person[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2] = True   # the person's pixels and a 1-pixel margin
    inner = footprint.copy()
    inner[1:-1, 1:-1] &= footprint[:-2, 1:-1] & footprint[2:, 1:-1] & footprint[1:-1, :-2] & footprint[1:-1, 2:]
    shadow = inner & ~person
    grown = footprint.copy()
    for dr, dc in ((-2, 0), (2, 0), (0, -2), (0, 2), (-1, -1), (1, 1), (-1, 1), (1, -1)):
        grown |= np.roll(footprint, (dr, dc), (0, 1))
    rows = np.mgrid[0:H, 0:W][0] + 0.5
    open_floor = ~grown & ~person & (rows > H / 2 + 2)
    assert shadow.sum() >= 8 and open_floor.sum() > 200
    name = objects["person"].parent.name[:-len(".camera")]
    photo = photo_session(name).photo
    with_proxy = _ratio(_render(addon, "with"), photo)
    for obj in objects.values():
        obj.hide_render = True
    without = _ratio(_render(addon, "without"), photo)
    print(f"the floor in the person's shadow ({shadow.sum()} px): composite / photo {with_proxy[shadow].mean():.3f} "
          f"with the proxy, {without[shadow].mean():.3f} without; the open floor ({open_floor.sum()} px) "
          f"{with_proxy[open_floor].mean():.3f} / {without[open_floor].mean():.3f}")
    # the sun is 0.9 of the light (ambient 0.1): in its shadow the floor keeps well under half
    assert with_proxy[shadow].mean() < 0.5 and without[shadow].mean() > 0.95
    assert abs(with_proxy[open_floor].mean() - without[open_floor].mean()) < 0.02


def test_a_cg_object_between_the_sun_and_the_person_darkens_the_person(addon, model):
    """A 0.6 m cube 2.5 m from the person's middle toward the sun (out of the frame): the person's
    pixels around the middle darken in the composite with the proxy, not without it, and not with
    the proxy alone."""
    objects, toward_sun = _under_a_sun(model, addon)
    person = objects["person"]
    name = person.parent.name[:-len(".camera")]
    photo = photo_session(name).photo
    alone = _ratio(_render(addon, "with"), photo)
    points = np.array([tuple(person.matrix_world @ v.co) for v in person.data.vertices])
    middle = mathutils.Vector(points.mean(axis=0))
    blocker = cube(middle + 2.5 * toward_sun, 0.6)
    r, c = _pixel(blocker.location)
    assert not (0 <= r < H and 0 <= c < W)  # the cube itself is out of the frame
    cube_with = _ratio(_render(addon, "cube_with"), photo)
    for obj in objects.values():
        obj.hide_render = True
    cube_without = _ratio(_render(addon, "cube_without"), photo)
    r, c = _pixel(middle)
    rows, cols = np.mgrid[0:H, 0:W]
    # the cube's shadow on the person is 0.6 m wide, about 11 pixels here: 7 x 7 around the middle
    near = (np.abs(rows - r) <= 3) & (np.abs(cols - c) <= 3)
    print(f"the person's middle ({near.sum()} px): composite / photo {cube_with[near].mean():.3f} with the proxy "
          f"and the cube, {cube_without[near].mean():.3f} without the proxy, {alone[near].mean():.3f} without the cube")
    assert cube_with[near].mean() < 0.5
    assert cube_without[near].mean() > 0.97 and alone[near].mean() > 0.95


# ------------------------------------------------------------------ Save Layers' Shadow layer

def test_save_layers_writes_the_persons_shadow_layer(addon, model):
    """The EXR's Relight.Shadow.X is Decomposition.shadow_layer under the dials' light (1 = lit),
    1 outside the person's crop, darker somewhere on the person under a sun from the side, and
    Blender's compositor lists it as a pass of the file."""
    from blender_addon.blender import bl_ops
    from blender_addon.worker import engine

    from relight.files.exr import write_exr
    from relight.lighting.light_map import light_map

    name = _relit_person(model, addon)
    # an HDR file of a sun from camera-left, 20 degrees up, a tenth ambient: a light with a key
    sun = light_map(directional_light(-90.0, 4, elevation_deg=20.0, ambient=0.1), 128).pixels
    write_exr(addon / "sun.exr", {c: sun[..., i] for i, c in enumerate("RGB")})
    s = bpy.context.scene.relight_photo
    s.light_kind, s.hdr_path = "HDR", str(addon / "sun.exr")
    session = photo_session(name)
    target = addon / "layers.exr"
    assert bpy.ops.relight_photo.save_layers(filepath=str(target), image_name=name) == {"FINISHED"}
    channels = exr.read_exr(target)
    shadow = np.asarray(channels["Relight.Shadow.X"])
    d = session.decomposition
    light, rotation, exposure, _ = bl_ops.current_dials(bpy.context, session)
    want = d.shadow_layer(engine.coefficients(d, light, rotation), exposure)
    np.testing.assert_array_equal(shadow, want)
    assert shadow.shape == (H, W) and shadow.min() >= 0.0 and shadow.max() <= 1.0
    y0, y1, x0, x1 = d.box
    outside = np.ones((H, W), bool)
    outside[y0:y1, x0:x1] = False
    assert outside.sum() > 100 and np.all(shadow[outside] == 1.0)  # off the person's crop: lit
    print(f"shadow layer: {np.mean(shadow < 0.99):.3f} of the pixels below 0.99, darkest {shadow.min():.3f}")
    assert shadow.min() < 0.9  # the relief shadows part of the person from the sun
    image = bpy.data.images.load(str(target))
    if hasattr(bpy.context.scene, "compositing_node_group"):  # Blender 5
        tree = bpy.data.node_groups.new("layers", "CompositorNodeTree")
    else:
        bpy.context.scene.use_nodes = True
        tree = bpy.context.scene.node_tree
    node = tree.nodes.new("CompositorNodeImage")
    node.image = image
    assert image.type == "MULTILAYER" and "Shadow" in [o.name for o in node.outputs if o.enabled]
