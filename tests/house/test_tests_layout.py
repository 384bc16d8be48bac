"""The tests' own house (issue 49): each test module in a folder that mirrors the folder of the code
it tests, the shared helpers in tests/support, and no test module over 600 lines (a longer one
tests more than one thing: split it by what it tests)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TESTS = ROOT / "tests"
MAX_LINES = 600
# folders of tests that mirror no code folder: the house's own rules, and the shared helpers and data
OWN_FOLDERS = {"house", "support", "data"}


def all_test_modules() -> list[Path]:
    return sorted(TESTS.rglob("test_*.py"))


def test_every_test_module_mirrors_a_code_folder():
    """tests/relight/network/test_x.py tests relight/network/; nothing at tests/ itself."""
    stray = []
    for path in all_test_modules():
        folder = path.parent.relative_to(TESTS)
        if folder.parts and folder.parts[0] in OWN_FOLDERS:
            continue
        if not folder.parts or not (ROOT / folder).is_dir():
            stray.append(path.relative_to(ROOT).as_posix())
    assert stray == [], f"test modules in no folder that mirrors the code's: {stray}"


def test_helpers_live_in_one_place():
    """Modules the tests import by name (no test_ prefix) are in tests/support, except the fixtures."""
    helpers = sorted(p.relative_to(ROOT).as_posix() for p in TESTS.rglob("*.py")
                     if not p.name.startswith("test_") and p.name != "conftest.py"
                     and p.parent != TESTS / "support")
    assert helpers == []
    assert sorted(p.relative_to(ROOT).as_posix() for p in TESTS.rglob("conftest.py")) == ["tests/conftest.py"]


def test_no_test_module_is_over_600_lines():
    long = {p.relative_to(ROOT).as_posix(): n for p in all_test_modules()
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES}
    assert long == {}
