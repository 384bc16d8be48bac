"""The person in the 3D scene: Compositing Setup's proxy of the photographed person.

Two objects of one relief mesh (logic.person_proxy), parented to the photo camera so that they stay
on the person wherever the artist moves it:

- `<photo>.person`, a Cycles shadow catcher seen only by the camera: its pixels stay transparent (the
  photo shows), a CG object behind the person is hidden by it, and a CG object's shadow on it reaches
  the render as alpha, which the compositor's Alpha Over turns into a darker person.
- `<photo>.person_shadow`, seen only by shadow rays: it casts the person's shadow on the floor catcher
  and on CG objects. It is a separate object because Cycles keeps a catcher's shadows off every
  catcher (the floor included), and it is the catcher scaled about the camera until it lies wholly
  behind it (person_proxy.caster_scale), so that it does not shadow the catcher with the person's own
  shadows, which the photo holds already.

Pressed again, Compositing Setup gives both objects a new mesh (no duplicates); a new Relight of the
photo does the same (refresh), and another photo's Compositing Setup hides this photo's proxy from the
render, as its camera is no longer the scene's.
"""

from __future__ import annotations

import bpy
import numpy as np

from ..logic import person_proxy, photo_light, pixel_buffers
from .bl_images import OUTPUT_LAYER, OUTPUT_OF, photo_by_id
from .bl_photo_world import tag, tagged

PERSON, PERSON_SHADOW = "person", "person_shadow"
FLOOR = "shadow_catcher"   # Compositing Setup's floor (blender_addon.blender.bl_compositing tags it so)
VISIBILITY = ("visible_camera", "visible_diffuse", "visible_glossy", "visible_transmission",
              "visible_volume_scatter", "visible_shadow")
SEEN_BY = {PERSON: {"visible_camera"}, PERSON_SHADOW: {"visible_shadow"}}


def relief_mesh(session, camera, floor=None) -> person_proxy.ReliefMesh:
    """The session's person as a relief mesh in `camera`'s upright frame (logic.person_proxy): the
    camera's lens and sensor at the photo's size as Blender shows it, standing on `floor` (None: a
    floor photo_light.CAMERA_HEIGHT below the camera)."""
    d = session.decomposition
    stored_h, stored_w = pixel_buffers.stored_size(session.photo.shape[:2], session.orientation)
    data = camera.data
    focal = person_proxy.focal_pixels(data.lens, data.sensor_width, data.sensor_height, data.sensor_fit,
                                      stored_w, stored_h)
    height = photo_light.CAMERA_HEIGHT
    if floor is not None:
        height = camera.matrix_world.translation.z - floor.matrix_world.translation.z
    return person_proxy.relief_mesh(d.shadows.depth, d.alpha, d.box, session.photo.shape[:2], focal, height)


def _mesh(name: str, vertices: np.ndarray, faces: np.ndarray):
    """A mesh of quads [m, 4] on `vertices` [n, 3], filled with foreach_set (no Python loop)."""
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(vertices))
    mesh.vertices.foreach_set("co", np.ascontiguousarray(vertices, np.float32).ravel())
    mesh.loops.add(faces.size)
    mesh.loops.foreach_set("vertex_index", np.ascontiguousarray(faces, np.int32).ravel())
    mesh.polygons.add(len(faces))
    mesh.polygons.foreach_set("loop_start", np.arange(0, faces.size, 4, dtype=np.int32))
    mesh.update(calc_edges=True)
    return mesh


def _set_mesh(obj, mesh) -> None:
    old = obj.data
    obj.data = mesh
    if old is not None and old.users == 0:
        bpy.data.meshes.remove(old)


def _object(scene, photo, session, what: str, mesh, camera):
    obj = tagged(bpy.data.objects, session.photo_id, what)
    if obj is None or obj.type != "MESH":
        obj = bpy.data.objects.new(mesh.name, mesh)
    else:
        _set_mesh(obj, mesh)
    tag(obj, bpy.data.objects, photo, what)
    if scene.objects.get(obj.name) is None:
        scene.collection.objects.link(obj)
    obj.parent = camera
    obj.matrix_parent_inverse.identity()
    obj.location, obj.rotation_euler, obj.scale = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)
    obj.is_shadow_catcher = what == PERSON
    obj.is_holdout = False
    for name in VISIBILITY:
        setattr(obj, name, name in SEEN_BY[what])
    obj.display_type = "WIRE"  # the photo behind the camera view stays visible in the viewport
    obj.hide_render = False
    return obj


def _vertices(session, relief, what: str) -> np.ndarray:
    vertices = relief.vertices if what == PERSON else person_proxy.caster_vertices(relief.vertices)
    made = photo_light.camera_setup(session.photo.shape[:2], None, session.orientation)
    return person_proxy.to_camera_local(vertices, made.rotation_euler)


def _meshes(photo, session, relief) -> dict:
    return {what: _mesh(photo_light.datablock_name(photo.name, what), _vertices(session, relief, what), relief.faces)
            for what in (PERSON, PERSON_SHADOW)}


def make_proxy(scene, photo, session, camera, floor=None):
    """Create or replace the photo's proxy (the catcher `<photo>.person` and the caster
    `<photo>.person_shadow`) in `camera`'s frame; other photos' proxies leave the render. Returns
    (catcher, caster, relief mesh)."""
    bpy.context.view_layer.update()  # a camera or floor made just now has no world matrix yet
    relief = relief_mesh(session, camera, floor)
    made = {what: _object(scene, photo, session, what, mesh, camera)
            for what, mesh in _meshes(photo, session, relief).items()}
    for obj in bpy.data.objects:  # another photo's person would cast and catch in this photo's render
        if obj.get(OUTPUT_LAYER) in SEEN_BY and obj.get(OUTPUT_OF) != session.photo_id:
            obj.hide_render = True
    return made[PERSON], made[PERSON_SHADOW], relief


def refresh(session) -> bool:
    """After a new Relight of the session's photo: its proxy, if it has one, takes the new
    decomposition's relief (the same objects, new meshes). Returns whether there was one."""
    photo = photo_by_id(session.photo_id)
    objects = {what: tagged(bpy.data.objects, session.photo_id, what) for what in SEEN_BY}
    camera = getattr(objects[PERSON], "parent", None)
    if photo is None or camera is None or camera.type != "CAMERA" or objects[PERSON_SHADOW] is None:
        return False
    relief = relief_mesh(session, camera, tagged(bpy.data.objects, session.photo_id, FLOOR))
    for what, mesh in _meshes(photo, session, relief).items():
        _set_mesh(objects[what], mesh)
    return True
