"""python -m export MODEL.safetensors --out model.onnx [--fp16] [--register NAME]

Writes model.onnx (+ model.onnx.sha256), checks it against torch on random
inputs at two sizes, and with --fp16 also model.fp16.onnx with its measured
error against the fp32 graph. Prints one line per check.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m export", description=__doc__.splitlines()[0])
    parser.add_argument("weights", help="RelightNet checkpoint (.safetensors, model/training/checkpoint.py)")
    parser.add_argument("--out", required=True, help="output .onnx path")
    parser.add_argument("--fp16", action="store_true", help="also write OUT stem + .fp16.onnx")
    parser.add_argument("--training-data", default=None,
                        help="description of the training data stored in the metadata")
    parser.add_argument("--default", action="store_true",
                        help="with --register: make NAME the registry's default model")
    parser.add_argument("--register", metavar="NAME", default=None,
                        help="record the model in relight/models/models.json (OUT must be in relight/models/)")
    args = parser.parse_args(argv)
    out = Path(args.out)
    if out.suffix != ".onnx":
        print(f"export: error: --out must end in .onnx, got {out}", file=sys.stderr)
        return 2
    try:
        from model.training.checkpoint import load_model, read_metadata as read_ckpt_metadata

        from export.onnx_export import (DEFAULT_TRAINING_DATA, PARITY_TOLERANCE, REAL_PHOTO, export_onnx,
                                        fp32_parity, max_abs_diff, onnx_outputs, parity_inputs, read_metadata)

        net = load_model(args.weights)
        if args.fp16 and getattr(net, "arch", None) == "geometry":
            # its light fit runs in float64 (model.networks.physics.fit_light), which
            # onnxconverter-common's fp16 pass cannot keep apart; fp16 graphs were
            # no faster on the CPU provider anyway (docs/TRADEOFFS.md)
            raise ValueError("--fp16 is not available for the geometry-first model; export fp32 only")
        ckpt_meta = read_ckpt_metadata(args.weights)
        training = args.training_data or ckpt_meta.get("training_data") or DEFAULT_TRAINING_DATA
        path, digest = export_onnx(net, out, training_data=str(training))
        worst = fp32_parity(net, path)
        print(f"wrote {path} (sha256 {digest}); fp32 parity vs torch (2 random inputs and "
              f"{REAL_PHOTO.name}): max diff {worst:.3g} of each output's size")
        if worst > PARITY_TOLERANCE:
            from relight.models import sidecar_path

            path.unlink()
            sidecar_path(path).unlink(missing_ok=True)  # no hash left behind for a file that is gone
            print(f"export: error: ONNX differs from torch by {worst:.3g} > {PARITY_TOLERANCE}; "
                  "removed the file and its .sha256", file=sys.stderr)
            return 1
        if args.fp16:
            from export.fp16 import export_fp16

            path16, digest16 = export_fp16(path, out.with_name(out.stem + ".fp16.onnx"))
            err, scale = {}, {}
            for x in parity_inputs(net.size_multiple, seed=1):
                ref = onnx_outputs(path, x)
                for k, v in max_abs_diff(ref, onnx_outputs(path16, x)).items():
                    err[k] = max(err.get(k, 0.0), v)
                    scale[k] = max(scale.get(k, 0.0), float(np.abs(ref[k]).max()))
            print(f"wrote {path16} (sha256 {digest16}); fp16 vs fp32 max abs diff "
                  "(and relative to the output's max |value|): "
                  + ", ".join(f"{k} {v:.3g} ({v / max(scale[k], 1e-30):.2g})" for k, v in err.items()))
        if args.register:
            from relight.models import register_model

            reg = register_model(args.register, path, digest, read_metadata(path), make_default=args.default)
            print(f"registered {args.register} in {reg}")
            if args.fp16:
                register_model(f"{args.register}-fp16", path16, digest16, read_metadata(path16))
                print(f"registered {args.register}-fp16 in {reg}")
    except (ValueError, OSError) as exc:
        print(f"export: error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
