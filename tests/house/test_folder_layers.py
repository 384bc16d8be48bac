"""The folders of each package form layers (issue 49): no two folders of a package import each
other, in either direction, through any of their modules, and each package's folders import only
the folders docs/ARCHITECTURE.md lists below them.

A module's folder is the directory that holds its file (`relight/lighting/sh.py` is in
`relight/lighting`, `relight/cli.py` in `relight`); imports are counted as in
test_import_cycles.py: at module level or inside a function, relative ones made absolute.
"""

from __future__ import annotations

import re

import pytest
from test_import_cycles import PACKAGES, ROOT, import_graph, module_files


def folder_graph() -> dict[str, dict[str, set[tuple[str, str]]]]:
    """{folder: {folder it imports (same package): {(importing module, imported module)}}}."""
    files = module_files()
    folder = {m: p.parent.relative_to(ROOT).as_posix() for m, p in files.items()}
    out: dict[str, dict[str, set[tuple[str, str]]]] = {f: {} for f in folder.values()}
    for module, imported in import_graph().items():
        for target in imported:
            a, b = folder[module], folder[target]
            if a != b and a.split("/")[0] == b.split("/")[0]:
                out[a].setdefault(b, set()).add((module, target))
    return out


def documented_layers() -> dict[str, list[str]]:
    """{package: its folders, top layer first}, from the "Layers" list of docs/ARCHITECTURE.md:
    one line per package, `- \\`pkg\\`: \\`a\\` > \\`b\\` > ...`."""
    text = (ROOT / "docs" / "ARCHITECTURE.md").read_text(encoding="utf-8")
    section = text.split("## Layers inside each package", 1)[1].split("\n## ", 1)[0]
    out = {}
    for line in section.splitlines():
        m = re.match(r"- `(\w+)/`: (.*)", line.strip())
        if m:
            out[m.group(1)] = [f.strip().strip("`").rstrip("/") for f in m.group(2).split(">")]
    return out


@pytest.mark.parametrize("package", PACKAGES)
def test_no_two_folders_import_each_other(package):
    graph = folder_graph()
    mutual = []
    for a, targets in graph.items():
        if a.split("/")[0] != package:
            continue
        for b, edges in targets.items():
            if a < b and a in graph.get(b, {}):
                mutual.append((a, b, sorted(edges)[:3], sorted(graph[b][a])[:3]))
    assert mutual == [], f"folders of {package}/ that import each other: {mutual}"


@pytest.mark.parametrize("package", PACKAGES)
def test_folders_import_only_the_layers_below(package):
    """Each folder imports only folders listed after it (the order is the layering)."""
    layers = documented_layers()
    folders = sorted({p.parent.relative_to(ROOT).as_posix() for p in (ROOT / package).rglob("*.py")})
    order = layers.get(package, [package])
    assert sorted(order) == folders, f"docs/ARCHITECTURE.md's layers of {package}/ name {order}, the folders are {folders}"
    rank = {f: i for i, f in enumerate(order)}
    upward = [(a, b, sorted(edges)[:2]) for a, targets in folder_graph().items() if a in rank
              for b, edges in targets.items() if rank[b] <= rank[a]]
    assert upward == [], f"imports that point up or sideways in {package}/: {upward}"


def test_the_farm_never_imports_the_command_layer():
    """The farm and the `relight` command both sit on the core; neither reaches into the other."""
    offenders = sorted((m, t) for m, imported in import_graph().items() if m.split(".")[0] == "farm"
                       for t in imported if t.startswith("relight.command") or t == "relight.cli")
    assert offenders == []
