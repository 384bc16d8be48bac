"""The Image Editor sidebar panel (tab "Relight")."""

from __future__ import annotations

import bpy

from . import bl_session
from ..worker import state


class RELIGHT_PHOTO_PT_panel(bpy.types.Panel):
    bl_label = "Relight Photo"
    bl_idname = "RELIGHT_PHOTO_PT_panel"
    bl_space_type = "IMAGE_EDITOR"
    bl_region_type = "UI"
    bl_category = "Relight"

    def draw(self, context):
        layout = self.layout
        settings = context.scene.relight_photo
        status = context.window_manager.relight_photo_status
        image = context.space_data.image

        col = layout.column()
        col.label(text=f"Photo: {image.name}" if image else "Open a photo in this editor",
                  icon="IMAGE_DATA" if image else "INFO")

        box = layout.box()
        box.prop(settings, "mask_mode")
        if settings.mask_mode == "AUTO":
            box.prop(settings, "person")
            if settings.people_found:
                found = settings.people_found
                relit = f", {settings.people_relit} relit" if settings.people_relit and found > 1 else ""
                box.label(text=f"{found} {'person' if found == 1 else 'people'} found{relit}; "
                               "'.matte' shows the cut-out", icon="USER")
        if settings.mask_mode == "IMAGE":
            box.template_ID(settings, "mask_image", open="image.open")

        box = layout.box()
        box.prop(settings, "light_kind")
        if settings.light_kind == "HDR":
            box.prop(settings, "hdr_path", text="")
        elif settings.light_kind == "PRESET":
            box.prop(settings, "preset", text="")
        elif settings.light_kind == "IMAGE":
            box.template_ID(settings, "light_image", open="image.open")
        elif settings.light_kind == "WORLD":
            world = context.scene.world
            box.label(text=f"World: {world.name}" if world else "The scene has no World",
                      icon="WORLD" if world else "ERROR")
        col = box.column(align=True)
        col.prop(settings, "rotation")
        col.prop(settings, "exposure")
        col.prop(settings, "strength", slider=True)

        box = layout.box()
        box.prop(settings, "quality")
        box.prop(settings, "model_path")
        box.prop(settings, "max_megapixels")

        row = layout.row(align=True)
        row.scale_y = 1.4
        row.enabled = not status.running
        row.operator("relight_photo.relight", icon="LIGHT_SUN")
        if image is not None and image.source in {"SEQUENCE", "MOVIE"}:  # frame by frame (bl_sequence)
            row = layout.row()
            row.enabled = not status.running
            row.operator("relight_photo.relight_sequence", icon="RENDER_ANIMATION")
            row.prop(settings, "overwrite_frames", text="Overwrite")
        row = layout.row()
        row.enabled = settings.last_photo_id in state.SESSIONS
        row.operator("relight_photo.save_layers", icon="FILE_IMAGE")
        # enabled without a relit photo: pressing then says why it cannot (bl_photo_world)
        row = layout.row(align=True)
        row.operator("relight_photo.light_to_world", icon="WORLD")
        row.operator("relight_photo.compositing_setup", icon="NODE_COMPOSITING")

        # what reopening could not bring back of this photo: shown as long as it holds
        notice = bl_session.notice_for(image)
        if notice:
            _wrapped_label(layout.box(), context, notice, "ERROR")
        if status.running:
            layout.label(text=f"{status.stage}: {100 * status.progress:.0f}% ({status.elapsed:.1f} s)",
                         icon="SORTTIME")
            layout.label(text="Esc cancels")
        elif status.message and status.message != notice:
            _wrapped_label(layout, context, status.message, "ERROR" if status.is_error else "CHECKMARK")


def _wrapped_label(layout, context, text: str, icon: str) -> None:
    """`text` as lines that fit the sidebar (a label does not wrap: a long sentence was cut off)."""
    import textwrap

    region = getattr(context, "region", None)
    prefs = getattr(context, "preferences", None)
    scale = prefs.system.ui_scale if prefs is not None else 1.0
    width = region.width if region is not None else 300
    chars = max(24, int(width / (7.0 * scale)))  # ~7 px a character at UI scale 1
    column = layout.column(align=True)
    for k, line in enumerate(textwrap.wrap(text, chars, break_on_hyphens=False)):
        column.label(text=line, icon=icon if k == 0 else "BLANK1")


CLASSES = (RELIGHT_PHOTO_PT_panel,)


register, unregister = bpy.utils.register_classes_factory(CLASSES)
