"""Install a built zip into a throw-away Blender user folder and relight with the
bundled wheels (not the venv's): the check the tests cannot make offline.

    python -m blender_addon.dev.check_installed_zip dist/relight_photo-0.1.0.zip MODEL.onnx

Re-executes itself with BLENDER_USER_RESOURCES set to a temporary folder, so
the real user's Blender is never touched. After the install it puts the
extension's site-packages first on sys.path, so onnxruntime, Pillow, OpenEXR
and relight are imported from the wheels inside the zip; prints where each
came from, then runs Relight and Save Layers.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

BUNDLED = ("onnxruntime", "PIL", "OpenEXR", "relight")


def _inside(zip_path: str, model: str, user_dir: str) -> int:
    import bpy

    result = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default",
                                                      enable_on_install=True)
    print("install:", sorted(result))
    site = Path(user_dir) / "extensions" / ".local" / "lib" / f"python{sys.version_info[0]}.{sys.version_info[1]}" \
        / "site-packages"
    sys.path.insert(0, str(site))
    for name in [m for m in sys.modules if m.split(".")[0] in BUNDLED]:
        del sys.modules[name]
    import importlib

    for name in BUNDLED:
        module = importlib.import_module(name)
        where = "bundled wheel" if str(site) in str(module.__file__) else "NOT bundled"
        print(f"{name:12s} {where}: {module.__file__}")
    import shutil

    # a real photo (public domain, from the checkout; the zip ships no photos), so the
    # Automatic mask runs the person matte's networks from the bundled wheel too
    photo = Path(user_dir) / "photo.jpg"
    shutil.copy(Path(__file__).resolve().parents[2] / "evaluation" / "data" / "matte_eval" / "grace_hopper.jpg",
                photo)
    image = bpy.data.images.load(str(photo))
    settings = bpy.context.scene.relight_photo
    settings.model_path = model
    settings.preset = "sunset"
    settings.mask_mode = "AUTO"
    print("relight:", sorted(bpy.ops.relight_photo.relight(image_name=image.name, synchronous=True)))
    print("people found:", settings.people_found)
    out = Path(user_dir) / "layers.exr"
    print("save layers:", sorted(bpy.ops.relight_photo.save_layers(filepath=str(out), image_name=image.name)))
    from relight.files.exr import read_exr

    print("EXR channels:", ", ".join(sorted(read_exr(out))))
    return 0


def main(argv=None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) == 3 and os.environ.get("BLENDER_USER_RESOURCES") == args[2]:
        return _inside(*args)
    if len(args) != 2:
        print("usage: python -m blender_addon.dev.check_installed_zip ZIP MODEL.onnx", file=sys.stderr)
        return 2
    zip_path, model = (str(Path(a).resolve()) for a in args)
    with tempfile.TemporaryDirectory(prefix="relight_zip_check_") as user_dir:
        env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
        env["BLENDER_USER_RESOURCES"] = user_dir
        # run this file by path: its folder, not the checkout, is on sys.path, so
        # `relight` can only come from what the zip installs
        done = subprocess.run([sys.executable, str(Path(__file__).resolve()), zip_path, model, user_dir],
                              cwd=user_dir, env=env)
        return done.returncode


if __name__ == "__main__":
    sys.exit(main())
