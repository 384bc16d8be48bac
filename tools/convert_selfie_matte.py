"""Convert MediaPipe's selfie-segmentation TFLite model to ONNX (the person matte of relight/matte.py).

Not run by CI or the tests: the shipped result is relight/models/person_matte.onnx,
recorded with its SHA-256 in relight/models/models.json. To reproduce it, in a
scratch virtual environment (never the project's: mediapipe pins numpy<2 and protobuf<5):

    python3 -m venv /tmp/convvenv && /tmp/convvenv/bin/pip install tflite onnx numpy
    pip download --no-deps mediapipe==0.10.21 --python-version 3.11 --only-binary :all: -d /tmp/mp
    unzip -o /tmp/mp/mediapipe-0.10.21-*.whl 'mediapipe/modules/selfie_segmentation/*' -d /tmp/mp
    /tmp/convvenv/bin/python tools/convert_selfie_matte.py \\
        /tmp/mp/mediapipe/modules/selfie_segmentation/selfie_segmentation.tflite \\
        --out relight/models/person_matte.onnx

The TFLite graph is read with the `tflite` package (flatbuffer accessors) and
rebuilt op by op with onnx.helper, in NCHW: TFLite weights are transposed,
fp16 constants (behind DEQUANTIZE ops) are stored as float32, and MediaPipe's
custom op Convolution2DTransposeBias (which tf2onnx does not convert) becomes
ConvTranspose with its bias. Input `image` [1, 3, H, W] RGB in [0, 1] (sRGB
encoded, as MediaPipe feeds it); output `mask` [1, 1, H, W], the person
probability. tools/check_matte_onnx.py compares the result with MediaPipe's own
TFLite pipeline on real photos.
"""

from __future__ import annotations

import argparse
import hashlib
import struct
import sys
from pathlib import Path

import numpy as np

OPSET = 17
MEDIAPIPE_VERSION = "0.10.21"


def _opnames(tflite):
    return {v: k for k, v in vars(tflite.BuiltinOperator).items() if not k.startswith("_")}


def _tensor_array(tflite, model, tensor) -> np.ndarray | None:
    """A constant tensor's values (None for activations)."""
    buf = model.Buffers(tensor.Buffer())
    if buf is None or buf.DataLength() == 0:
        return None
    dtypes = {tflite.TensorType.FLOAT32: np.float32, tflite.TensorType.FLOAT16: np.float16,
              tflite.TensorType.INT32: np.int32}
    if tensor.Type() not in dtypes:
        raise ValueError(f"constant of unsupported type {tensor.Type()}: {tensor.Name()}")
    raw = buf.DataAsNumpy().tobytes()
    return np.frombuffer(raw, dtypes[tensor.Type()]).reshape(tensor.ShapeAsNumpy())


def _same_pads(in_hw, k_hw, s_hw, d_hw=(1, 1)):
    """TensorFlow's SAME padding as ONNX pads [top, left, bottom, right] (extra on the end)."""
    before, after = [], []
    for n, k, s, d in zip(in_hw, k_hw, s_hw, d_hw):
        out = -(-n // s)
        total = max((out - 1) * s + (k - 1) * d + 1 - n, 0)
        before.append(total // 2)
        after.append(total - total // 2)
    return before + after


def convert(tflite_path: Path, out_path: Path) -> None:
    import onnx
    import tflite
    from onnx import TensorProto, helper, numpy_helper

    data = tflite_path.read_bytes()
    model = tflite.Model.GetRootAsModel(data, 0)
    graph = model.Subgraphs(0)
    names = _opnames(tflite)
    tensors = [graph.Tensors(i) for i in range(graph.TensorsLength())]
    shape = {i: [int(v) for v in t.ShapeAsNumpy()] for i, t in enumerate(tensors)}

    consts: dict[int, np.ndarray] = {}   # tensor index -> value (NHWC, as stored)
    nodes, inits = [], []
    name = {i: f"t{i}" for i in range(len(tensors))}

    def const(value: np.ndarray, label: str) -> str:
        inits.append(numpy_helper.from_array(np.ascontiguousarray(value), label))
        return label

    pending: list = []  # a fused activation's node, appended after the op that feeds it

    def activation(out: str, fused: int) -> str:
        """The name the op itself writes to: `out`, or `out`_pre when an activation follows."""
        A = tflite.ActivationFunctionType
        if fused == A.NONE:
            return out
        if fused == A.RELU:
            pending.append(helper.make_node("Relu", [out + "_pre"], [out]))
        elif fused == A.RELU6:
            pending.append(helper.make_node("Clip", [out + "_pre", const(np.float32(0), out + "_lo"),
                                                     const(np.float32(6), out + "_hi")], [out]))
        else:
            raise ValueError(f"unsupported fused activation {fused}")
        return out + "_pre"

    def nchw_const(value: np.ndarray, label: str) -> str:
        """An NHWC constant operand of an elementwise op, laid out for NCHW broadcasting."""
        v = value.astype(np.float32)
        if v.ndim == 4:
            v = v.transpose(0, 3, 1, 2)
        elif v.ndim == 1 and v.size > 1:
            v = v.reshape(-1, 1, 1)
        return const(v, label)

    for t_index, tensor in enumerate(tensors):
        value = _tensor_array(tflite, model, tensor)
        if value is not None:
            consts[t_index] = value

    for i in range(graph.OperatorsLength()):
        op = graph.Operators(i)
        code = model.OperatorCodes(op.OpcodeIndex())
        custom = code.CustomCode()
        kind = custom.decode() if custom else names[max(code.BuiltinCode(), code.DeprecatedBuiltinCode())]
        ins = [int(j) for j in op.InputsAsNumpy()]
        outs = [int(j) for j in op.OutputsAsNumpy()]
        out = name[outs[0]]
        if kind == "DEQUANTIZE":
            consts[outs[0]] = consts[ins[0]].astype(np.float32)
            continue
        if kind in ("CONV_2D", "DEPTHWISE_CONV_2D"):
            opts_cls = tflite.Conv2DOptions if kind == "CONV_2D" else tflite.DepthwiseConv2DOptions
            opts = opts_cls()
            o = op.BuiltinOptions()
            opts.Init(o.Bytes, o.Pos)
            w = consts[ins[1]].astype(np.float32)
            b = consts[ins[2]].astype(np.float32) if len(ins) > 2 and ins[2] >= 0 else None
            n, h, wd, c = shape[ins[0]]
            if kind == "CONV_2D":
                weight, group = w.transpose(0, 3, 1, 2), 1          # [O, kh, kw, I] -> [O, I, kh, kw]
            else:
                weight, group = w.transpose(3, 0, 1, 2), c          # [1, kh, kw, C*m] -> [C*m, 1, kh, kw]
            k = weight.shape[2:]
            strides = [opts.StrideH(), opts.StrideW()]
            dil = [opts.DilationHFactor(), opts.DilationWFactor()]
            pads = (_same_pads((h, wd), k, strides, dil) if opts.Padding() == tflite.Padding.SAME
                    else [0, 0, 0, 0])
            inputs = [name[ins[0]], const(weight, out + "_w")] + ([const(b, out + "_b")] if b is not None else [])
            target = activation(out, opts.FusedActivationFunction())
            nodes.append(helper.make_node("Conv", inputs, [target], kernel_shape=list(k), strides=strides,
                                          dilations=dil, pads=pads, group=group))
        elif kind == "Convolution2DTransposeBias":
            # MediaPipe's custom options are TfLiteTransposeConvParams: padding, stride_w, stride_h (int32)
            padding, stride_w, stride_h = struct.unpack("<3i", op.CustomOptionsAsNumpy().tobytes()[:12])
            w = consts[ins[1]].astype(np.float32)                    # [O, kh, kw, I]
            b = consts[ins[2]].astype(np.float32)
            weight = w.transpose(3, 0, 1, 2)                        # ONNX ConvTranspose: [I, O, kh, kw]
            _, h, wd, _ = shape[ins[0]]
            _, oh, ow, _ = shape[outs[0]]
            k = w.shape[1:3]
            pads_b, pads_e = [], []
            for n_in, n_out, kk, s in ((h, oh, k[0], stride_h), (wd, ow, k[1], stride_w)):
                total = max((n_in - 1) * s + kk - n_out, 0)
                pads_b.append(total // 2)
                pads_e.append(total - total // 2)
            nodes.append(helper.make_node("ConvTranspose", [name[ins[0]], const(weight, out + "_w"),
                                                            const(b, out + "_b")], [out],
                                          kernel_shape=list(k), strides=[stride_h, stride_w],
                                          pads=pads_b + pads_e))
            del padding  # the explicit pads above already give the output size TFLite records
        elif kind == "AVERAGE_POOL_2D":
            opts = tflite.Pool2DOptions()
            o = op.BuiltinOptions()
            opts.Init(o.Bytes, o.Pos)
            _, h, wd, _ = shape[ins[0]]
            k = [opts.FilterHeight(), opts.FilterWidth()]
            s = [opts.StrideH(), opts.StrideW()]
            pads = _same_pads((h, wd), k, s) if opts.Padding() == tflite.Padding.SAME else [0, 0, 0, 0]
            target = activation(out, opts.FusedActivationFunction())
            # TFLite averages over the valid pixels only
            nodes.append(helper.make_node("AveragePool", [name[ins[0]]], [target], kernel_shape=k, strides=s,
                                          pads=pads, count_include_pad=0))
        elif kind in ("ADD", "MUL"):
            opts = (tflite.AddOptions if kind == "ADD" else tflite.MulOptions)()
            o = op.BuiltinOptions()
            fused = 0
            if o is not None:
                opts.Init(o.Bytes, o.Pos)
                fused = opts.FusedActivationFunction()
            operands = [nchw_const(consts[j], f"{out}_c{n}") if j in consts else name[j]
                        for n, j in enumerate(ins)]
            target = activation(out, fused)
            nodes.append(helper.make_node("Add" if kind == "ADD" else "Mul", operands, [target]))
        elif kind in ("RELU", "HARD_SWISH", "LOGISTIC"):
            onnx_op = {"RELU": "Relu", "HARD_SWISH": "HardSwish", "LOGISTIC": "Sigmoid"}[kind]
            nodes.append(helper.make_node(onnx_op, [name[ins[0]]], [out]))
        elif kind == "RESIZE_BILINEAR":
            opts = tflite.ResizeBilinearOptions()
            o = op.BuiltinOptions()
            opts.Init(o.Bytes, o.Pos)
            n, _, _, c = shape[ins[0]]
            oh, ow = (int(v) for v in consts[ins[1]])
            mode = ("align_corners" if opts.AlignCorners() else
                    "half_pixel" if opts.HalfPixelCenters() else "asymmetric")
            sizes = const(np.array([n, c, oh, ow], np.int64), out + "_sizes")
            nodes.append(helper.make_node("Resize", [name[ins[0]], "", "", sizes], [out], mode="linear",
                                          coordinate_transformation_mode=mode))
        elif kind == "MEAN":
            opts = tflite.ReducerOptions()
            o = op.BuiltinOptions()
            opts.Init(o.Bytes, o.Pos)
            nhwc_to_nchw = {0: 0, 1: 2, 2: 3, 3: 1}
            axes = sorted(nhwc_to_nchw[int(a) % 4] for a in np.atleast_1d(consts[ins[1]]))
            if not opts.KeepDims():
                raise ValueError("MEAN without keep_dims is not supported")
            nodes.append(helper.make_node("ReduceMean", [name[ins[0]]], [out], axes=axes, keepdims=1))
        else:
            raise ValueError(f"unsupported TFLite op {kind} (operator {i})")
        nodes.extend(pending)
        pending.clear()

    (inp,), (outp,) = graph.InputsAsNumpy(), graph.OutputsAsNumpy()
    n, h, w, c = shape[int(inp)]
    _, oh, ow, oc = shape[int(outp)]
    # inputs/outputs in NCHW: the graph above already works in NCHW, so the
    # graph input is the TFLite input transposed and the output likewise
    nodes.insert(0, helper.make_node("Identity", ["image"], [name[int(inp)]]))
    nodes.append(helper.make_node("Identity", [name[int(outp)]], ["mask"]))
    g = helper.make_graph(nodes, "person_matte", [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, c, h, w])],
                          [helper.make_tensor_value_info("mask", TensorProto.FLOAT, [1, oc, oh, ow])], inits)
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="tools/convert_selfie_matte.py")
    m.ir_version = 8
    meta = {
        "relight.format": "relight-matte/1",
        "relight.matte.source": f"mediapipe {MEDIAPIPE_VERSION} wheel (PyPI), "
                                f"mediapipe/modules/selfie_segmentation/{tflite_path.name}",
        "relight.matte.source_sha256": hashlib.sha256(data).hexdigest(),
        "relight.matte.version": f"mediapipe {MEDIAPIPE_VERSION}, {tflite_path.stem}, converted to ONNX opset {OPSET}",
        "relight.matte.licence": "Apache-2.0 (Google LLC, MediaPipe)",
        "relight.matte.input_spec": "image [1, 3, H, W] float32, RGB sRGB-encoded in [0, 1]; "
                                    "mask [1, 1, H, W] person probability",
    }
    for k, v in meta.items():
        m.metadata_props.add(key=k, value=v)
    onnx.checker.check_model(m, full_check=True)
    out_path.write_bytes(m.SerializeToString())
    digest = hashlib.sha256(out_path.read_bytes()).hexdigest()
    print(f"wrote {out_path} ({out_path.stat().st_size} bytes, {len(nodes)} nodes), sha256 {digest}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("tflite", type=Path)
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(argv)
    convert(args.tflite, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
