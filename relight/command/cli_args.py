"""The `relight` command's argument parsing: the parser class and the value types
shared by its sub-commands (relight/cli.py, relight/command/request.py)."""

from __future__ import annotations

import argparse
import re

from relight.files.argument_types import bounded_int, finite_float  # noqa: F401 (re-exported: the command's types)

EXIT_BAD_INPUT = 2
ROTATE_LIMIT = 1e6  # degrees either way: beyond, a float's angle mod 360 loses its precision
# what argparse must read as a (negative) number, not an option: -1, -.5, -1e9, -2.5E-3, -inf, -nan
_NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$|^-(inf|infinity|nan)$", re.IGNORECASE)


class Parser(argparse.ArgumentParser):
    """argparse that reports usage errors as one line on stderr, exit 2, and
    takes `--exposure -1e9` or `--rotate -inf` as an option with its value (then
    judged by the option's type), where plain argparse sees a second option."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = _NEGATIVE_NUMBER

    def error(self, message):
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}\n")


# the --rotate type of `relight sh`, `image`, `video` and `light`: one definition
rotation_deg = finite_float(-ROTATE_LIMIT, ROTATE_LIMIT, what="angle (degrees)")


def exposure_ev(text: str) -> float:
    """argparse type of --exposure: the one check of the exposure on the command's path
    (relight.lighting.light.exposure_scale's bound and message); trusted after it."""
    from relight.lighting.light import exposure_scale

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid float value: {text!r}") from None
    try:
        exposure_scale(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return value
