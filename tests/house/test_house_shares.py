"""The house is a product, not a lab (issue 49): benchmarks/ holds at most 15 % of the lines of
Python outside tests/ (a study whose result is in docs/ leaves the tree, its command and commit
kept there), and the shipped core holds no experiment without a caller in the product."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ROOMS = ("relight", "farm", "blender_addon", "model", "export", "evaluation", "tools", "benchmarks")
BENCHMARK_SHARE = 0.15


def python_lines(folder: str) -> int:
    return sum(len(p.read_text(encoding="utf-8").splitlines()) for p in (ROOT / folder).rglob("*.py"))


def test_benchmarks_are_at_most_15_percent_of_the_house():
    lines = {room: python_lines(room) for room in ROOMS}
    share = lines["benchmarks"] / sum(lines.values())
    assert share <= BENCHMARK_SHARE, f"benchmarks/ is {share:.1%} of the house's lines: {lines}"


def test_every_core_module_has_a_caller_in_the_product():
    """A module of relight/ that only studies, benchmarks or tests import is an experiment: it
    leaves the core (issue 49: the face mesh did). The product is the core itself, the farm, the
    model, the export and the add-on; relight/cli.py and the package files are entry points."""
    from test_import_cycles import import_graph

    graph = import_graph()
    product = ("relight", "blender_addon", "farm", "model", "export")
    imported = {t for m, targets in graph.items() if m.split(".")[0] in product for t in targets if t != m}
    orphans = sorted(m for m in graph if m.startswith("relight.") and m not in imported
                     and m != "relight.cli" and not (ROOT / m.replace(".", "/") / "__init__.py").exists())
    assert orphans == []
