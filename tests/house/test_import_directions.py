"""The rooms' import directions and the rooms table of docs/ARCHITECTURE.md, held true.

A room is a top-level package of the project. ALLOWED says which other rooms each may
import, BANNED which libraries it may not (the core and evaluation/ run without torch
or Blender; the add-on runs in Blender's Python, which has no torch). Every import
counts, at module level or inside a function, as in tests/house/test_import_cycles.py,
whose graph this reads. docs/ARCHITECTURE.md states the same two tables ("Import
directions"), and its rooms table names every module of every room, so the doc
cannot fall behind the code.
"""

from __future__ import annotations

import re

import pytest

from test_import_cycles import PACKAGES, ROOT, import_graph, imported_names, module_files

ARCHITECTURE = ROOT / "docs" / "ARCHITECTURE.md"

# room: the other rooms it may import (it may always import itself)
ALLOWED = {
    "relight": set(),
    "evaluation": {"relight"},
    "farm": {"relight"},
    "model": {"relight", "evaluation"},
    "export": {"model", "relight"},
    "blender_addon": {"relight"},
}
# room: libraries it never imports
BANNED = {
    "relight": {"torch", "bpy"},
    "evaluation": {"torch", "bpy"},
    "farm": set(),
    "model": {"bpy"},
    "export": {"bpy"},
    "blender_addon": {"torch"},
}


def room(module: str) -> str:
    return module.split(".")[0]


def wrong_directions(graph: dict[str, set[str]], allowed: dict[str, set[str]]) -> list[str]:
    """'a.b -> c.d' for every import of a room that ALLOWED does not let it import."""
    return sorted(f"{m} -> {t}" for m, targets in graph.items() for t in targets
                  if room(t) != room(m) and room(t) not in allowed[room(m)])


def banned_imports(names: dict[str, set[str]], banned: dict[str, set[str]]) -> list[str]:
    """'a.b -> lib' for every import of a library its room bans."""
    return sorted(f"{m} -> {n}" for m, imported in names.items() for n in imported
                  if n.split(".")[0] in banned[room(m)])


def _doc_section(title: str) -> str:
    text = ARCHITECTURE.read_text(encoding="utf-8")
    start = text.index(f"## {title}\n")
    end = text.find("\n## ", start + 1)
    return text[start:end if end >= 0 else None]


def doc_directions() -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """ALLOWED and BANNED as the table of ARCHITECTURE.md's "Import directions" states them:
    rows | `room/` | `other/`, ... or - | library, ... or - |."""
    allowed, banned = {}, {}
    for line in _doc_section("Import directions").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 3 or not re.fullmatch(r"`\w+/`", cells[0]):
            continue
        name = cells[0].strip("`/")
        allowed[name] = set(re.findall(r"`(\w+)/`", cells[1]))
        banned[name] = {b.strip() for b in cells[2].split(",")} - {"-", ""}
    return allowed, banned


def test_the_checks_find_a_wrong_direction_and_a_banned_library():
    graph = {"relight.a": {"relight.b"}, "relight.b": {"model.x"}, "model.x": {"relight.a"}}
    assert wrong_directions(graph, {"relight": set(), "model": {"relight"}}) == ["relight.b -> model.x"]
    names = {"relight.a": {"numpy", "torch.nn"}, "model.x": {"torch"}}
    assert banned_imports(names, {"relight": {"torch"}, "model": set()}) == ["relight.a -> torch.nn"]


def test_every_room_has_its_rules():
    assert set(ALLOWED) == set(BANNED) == set(PACKAGES)


@pytest.mark.parametrize("package", PACKAGES)
def test_imports_point_the_allowed_way(package):
    graph = {m: t for m, t in import_graph().items() if room(m) == package}
    assert wrong_directions(graph, ALLOWED) == [], f"{package}/ imports a room it may not (docs/ARCHITECTURE.md)"


@pytest.mark.parametrize("package", PACKAGES)
def test_no_banned_library(package):
    names = {m: n for m, n in imported_names().items() if room(m) == package}
    assert banned_imports(names, BANNED) == [], f"{package}/ imports a library it may not (docs/ARCHITECTURE.md)"


def test_architecture_states_the_same_directions():
    assert doc_directions() == (ALLOWED, BANNED)


def test_architecture_names_every_module_and_no_other():
    """Each module's path (`relight/lighting/sh.py`) in the rooms table; each path there exists."""
    table = _doc_section("Data flow, and each room's one job")
    named = set(re.findall(r"`((?:%s)/[\w/]+\.py)`" % "|".join(PACKAGES), table))
    files = {p.relative_to(ROOT).as_posix() for p in module_files().values()}
    assert sorted(files - named) == [], "modules missing from docs/ARCHITECTURE.md's rooms table"
    assert sorted(named - files) == [], "docs/ARCHITECTURE.md's rooms table names modules that do not exist"


# the add-on's Blender layer: the only modules of the add-on that import bpy (dev/: tools run in Blender)
ADDON_BPY_LAYER = "blender_addon.blender"
MAX_MODULES_PER_FOLDER = 15
MAX_MODULE_LINES = 450


def test_only_the_addons_blender_layer_imports_bpy():
    """The add-on's rule: its bl_* modules, in blender_addon/blender/, import bpy; the others do not."""
    names = {m: n for m, n in imported_names().items() if room(m) == "blender_addon"}
    uses_bpy = {m for m, imported in names.items() if any(n.split(".")[0] == "bpy" for n in imported)}
    layer = {m for m in names if m.startswith(ADDON_BPY_LAYER + ".")}
    dev = {m for m in names if m.startswith("blender_addon.dev")}
    assert sorted(uses_bpy - layer - dev) == [], "bpy imported outside blender_addon/blender/"
    assert sorted(layer - uses_bpy) == [], "a module of blender_addon/blender/ without bpy belongs elsewhere"
    assert sorted(m for m in layer if not m.rpartition(".")[2].startswith("bl_")) == []


def test_no_crowded_folder_and_no_long_module():
    """No folder of the packages holds more than 15 modules (besides its __init__.py), and no module of
    theirs is over 450 lines (issue 39: the layout shows the jobs)."""
    folders: dict[str, int] = {}
    for path in module_files().values():
        if path.name != "__init__.py":
            folder = path.parent.relative_to(ROOT).as_posix()
            folders[folder] = folders.get(folder, 0) + 1
    assert {f: n for f, n in folders.items() if n > MAX_MODULES_PER_FOLDER} == {}
    lengths = {p.relative_to(ROOT).as_posix(): len(p.read_text(encoding="utf-8").splitlines())
               for p in module_files().values()}
    assert {f: n for f, n in lengths.items() if n > MAX_MODULE_LINES} == {}
