"""Scene settings (saved with the .blend) and window-manager status (not saved)."""

import bpy
from bpy.props import (BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty,
                       StringProperty)

from . import bl_dials
from ..logic import light_sources, photo_checks, quality

_preset_items_cache: list = []  # bpy needs the enum items kept alive by Python


def _preset_items(_self, _context):
    if not _preset_items_cache:
        try:
            names = light_sources.preset_names()
        except Exception:  # a broken data folder must not break the panel
            names = []
        _preset_items_cache.extend(
            (n, n.replace("blender:", "Blender: ").replace("_", " ").title(), f"Light preset {n}")
            for n in names)
        if not _preset_items_cache:
            _preset_items_cache.append(("NONE", "No presets", "No light preset is installed"))
    return _preset_items_cache


_person_items_cache: list = []


def _person_items(self, _context):
    # Everyone (the default), then as many people as the last Relight found (at least one)
    count = max(1, int(getattr(self, "people_found", 1)))
    if len(_person_items_cache) != count + 1:
        _person_items_cache[:] = [
            ("0", "Everyone", "Everyone in the photo, relit together under the photo's one light"),
            ("1", "Largest person", "The largest person in the photo alone")] + [
            (str(i), f"Person {i}", f"The {i}th largest person in the photo alone") for i in range(2, count + 1)]
    return _person_items_cache


def _light_changed(_self, context):
    bl_dials.schedule_refresh(context)


class RelightPhotoSettings(bpy.types.PropertyGroup):
    mask_mode: EnumProperty(
        name="Mask",
        items=[("AUTO", "Automatic", "Find the people in the photo and use the chosen person's matte"),
               ("NETWORK", "Network Matte",
                "Use the matte the relighting network predicts (for images that are not photos)"),
               ("IMAGE_ALPHA", "Image Alpha", "Use the photo's own alpha channel"),
               ("IMAGE", "Other Image", "Use another image of the same size (its alpha, else its grey level)")],
        default="AUTO")
    mask_image: PointerProperty(name="Mask Image", type=bpy.types.Image)
    person: EnumProperty(name="Person", items=_person_items,
                         description="Which person to relight (press Relight after choosing)")
    people_found: IntProperty(name="People Found", default=0, min=0,
                              description="How many people the last Relight found in the photo")
    people_relit: IntProperty(name="People Relit", default=0, min=0,
                              description="How many people the last Relight relit (Everyone: all found but "
                                          "those too small)")
    light_kind: EnumProperty(
        name="Light",
        items=[("WORLD", "World", "The scene's World (environment texture or baked procedural sky)"),
               ("HDR", "HDR File", "An equirectangular .exr or .hdr file"),
               ("PRESET", "Preset", "A bundled HDR light"),
               ("IMAGE", "Other Photo", "The light estimated from another photo (light transfer)")],
        default="PRESET", update=_light_changed)
    hdr_path: StringProperty(name="HDR File", subtype="FILE_PATH", update=_light_changed)
    preset: EnumProperty(name="Preset", items=_preset_items, update=_light_changed)
    light_image: PointerProperty(name="Light From", type=bpy.types.Image, update=_light_changed)
    rotation: FloatProperty(
        name="Rotation", description="Turn the light about the vertical axis",
        subtype="ANGLE", unit="ROTATION", default=0.0, soft_min=-3.14159265, soft_max=3.14159265,
        update=_light_changed)
    exposure: FloatProperty(name="Exposure", description="Light intensity in stops (EV)",
                            default=0.0, soft_min=-5.0, soft_max=5.0, update=_light_changed)
    strength: FloatProperty(name="Strength", description="Blend between the photo (0) and the relit photo (1)",
                            subtype="FACTOR", default=1.0, min=0.0, max=1.0, update=_light_changed)
    quality: EnumProperty(name="Quality", items=quality.enum_items(), default=quality.DEFAULT_QUALITY)
    model_path: StringProperty(name="Model", subtype="FILE_PATH",
                               description="Custom ONNX model; empty uses the quality preset's shipped model")
    max_megapixels: IntProperty(
        name="Max Photo Size", default=photo_checks.DEFAULT_MEGAPIXELS, min=1,
        max=photo_checks.MOST_MEGAPIXELS,
        description="The largest photo Relight reads, in megapixels; a larger one is refused before it is "
                    "decoded (about 0.16 GB of memory per megapixel)")
    overwrite_frames: BoolProperty(
        name="Overwrite Frames",
        description="Relight Sequence may replace the frames an earlier run left in its output folder")
    last_photo_id: StringProperty(name="Last Photo", description="Id of the photo the dials currently relight")


class RelightPhotoStatus(bpy.types.PropertyGroup):
    running: BoolProperty(default=False)
    stage: StringProperty(default="")            # what the running job does now, in the artist's words
    progress: FloatProperty(default=0.0, min=0.0, max=1.0, subtype="FACTOR")
    elapsed: FloatProperty(default=0.0)          # seconds since Relight was pressed
    message: StringProperty(default="")
    is_error: BoolProperty(default=False)


CLASSES = (RelightPhotoSettings, RelightPhotoStatus)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.relight_photo = PointerProperty(type=RelightPhotoSettings)
    bpy.types.WindowManager.relight_photo_status = PointerProperty(type=RelightPhotoStatus)


def unregister() -> None:
    del bpy.types.WindowManager.relight_photo_status
    del bpy.types.Scene.relight_photo
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
    _preset_items_cache.clear()
    _person_items_cache.clear()
