"""The end of an evaluation command: run it, print the report it wrote and one line of
what it made; a ValueError (bad model, data or option) is one line on stderr, exit 2."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Callable


def run_report(prog: str, run: Callable[[], object], report: Path, summary: Callable[[object], str]) -> int:
    """`run()` writes `report` (markdown); returns the process exit code."""
    try:
        result = run()
    except ValueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    print(Path(report).read_text(encoding="utf-8"), end="")
    print(summary(result))
    return 0
