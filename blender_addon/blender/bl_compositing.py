"""Compositing Setup: CG objects rendered over the photo, lit like the person, shadows on a floor.

One click after Photo Light -> World (which it does too): a camera with the
photo's resolution and the photo as its background image (the viewport), a
shadow-catcher floor, transparent film and Cycles, and a compositor that puts
the render over the photo (Alpha Over), with the Standard view transform so
the photo comes out as it went in. Where things stand (camera, floor) is
photo_light's; it is set when they are made and left to the artist after.
Blender 5 composites with a node group (scene.compositing_node_group), Blender
4 with the scene's own tree: both are handled.
"""

from __future__ import annotations

import bpy

from . import bl_photo_world, bl_proxy
from ..logic import photo_light, pixel_buffers
from .bl_photo_world import RelitPhotoOperator, tag, tagged

CAMERA, COMPOSITE = "camera", "composite"
FLOOR = bl_proxy.FLOOR  # the shadow catcher: the proxy stands on it
NODE_PREFIX = "Relight Photo "  # our nodes in a Blender 4 compositor tree (the user's stay)


def _photo_file(photo) -> str | None:
    if photo.source == "FILE" and photo.packed_file is None and photo.filepath:
        return bpy.path.abspath(photo.filepath, library=photo.library)
    return None


def _in_scene(scene, obj) -> None:
    if scene.objects.get(obj.name) is None:
        scene.collection.objects.link(obj)


def make_camera(scene, photo, session):
    pid = session.photo_id
    obj = tagged(bpy.data.objects, pid, CAMERA)
    made = obj is None or obj.type != "CAMERA"
    if made:
        path = _photo_file(photo)
        # the photo as Blender shows it (stored), the camera rolled to see the upright world so
        setup = photo_light.camera_setup(pixel_buffers.stored_size(session.photo.shape[:2], session.orientation),
                                         photo_light.focal_35mm(path) if path else None, session.orientation)
        data = bpy.data.cameras.new(photo_light.datablock_name(photo.name, CAMERA))
        data.lens, data.sensor_width, data.sensor_fit = setup.lens_mm, setup.sensor_width_mm, "AUTO"
        obj = bpy.data.objects.new(data.name, data)
        obj.location, obj.rotation_euler = setup.location, setup.rotation_euler
    tag(obj, bpy.data.objects, photo, CAMERA)
    _in_scene(scene, obj)
    data = obj.data
    data.show_background_images = True  # the photo behind the viewport's camera view
    background = data.background_images[0] if len(data.background_images) else data.background_images.new()
    background.source = "IMAGE"
    background.image = photo
    background.display_depth = "BACK"
    background.frame_method = "FIT"  # the render has the photo's aspect: FIT and CROP agree
    background.alpha = 1.0
    scene.camera = obj
    height, width = pixel_buffers.stored_size(session.photo.shape[:2], session.orientation)
    render = scene.render
    render.resolution_x, render.resolution_y = width, height
    if made:  # the artist's Resolution % (a quick render at 50 %) is kept when pressed again
        render.resolution_percentage = 100
    render.pixel_aspect_x = render.pixel_aspect_y = 1.0
    return obj


def make_floor(scene, photo, session):
    obj = tagged(bpy.data.objects, session.photo_id, FLOOR)
    if obj is None or obj.type != "MESH":
        mesh = bpy.data.meshes.new(photo_light.datablock_name(photo.name, FLOOR))
        mesh.from_pydata(photo_light.floor_corners(), [], [(0, 1, 2, 3)])
        mesh.update()
        obj = bpy.data.objects.new(mesh.name, mesh)
    tag(obj, bpy.data.objects, photo, FLOOR)
    _in_scene(scene, obj)
    obj.is_shadow_catcher = True  # Cycles: only the shadows it receives reach the render (as alpha)
    return obj


def _alpha_over_inputs(node):
    """(background, foreground) sockets: named in Blender 5, the two 'Image' inputs in Blender 4."""
    names = {s.name: s for s in node.inputs}
    if "Background" in names and "Foreground" in names:
        return names["Background"], names["Foreground"]
    return node.inputs[1], node.inputs[2]


def _to_render_size(node) -> None:
    """A Scale node that fits its image to the render's size, the Resolution % included (Blender 4:
    properties; Blender 5: menu inputs)."""
    if hasattr(node, "space"):
        node.space, node.frame_method = "RENDER_SIZE", "FIT"
    else:
        node.inputs["Type"].default_value = "Render Size"
        node.inputs["Frame Type"].default_value = "Fit"


def _composite_nodes(tree, scene, photo):
    """Photo (background, scaled to the render's size) and render (foreground) into an Alpha Over;
    returns the Alpha Over node."""
    nodes, links = tree.nodes, tree.links
    image = nodes.new("CompositorNodeImage")
    image.name = NODE_PREFIX + "Photo"
    image.image = photo
    image.location = (-500.0, 200.0)
    # the compositor centres an image at its own size: at a Resolution % under 100 the render is
    # smaller, and the photo behind it must shrink with it (it showed its middle only)
    scale = nodes.new("CompositorNodeScale")
    scale.name = NODE_PREFIX + "Photo to Render Size"
    _to_render_size(scale)
    scale.location = (-300.0, 200.0)
    links.new(image.outputs["Image"], scale.inputs["Image"])
    layers = nodes.new("CompositorNodeRLayers")
    layers.name = NODE_PREFIX + "Render"
    if hasattr(layers, "scene"):
        layers.scene = scene
    layers.location = (-300.0, -100.0)
    over = nodes.new("CompositorNodeAlphaOver")  # premultiplied foreground: what Cycles renders
    over.name = NODE_PREFIX + "Over"
    background, foreground = _alpha_over_inputs(over)
    links.new(scale.outputs["Image"], background)
    links.new(layers.outputs["Image"], foreground)
    return over


def make_compositor(scene, photo, session):
    """The render over the photo, in the compositor; returns the tree that does it."""
    if hasattr(scene, "compositing_node_group"):  # Blender 5
        group = tagged(bpy.data.node_groups, session.photo_id, COMPOSITE)
        if group is None:
            group = bpy.data.node_groups.new(photo_light.datablock_name(photo.name, COMPOSITE), "CompositorNodeTree")
        tag(group, bpy.data.node_groups, photo, COMPOSITE)
        group.nodes.clear()
        group.interface.clear()
        group.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
        over = _composite_nodes(group, scene, photo)
        output = group.nodes.new("NodeGroupOutput")
        output.location = (300.0, 0.0)
        group.links.new(over.outputs["Image"], output.inputs[0])
        scene.compositing_node_group = group
        return group
    scene.use_nodes = True  # Blender 4: the scene's own tree; the user's nodes are kept
    tree = scene.node_tree
    for node in [n for n in tree.nodes if n.name.startswith(NODE_PREFIX)]:
        tree.nodes.remove(node)
    over = _composite_nodes(tree, scene, photo)
    composite = next((n for n in tree.nodes if n.type == "COMPOSITE"), None)
    if composite is None:
        composite = tree.nodes.new("CompositorNodeComposite")
        composite.name = NODE_PREFIX + "Composite"
    composite.location = (300.0, 0.0)
    tree.links.new(over.outputs["Image"], composite.inputs["Image"])
    return tree


def make_render_settings(scene) -> None:
    render = scene.render
    render.engine = "CYCLES"           # the shadow catcher is Cycles'
    render.film_transparent = True     # the photo shows where nothing was rendered
    render.use_compositing = True
    view = scene.view_settings
    view.view_transform = "Standard"   # the photo (sRGB) comes out as it went in
    view.look = "None"
    view.exposure, view.gamma = 0.0, 1.0


class RELIGHT_PHOTO_OT_compositing_setup(bpy.types.Operator, RelitPhotoOperator):
    """Set up a render over the photo: its light as the World, a camera of its size with the photo behind it,
    a shadow-catcher floor and a compositor that puts the render over the photo (Cycles, transparent film)"""

    bl_idname = "relight_photo.compositing_setup"
    bl_label = "Compositing Setup"
    bl_options = {"REGISTER", "UNDO"}

    def step(self, context, photo, session) -> str:
        scene = context.scene
        bl_photo_world.make_world(scene, photo, session)
        camera = make_camera(scene, photo, session)
        floor = make_floor(scene, photo, session)
        person, _, _ = bl_proxy.make_proxy(scene, photo, session, camera, floor)  # the person casts and catches
        make_compositor(scene, photo, session)
        make_render_settings(scene)
        return (f"Render '{camera.name}' to put CG objects over '{photo.name}', lit like the person, "
                f"shadows on '{floor.name}' and '{person.name}'")


CLASSES = (RELIGHT_PHOTO_OT_compositing_setup,)


register, unregister = bpy.utils.register_classes_factory(CLASSES)
