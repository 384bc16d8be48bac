"""A moved lamp against a turned rotation dial: seconds from the change to the relit image, add-on headless.

    .venv/bin/python benchmarks/bench_lamps_dial.py [--megapixels 2] [--moves 5]

The bundled astronaut photo, resized (Pillow, Lanczos) to --megapixels, is relit once
with the shipped model (Draft, the network's matte) under the World light (a flat
Environment Texture World) with one point lamp in the scene. Then, alternately, the
lamp is moved (its new place delivered as the depsgraph update Blender sends, through
the add-on's handler) and the rotation dial is turned, --moves times each; each is timed
from the change to the relit image written. Headless, both relight the full size at
once (with a UI both take the same timer and preview path, docs/addon.md). Also timed:
projecting the scene's lamps to SH alone. Prints the load average: on a shared machine
compare rows of one run.
"""

from __future__ import annotations

import math
import os
import statistics
import time
import types

import numpy as np
from photos import megapixels_parser, photo_in_temporary_folder  # benchmarks/photos.py


def main(argv=None) -> int:
    parser = megapixels_parser(__doc__, 2.0)
    parser.add_argument("--moves", type=int, default=5)
    args = parser.parse_args(argv)

    import bpy

    import blender_addon
    from blender_addon.blender import bl_dials, bl_world
    from relight.files.exr import write_exr
    from relight.lighting.lamps import lamps_coeffs

    with photo_in_temporary_folder("bench_lamps_dial_", args.megapixels) as (folder, path, size):
        flat = folder / "flat.exr"
        write_exr(flat, {c: np.full((32, 64), 0.3, np.float32) for c in "RGB"})
        blender_addon.register()
        try:
            bpy.ops.wm.read_homefile(use_empty=True)
            scene = bpy.context.scene
            world = bpy.data.worlds.new("flat")
            if bpy.app.version < (5, 0, 0):
                world.use_nodes = True
            texture = world.node_tree.nodes.new("ShaderNodeTexEnvironment")
            texture.image = bpy.data.images.load(str(flat))
            world.node_tree.links.new(texture.outputs["Color"], world.node_tree.nodes["Background"].inputs["Color"])
            scene.world = world
            data = bpy.data.lights.new("lamp", "POINT")
            data.energy = 300.0
            lamp = bpy.data.objects.new("lamp", data)
            lamp.location = (2.0, 1.0, 2.5)
            scene.collection.objects.link(lamp)
            photo = bpy.data.images.load(str(path))
            settings = scene.relight_photo
            settings.quality, settings.mask_mode, settings.light_kind = "DRAFT", "NETWORK", "WORLD"
            assert bpy.ops.relight_photo.relight(image_name=photo.name, synchronous=True) == {"FINISHED"}
            update = types.SimpleNamespace(id_type_updated=lambda kind: kind == "OBJECT",
                                           updates=[types.SimpleNamespace(id=lamp)])
            lamp_s, dial_s, project_s = [], [], []
            for i in range(args.moves):
                angle = 2 * math.pi * (i + 1) / (args.moves + 1)
                lamp.location = (2.5 * math.cos(angle), 1.0 + 2.5 * math.sin(angle), 2.5)
                t0 = time.perf_counter()
                bpy.context.view_layer.update()
                bl_dials.on_depsgraph_update(scene, update)
                lamp_s.append(time.perf_counter() - t0)
                t0 = time.perf_counter()
                settings.rotation = angle
                dial_s.append(time.perf_counter() - t0)
                t0 = time.perf_counter()
                lamps_coeffs(bl_world.scene_lamps(scene), (0.0, 3.0, 1.0), 4)
                project_s.append(time.perf_counter() - t0)
            print(f"photo {size[0]} x {size[1]} ({size[0] * size[1] / 1e6:.1f} MP); bpy {bpy.app.version_string}; "
                  f"load average {os.getloadavg()[0]:.2f}")
            print("| change | median (s) | max (s) |")
            print("|---|---|---|")
            for name, values in (("lamp moved (handler -> relit)", lamp_s), ("rotation dial (-> relit)", dial_s),
                                 ("the scene's lamps to SH alone", project_s)):
                print(f"| {name} | {statistics.median(values):.4f} | {max(values):.4f} |")
        finally:
            bpy.ops.wm.read_homefile()
            blender_addon.unregister()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
