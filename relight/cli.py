"""The `relight` command: `relight sh`, `relight presets`, `relight image`."""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import re
import sys

import numpy as np

EXIT_BAD_INPUT = 2
ROTATE_LIMIT = 1e6  # degrees either way: beyond, a float's angle mod 360 loses its precision
# what argparse must read as a (negative) number, not an option: -1, -.5, -1e9, -2.5E-3, -inf, -nan
_NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$|^-(inf|infinity|nan)$", re.IGNORECASE)


class _Parser(argparse.ArgumentParser):
    """argparse that reports usage errors as one line on stderr, exit 2, and
    takes `--exposure -1e9` or `--rotate -inf` as an option with its value (then
    judged by the option's type), where plain argparse sees a second option."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = _NEGATIVE_NUMBER

    def error(self, message):
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}\n")


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


def cores_available() -> int:
    """CPU cores this process may run on (its affinity mask, not the host's count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _cmd_sh(args) -> int:
    from relight import sh
    from relight.envmap import light_from_map

    coeffs = light_from_map(
        args.map,
        args.order,
        rotation_deg=args.rotate,
        normalize=args.normalize,
        target=args.target,
    )
    if args.window != "none":
        coeffs = sh.apply_window(coeffs, args.window)
    if args.json:
        print(json.dumps({"order": args.order, "coeffs": np.round(coeffs, 9).tolist()}))
    else:
        print(f"# SH order {args.order}, {sh.num_coeffs(args.order)} coefficients (l, m, R, G, B)")
        for l in range(args.order + 1):
            for m in range(-l, l + 1):
                r, g, b = coeffs[l * l + l + m]
                print(f"{l:2d} {m:+3d} {r:14.8g} {g:14.8g} {b:14.8g}")
    return 0


def _cmd_presets(args) -> int:
    from relight import presets

    names = presets.list_presets()
    if args.blender:
        names += presets.list_blender_presets()
    for name in names:
        tag = "\theld-out" if name in presets.HELD_OUT else ""
        print(f"{name}{tag}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="relight", description="Single-image full-body human relighting.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    from relight.sh import MAX_ORDER

    p = sub.add_parser("sh", help="SH coefficients of an equirect HDR map or preset")
    p.add_argument("map", help="EXR/.hdr path or preset name (see `relight presets`)")
    p.add_argument("--order", type=bounded_int(0, MAX_ORDER), default=4,
                   help="SH order N, (N+1)^2 coefficients (default 4)")
    p.add_argument("--rotate", type=finite_float(-ROTATE_LIMIT, ROTATE_LIMIT, what="angle (degrees)"),
                   default=0.0, metavar="DEG",
                   help="rotate the light about world Z")
    p.add_argument("--normalize", action="store_true", help="scale to the reference mean luminance")
    p.add_argument("--target", type=finite_float(0.0, 1e6, low_open=True, what="target luminance"), default=0.8,
                   help="reference mean luminance (default 0.8)")
    p.add_argument("--window", choices=("none", "hanning", "lanczos"), default="none",
                   help="ringing window applied per band after projection (default none)")
    p.add_argument("--json", action="store_true", help='print {"order": N, "coeffs": [[r, g, b], ...]}')
    p.set_defaults(func=_cmd_sh)

    p = sub.add_parser("presets", help="list the bundled HDR light presets")
    p.add_argument("--blender", action="store_true", help="also list Blender's maps (needs bpy)")
    p.set_defaults(func=_cmd_presets)

    if importlib.util.find_spec("relight.cli_image") is not None:
        from relight.cli_image import register

        register(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # usage error (exit 2, one line already printed) or --help (0)
        return int(exc.code or 0)
    try:
        return int(args.func(args) or 0)
    except BrokenPipeError:  # e.g. `relight presets | head -1`
        sys.stderr.close()
        return 0
    except (ValueError, OSError) as exc:
        print(f"relight {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except MemoryError:  # the size checks should come first; this is the last line of defence
        print(f"relight {args.command}: error: out of memory", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
