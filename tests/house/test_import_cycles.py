"""No import cycles between the project's modules (issue 19).

Every `import` and `from ... import` in relight/, model/, export/, blender_addon/,
farm/ and evaluation/ counts, at module level or inside a function (a lazy import that
closes a loop is still a cycle: neither module can be understood without the
other). `from package import name` points at the submodule when `name` is one,
else at the package. The cycles are the strongly connected components of that
graph with more than one module, or a module importing itself.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("relight", "model", "export", "blender_addon", "farm", "evaluation")


def module_files() -> dict[str, Path]:
    """{dotted module name: its file} for every module of PACKAGES."""
    out = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


def imported_names() -> dict[str, set[str]]:
    """{module: every dotted name it imports, relative imports made absolute}; for
    `from package import name`, package.name when that is a module of the project, else
    the package (so a library's `from torch import nn` is `torch`)."""
    modules = module_files()
    out: dict[str, set[str]] = {m: set() for m in modules}
    for name, path in modules.items():
        is_package = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.Import):
                out[name].update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = name.split(".") if is_package else name.split(".")[:-1]
                    base = base[:len(base) - (node.level - 1)]
                    module = ".".join(base + ([node.module] if node.module else []))
                else:
                    module = node.module or ""
                for alias in node.names:
                    sub = f"{module}.{alias.name}"
                    out[name].add(sub if sub in modules else module)
    return out


def import_graph() -> dict[str, set[str]]:
    """{module: modules of the project it imports}."""
    modules = module_files()
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for name, targets in imported_names().items():
        for target in targets:
            # `import a.b.c` loads a, a.b and a.b.c: the deepest project module is the edge
            while target and target not in modules:
                target = target.rpartition(".")[0]
            if target and target != name:
                graph[name].add(target)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan), sorted."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(out)


def test_the_cycle_finder_finds_a_cycle_and_only_that():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert cycles(graph) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_the_graph_sees_lazy_and_relative_imports():
    graph = import_graph()
    assert "relight.command.cli_image" in graph["relight.cli"]          # imported inside build_parser()
    assert "blender_addon.logic.light_sources" in graph["blender_addon.worker.engine"]  # `from . import light_sources`
    assert "relight.lighting.light" in graph["farm.synthesis.lights"]


@pytest.mark.parametrize("package", PACKAGES)
def test_no_import_cycles(package):
    found = [c for c in cycles(import_graph()) if any(m.split(".")[0] == package for m in c)]
    assert found == [], f"import cycles through {package}/: {found}"


def test_from_relight_import_relighter_and_import_relight_stays_light():
    """Issue 40: `from relight import Relighter` failed; `import relight` alone loads nothing heavy."""
    import subprocess
    import sys

    code = ("import sys, relight\n"
            "heavy = sorted(m for m in ('numpy', 'onnxruntime', 'relight.network.runtime') if m in sys.modules)\n"
            "assert heavy == [], heavy\n"
            "from relight import Relighter, Decomposition, SHLight, sh_light\n"
            "from relight.network.runtime import Relighter as R\n"
            "assert Relighter is R and 'relight.network.runtime' in sys.modules\n"
            "assert {'Relighter', 'sh_light'} <= set(dir(relight))\n"
            "try:\n    relight.no_such_name\nexcept AttributeError as e:\n    assert 'no_such_name' in str(e)\n"
            "else:\n    raise SystemExit('no AttributeError')\n")
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
