"""The `relight` command: `relight sh`, `relight presets`, `relight image`, `relight light`, `relight video`."""

from __future__ import annotations

import argparse
import json
import logging
import sys

import numpy as np

from relight.command.cli_args import EXIT_BAD_INPUT, Parser, bounded_int, finite_float, rotation_deg

def _cmd_sh(args) -> int:
    from relight.lighting import sh
    from relight.lighting.light import sh_light

    coeffs = sh_light(args.map, args.order, rotation_deg=args.rotate, normalize=args.normalize, target=args.target)
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
    from relight.lighting import presets

    names = presets.list_presets()
    if args.blender:
        names += presets.list_blender_presets()
    for name in names:
        tag = "\theld-out" if name in presets.HELD_OUT else ""
        print(f"{name}{tag}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="relight", description="Single-image full-body human relighting.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)

    from relight.lighting.sh import MAX_ORDER, REFERENCE_LUMINANCE

    p = sub.add_parser("sh", help="SH coefficients of an equirect HDR map or preset")
    p.add_argument("map", help="EXR/.hdr path or preset name (see `relight presets`)")
    p.add_argument("--order", type=bounded_int(0, MAX_ORDER), default=4,
                   help="SH order N, (N+1)^2 coefficients (default 4)")
    p.add_argument("--rotate", type=rotation_deg,
                   default=0.0, metavar="DEG",
                   help="rotate the light about world Z")
    p.add_argument("--normalize", action="store_true", help="scale to the reference mean luminance")
    p.add_argument("--target", type=finite_float(0.0, 1e6, low_open=True, what="target luminance"),
                   default=REFERENCE_LUMINANCE, help=f"reference mean luminance (default {REFERENCE_LUMINANCE:g})")
    p.add_argument("--window", choices=("none", "hanning", "lanczos"), default="none",
                   help="ringing window applied per band after projection (default none)")
    p.add_argument("--json", action="store_true", help='print {"order": N, "coeffs": [[r, g, b], ...]}')
    p.set_defaults(func=_cmd_sh)

    p = sub.add_parser("presets", help="list the bundled HDR light presets")
    p.add_argument("--blender", action="store_true", help="also list Blender's maps (needs bpy)")
    p.set_defaults(func=_cmd_presets)

    from relight.command.cli_image import register as register_image
    from relight.command.cli_light import register as register_light
    from relight.command.cli_video import register as register_video

    register_image(sub)
    register_light(sub)
    register_video(sub)
    return parser


class _LogFormatter(logging.Formatter):
    """`relight image: warning: message`, as the command's own lines read."""

    def format(self, record):
        record.level = record.levelname.lower()
        return super().format(record)


def main(argv=None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # usage error (exit 2, one line already printed) or --help (0)
        return int(exc.code or 0)
    # the command's logging, configured once per process: warnings and worse on stderr in the
    # command's one-line format (relight's modules log through logging.getLogger(__name__)); a
    # process that configured logging already (an embedding program, pytest) keeps its own
    if not logging.getLogger().handlers:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(_LogFormatter(f"relight {args.command}: %(level)s: %(message)s"))
        logging.basicConfig(level=logging.WARNING, handlers=[handler])
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
