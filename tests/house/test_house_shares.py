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
