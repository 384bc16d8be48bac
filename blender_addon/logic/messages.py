"""The artist's messages made from an error: its first line, without the closing full stop.
Plain Python, imported by the logic modules that word a core error for the artist."""

from __future__ import annotations


def first_line(exc: BaseException) -> str:
    """The first line of an error's message, without its closing full stop (for the artist's messages)."""
    text = str(exc).strip().splitlines()
    return text[0].rstrip(".") if text else type(exc).__name__
