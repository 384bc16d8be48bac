"""fp16 variant of an exported graph: weights and compute in float16, I/O in float32.

Uses onnxconverter-common's float16 pass with keep_io_types=True, which puts
Cast nodes at the graph's input and outputs and keeps ops without useful
fp16 kernels (its default block list: Resize, Range, ...) in float32.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import onnx

from export.onnx_export import read_metadata, save_atomic, set_metadata


def convert_to_fp16(model: onnx.ModelProto) -> onnx.ModelProto:
    """A float16 copy of `model` with float32 inputs and outputs and the same metadata."""
    from onnxconverter_common import float16

    meta = read_metadata(model)
    with warnings.catch_warnings():
        # it warns about fp32 constants that underflow/overflow fp16 and clamps them
        warnings.simplefilter("ignore", UserWarning)
        half = float16.convert_float_to_float16(model, keep_io_types=True, disable_shape_infer=False)
    meta["relight.precision"] = "fp16"
    set_metadata(half, meta)
    return half


def export_fp16(fp32_path: str | os.PathLike, out: str | os.PathLike) -> tuple[Path, str]:
    """Write the fp16 variant of the fp32 ONNX file at `fp32_path`; returns (path, sha256)."""
    return save_atomic(convert_to_fp16(onnx.load(str(fp32_path))), out)
