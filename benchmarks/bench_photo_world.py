"""Photo Light -> World and Compositing Setup on a 24 MP photo already relit: seconds per press.

    .venv/bin/python benchmarks/bench_photo_world.py [--megapixels 24] [--presses 3]
    .venv-b52/bin/python benchmarks/bench_photo_world.py

The bundled astronaut photo is resized (Pillow, Lanczos) to about 24 MP and
saved as a JPEG; the add-on (headless bpy) relights it once with the shipped
model (Draft, the network's matte: the timed buttons do not depend on either),
then each button is pressed --presses times and timed around the bpy.ops call
on the main thread (the first press includes the map's basis tables, built once
per process). The goal (issue 27) is <= 1 s a press. Prints the load average:
on a shared machine compare rows of one run.
"""

from __future__ import annotations

import os
import statistics
import time

from photos import megapixels_parser, photo_in_temporary_folder  # benchmarks/photos.py


def main(argv=None) -> int:
    parser = megapixels_parser(__doc__, 24.0)
    parser.add_argument("--presses", type=int, default=3)
    args = parser.parse_args(argv)

    import bpy

    import blender_addon

    with photo_in_temporary_folder("bench_photo_world_", args.megapixels) as (_, path, size):
        blender_addon.register()
        try:
            bpy.ops.wm.read_homefile(use_empty=True)
            photo = bpy.data.images.load(str(path))
            settings = bpy.context.scene.relight_photo
            settings.quality, settings.mask_mode, settings.light_kind, settings.preset = \
                "DRAFT", "NETWORK", "PRESET", "studio"
            t0 = time.perf_counter()
            assert bpy.ops.relight_photo.relight(image_name=photo.name, synchronous=True) == {"FINISHED"}
            relight_s = time.perf_counter() - t0
            print(f"photo {size[0]} x {size[1]} ({size[0] * size[1] / 1e6:.1f} MP); Relight {relight_s:.1f} s; "
                  f"bpy {bpy.app.version_string}; load average {os.getloadavg()[0]:.2f}")
            print("| button | press 1 (s) | later presses, median (s) | load average |")
            print("|---|---|---|---|")
            for operator in (bpy.ops.relight_photo.light_to_world, bpy.ops.relight_photo.compositing_setup):
                seconds = []
                for _ in range(args.presses):
                    t0 = time.perf_counter()
                    assert operator(image_name=photo.name) == {"FINISHED"}
                    seconds.append(time.perf_counter() - t0)
                later = statistics.median(seconds[1:]) if len(seconds) > 1 else float("nan")
                print(f"| {operator.idname_py()} | {seconds[0]:.2f} | {later:.2f} | {os.getloadavg()[0]:.2f} |")
        finally:
            bpy.ops.wm.read_homefile(use_empty=True)
            blender_addon.unregister()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
