"""Command-line value types shared by the `relight` command (relight/command/cli_args.py, which
re-exports them) and the farm's (farm/cli.py): text to a checked number, or argparse's
one-line error. Below both, so neither command imports the other's layer."""

from __future__ import annotations

import argparse
import math


def finite_float(low: float, high: float, *, low_open: bool = False, what: str = "number"):
    """argparse type: a finite float in [low, high] ((low, high] when low_open)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid float value: {text!r}") from None
        if not math.isfinite(value) or value > high or value < low or (low_open and value == low):
            raise argparse.ArgumentTypeError(
                f"must be a finite {what} in {'(' if low_open else '['}{low:g}, {high:g}], got {text}")
        return value

    return parse


def bounded_int(low: int, high: int, why: str = ""):
    """argparse type: an integer in [low, high]."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid int value: {text!r}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be an integer in [{low}, {high}]{why}, got {text}")
        return value

    return parse
