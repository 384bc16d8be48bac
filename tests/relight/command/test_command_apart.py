"""Issue 49: no `relight` sub-command imports another's module (what they share is relight/command/request.py),
and below their entry points they pass request values, not the argparse namespace."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

COMMAND = Path(__file__).resolve().parents[3] / "relight" / "command"
COMMANDS = {"cli_image", "cli_light", "cli_video"}  # the sub-commands' modules
ENTRY_POINTS = {"run_image", "run_light", "run_video"}


def _imported(path: Path) -> set[str]:
    """Every module an import statement of `path` names (at module level or inside a function)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_no_command_imports_another(command):
    others = {f"relight.command.{name}" for name in COMMANDS - {command}}
    assert not _imported(COMMAND / f"{command}.py") & others


@pytest.mark.parametrize("module", sorted(COMMANDS | {"request"}))
def test_only_the_entry_points_and_the_request_builders_take_the_namespace(module):
    # a function taking the parsed namespace is named `args` by the command's convention (argparse's func)
    takers = {node.name for node in ast.walk(ast.parse((COMMAND / f"{module}.py").read_text()))
              if isinstance(node, ast.FunctionDef) and any(a.arg == "args" for a in node.args.args)}
    assert takers <= ENTRY_POINTS | {"from_args", "relight_options"}, takers
