"""The add-on reads images only through the core (issue 49): no module of blender_addon/ imports
Pillow but its build and developer tools, which never run inside the installed extension. The
photo's header (size, orientation, focal length) and its size limits are the core's
(relight.files.photo_header, relight.files.image_limits); the add-on words what they say.

Imports are counted as in test_import_cycles.py: at module level or inside a function. That no
two of the add-on's folders import each other is tests/house/test_folder_layers.py's
test_no_two_folders_import_each_other[blender_addon].
"""

from __future__ import annotations

from test_import_cycles import imported_names

# the add-on's modules that may import Pillow: the zip's builder and the developer tools (not in the zip)
BUILD_AND_DEV_TOOLS = ("blender_addon.build", "blender_addon.dev")


def pillow_importers(names: dict[str, set[str]], allowed: tuple[str, ...] = BUILD_AND_DEV_TOOLS) -> list[str]:
    """'module -> name' for each import of PIL by an add-on module outside `allowed` (a module or a
    folder's dotted prefix)."""
    return sorted(f"{m} -> {n}" for m, imported in names.items() for n in imported
                  if m.split(".")[0] == "blender_addon" and n.split(".")[0] == "PIL"
                  and not any(m == a or m.startswith(a + ".") for a in allowed))


def test_the_check_finds_pillow_outside_the_tools():
    names = {"blender_addon.logic.photo_checks": {"numpy", "PIL.Image"},
             "blender_addon.dev.contact_sheet": {"PIL"}, "blender_addon.build": {"PIL.Image"},
             "blender_addon.developer": {"PIL"}, "relight.files.photo": {"PIL"}}
    assert pillow_importers(names) == ["blender_addon.developer -> PIL",
                                       "blender_addon.logic.photo_checks -> PIL.Image"]


def test_no_pillow_in_the_addon_outside_its_build_and_dev_tools():
    assert pillow_importers(imported_names()) == [], (
        "the add-on reads images through relight.files (photo_header, photo), not Pillow")
