"""Convert MediaPipe's person networks (TFLite) to ONNX: the person matte of relight/person/matte.py.

Not run by CI or the tests: the shipped results are relight/models/person_matte_*.onnx,
recorded with their SHA-256 in relight/models/models.json. To reproduce them, in a
scratch virtual environment (never the project's: mediapipe pins numpy<2 and protobuf<5):

    python3 -m venv /tmp/convvenv && /tmp/convvenv/bin/pip install tflite onnx numpy
    pip download --no-deps mediapipe==0.10.21 --python-version 3.11 --only-binary :all: -d /tmp/mp
    unzip -o /tmp/mp/mediapipe-0.10.21-*.whl 'mediapipe/modules/*' -d /tmp/mp
    MP=/tmp/mp/mediapipe/modules; PY=/tmp/convvenv/bin/python
    $PY tools/convert_mediapipe_matte.py $MP/selfie_segmentation/selfie_segmentation.tflite \
        --fp16-weights --out relight/models/person_matte_selfie.onnx
    $PY tools/convert_mediapipe_matte.py $MP/pose_detection/pose_detection.tflite \
        --output Identity:boxes --output Identity_1:scores --signed-input --fp16-weights \
        --out relight/models/person_matte_pose_detector.onnx
    $PY tools/convert_mediapipe_matte.py $MP/pose_landmark/pose_landmark_full.tflite \
        --output Identity_2:mask --sigmoid --fp16-weights \
        --out relight/models/person_matte_pose_segmentation.onnx

The face mesh's landmark network (issue 37's study; it left the tree in issue 49, at commit 6d8d254)
converted the same way: --output conv2d_21:landmarks --output conv2d_31:face_flag --sigmoid-output
face_flag (docs/EVALUATION.md, "The face mesh").

The pose landmark network with its 33 body landmarks too (not shipped; issue 25's skin-probe study
measured a face probe with it: docs/EVALUATION.md): --output Identity_2:mask --output Identity:landmarks
--sigmoid-output mask (within 1.4e-3 of the TFLite reference kernels, landmarks in pixels of
the 256 x 256 input; 29% more time than the mask alone).

The TFLite graph is read with the `tflite` package (flatbuffer accessors) and
rebuilt op by op with onnx.helper, in NCHW, keeping only the operators the
chosen outputs depend on: TFLite weights are transposed, sparse constants
(behind DENSIFY) made dense, fp16 constants (behind DEQUANTIZE) kept as fp16
behind a Cast with --fp16-weights, and MediaPipe's custom op
Convolution2DTransposeBias (which tf2onnx does not convert) becomes
ConvTranspose with its bias. Input `image` [1, 3, H, W] RGB in [0, 1] (sRGB
encoded, as MediaPipe feeds it); 4-D outputs in NCHW. tools/check_matte_onnx.py
compares the results with the TFLite originals on real photos.
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
    values = np.frombuffer(raw, dtypes[tensor.Type()])
    if tensor.Sparsity() is not None:
        return _densify(tflite, tensor.Sparsity(), values, [int(v) for v in tensor.ShapeAsNumpy()])
    return values.reshape(tensor.ShapeAsNumpy())


def _index_vector(tflite, kind: int, table) -> np.ndarray:
    cls = {tflite.SparseIndexVector.Int32Vector: tflite.Int32Vector,
           tflite.SparseIndexVector.Uint16Vector: tflite.Uint16Vector,
           tflite.SparseIndexVector.Uint8Vector: tflite.Uint8Vector}[kind]
    vec = cls()
    vec.Init(table.Bytes, table.Pos)
    return vec.ValuesAsNumpy().astype(np.int64)


def _densify(tflite, sparsity, values: np.ndarray, dense_shape: list[int]) -> np.ndarray:
    """A TFLite sparse constant (the SparsityParameters format: dense and CSR levels in
    traversal order, optional blocks) as a dense array: the walk of TFLite's FormatConverter."""
    order = [int(v) for v in sparsity.TraversalOrderAsNumpy()]
    block_map = [int(v) for v in sparsity.BlockMapAsNumpy()] if sparsity.BlockMapLength() else []
    rank = len(dense_shape)
    levels = []
    block_size = []
    for level in range(sparsity.DimMetadataLength()):
        meta = sparsity.DimMetadata(level)
        if meta.Format() == tflite.DimensionType.DENSE:
            levels.append(("dense", meta.DenseSize(), None, None))
        else:
            levels.append(("csr", None, _index_vector(tflite, meta.ArraySegmentsType(), meta.ArraySegments()),
                           _index_vector(tflite, meta.ArrayIndicesType(), meta.ArrayIndices())))
        if level >= rank:
            block_size.append(meta.DenseSize())
    out = np.zeros(dense_shape, values.dtype)
    cursor = [0]
    idx = [0] * len(levels)

    def walk(level: int, prev: int) -> None:
        if level == len(levels):
            orig = [0] * rank
            for i in range(rank):
                orig[order[i]] = idx[i]
            for i in range(rank, len(levels)):
                b = order[i] - rank
                orig[block_map[b]] = orig[block_map[b]] * block_size[b] + idx[i]
            out[tuple(orig)] = values[cursor[0]]
            cursor[0] += 1
            return
        kind, size, segments, indices = levels[level]
        if kind == "dense":
            for i in range(size):
                idx[level] = i
                walk(level + 1, prev * size + i)
        else:
            for i in range(segments[prev], segments[prev + 1]):
                idx[level] = int(indices[i])
                walk(level + 1, i)

    walk(0, 0)
    if cursor[0] != values.size:
        raise ValueError(f"sparse constant: {cursor[0]} values placed, {values.size} stored")
    return out


def _same_pads(in_hw, k_hw, s_hw, d_hw=(1, 1)):
    """TensorFlow's SAME padding as ONNX pads [top, left, bottom, right] (extra on the end)."""
    before, after = [], []
    for n, k, s, d in zip(in_hw, k_hw, s_hw, d_hw):
        out = -(-n // s)
        total = max((out - 1) * s + (k - 1) * d + 1 - n, 0)
        before.append(total // 2)
        after.append(total - total // 2)
    return before + after


def convert(tflite_path: Path, out_path: Path, outputs_wanted: list[tuple[str, str]] | None = None,
            sigmoid: bool | frozenset = False, signed_input: bool = False, fp16_weights: bool = False) -> None:
    """Write the ONNX graph of the TFLite outputs named in `outputs_wanted` ((TFLite name,
    ONNX name) pairs; default: the only output, as "mask") with only the operators they
    depend on. `sigmoid` turns outputs' logits into probabilities: True for every output,
    or the ONNX names of those it applies to;
    `signed_input` maps the [0, 1] input to the [-1, 1] the network was trained on.
    `fp16_weights` stores weight tensors that were float16 in the TFLite file as float16
    again (each behind a Cast to float32): half the bytes, the same values."""
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
    nodes, inits, casts = [], [], []
    name = {i: f"t{i}" for i in range(len(tensors))}

    def const(value: np.ndarray, label: str) -> str:
        value = np.ascontiguousarray(value)
        if fp16_weights and value.dtype == np.float32 and value.size >= 64 \
                and np.array_equal(value.astype(np.float16).astype(np.float32), value):
            # exactly representable (it came from a float16 constant): stored as such
            inits.append(numpy_helper.from_array(value.astype(np.float16), label + "_f16"))
            casts.append(helper.make_node("Cast", [label + "_f16"], [label], to=TensorProto.FLOAT))
            return label
        inits.append(numpy_helper.from_array(value, label))
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

    by_name = {tensors[int(j)].Name().decode(): int(j) for j in graph.OutputsAsNumpy()}
    if outputs_wanted is None:
        if len(by_name) != 1:
            raise ValueError(f"name the outputs to convert, among {sorted(by_name)}")
        outputs_wanted = [(next(iter(by_name)), "mask")]
    if any(t not in by_name for t, _ in outputs_wanted):
        raise ValueError(f"outputs must be among {sorted(by_name)}")
    producer = {}
    for i in range(graph.OperatorsLength()):
        for j in graph.Operators(i).OutputsAsNumpy():
            producer[int(j)] = i
    needed, stack = set(), [by_name[t] for t, _ in outputs_wanted]
    while stack:  # the operators the chosen output depends on
        t = stack.pop()
        if t in producer and producer[t] not in needed:
            needed.add(producer[t])
            stack.extend(int(j) for j in graph.Operators(producer[t]).InputsAsNumpy() if j >= 0)

    for i in range(graph.OperatorsLength()):
        if i not in needed:
            continue
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
        if kind == "DENSIFY":  # a sparse constant, made dense at conversion time
            consts[outs[0]] = consts[ins[0]]
            continue
        if kind == "RESHAPE":
            # NCHW inside: back to NHWC first, so the flattening order is TFLite's
            src = name[ins[0]]
            if len(shape[ins[0]]) == 4:
                nodes.append(helper.make_node("Transpose", [src], [out + "_nhwc"], perm=[0, 2, 3, 1]))
                src = out + "_nhwc"
            target = np.array(shape[outs[0]], np.int64)
            if len(target) == 4:
                raise ValueError("RESHAPE to 4-D is not supported")
            nodes.append(helper.make_node("Reshape", [src, const(target, out + "_shape")], [out]))
            continue
        if kind == "CONCATENATION":
            opts = tflite.ConcatenationOptions()
            o = op.BuiltinOptions()
            opts.Init(o.Bytes, o.Pos)
            rank = len(shape[outs[0]])
            axis = opts.Axis() % rank
            if rank == 4:
                axis = {0: 0, 1: 2, 2: 3, 3: 1}[axis]
            target = activation(out, opts.FusedActivationFunction())
            nodes.append(helper.make_node("Concat", [name[j] for j in ins], [target], axis=axis))
            nodes.extend(pending)
            pending.clear()
            continue
        if kind == "DEPTH_TO_SPACE":
            opts = tflite.DepthToSpaceOptions()
            o = op.BuiltinOptions()
            opts.Init(o.Bytes, o.Pos)
            # TFLite's NHWC channel order (i * bs + j) * C + c is ONNX's DCR mode
            nodes.append(helper.make_node("DepthToSpace", [name[ins[0]]], [out], blocksize=opts.BlockSize(),
                                          mode="DCR"))
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
        elif kind in ("AVERAGE_POOL_2D", "MAX_POOL_2D"):
            opts = tflite.Pool2DOptions()
            o = op.BuiltinOptions()
            opts.Init(o.Bytes, o.Pos)
            _, h, wd, _ = shape[ins[0]]
            k = [opts.FilterHeight(), opts.FilterWidth()]
            s = [opts.StrideH(), opts.StrideW()]
            pads = _same_pads((h, wd), k, s) if opts.Padding() == tflite.Padding.SAME else [0, 0, 0, 0]
            target = activation(out, opts.FusedActivationFunction())
            if kind == "MAX_POOL_2D":  # ONNX's MaxPool, like TFLite's, never takes a padded value
                nodes.append(helper.make_node("MaxPool", [name[ins[0]]], [target], kernel_shape=k, strides=s,
                                              pads=pads))
            else:  # TFLite averages over the valid pixels only
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
        elif kind == "PRELU":  # the face landmark model's; slope per channel, NHWC [1, 1, C] -> [C, 1, 1]
            slope = consts[ins[1]].astype(np.float32)
            if slope.size != shape[ins[0]][-1]:
                raise ValueError(f"PRELU slope of shape {slope.shape} is not per channel (operator {i})")
            nodes.append(helper.make_node("PRelu", [name[ins[0]], const(slope.reshape(-1, 1, 1), out + "_slope")],
                                          [out]))
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
        elif kind == "PAD":
            pads = consts[ins[1]].astype(np.int64)                   # [4, 2] NHWC (before, after)
            order = [0, 3, 1, 2]
            onnx_pads = [int(pads[a, 0]) for a in order] + [int(pads[a, 1]) for a in order]
            nodes.append(helper.make_node("Pad", [name[ins[0]], const(np.array(onnx_pads, np.int64), out + "_pads")],
                                          [out], mode="constant"))
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

    (inp,) = graph.InputsAsNumpy()
    n, h, w, c = shape[int(inp)]
    # the graph above works in NCHW: the input is the TFLite input transposed, 4-D outputs likewise
    if signed_input:
        nodes[:0] = [helper.make_node("Mul", ["image", const(np.float32(2), "in_scale")], ["image_x2"]),
                     helper.make_node("Sub", ["image_x2", const(np.float32(1), "in_one")], [name[int(inp)]])]
    else:
        nodes.insert(0, helper.make_node("Identity", ["image"], [name[int(inp)]]))
    nodes[:0] = casts
    graph_outputs = []
    sigmoid_names = {o for _, o in outputs_wanted} if sigmoid is True else set(sigmoid or ())
    for tfl_name, onnx_name in outputs_wanted:
        t = by_name[tfl_name]
        dims = shape[t] if len(shape[t]) != 4 else [shape[t][0], shape[t][3], shape[t][1], shape[t][2]]
        nodes.append(helper.make_node("Sigmoid" if onnx_name in sigmoid_names else "Identity", [name[t]],
                                      [onnx_name]))
        graph_outputs.append(helper.make_tensor_value_info(onnx_name, TensorProto.FLOAT, dims))
    g = helper.make_graph(nodes, "person_matte", [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, c, h, w])],
                          graph_outputs, inits)
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="tools/convert_mediapipe_matte.py")
    m.ir_version = 8
    meta = {
        "relight.format": "relight-matte/1",
        "relight.matte.source": f"mediapipe {MEDIAPIPE_VERSION} wheel (PyPI), "
                                f"mediapipe/modules/{tflite_path.parent.name}/{tflite_path.name}"
                                + ", outputs " + ", ".join(f"{t} as {o}" for t, o in outputs_wanted),
        "relight.matte.source_sha256": hashlib.sha256(data).hexdigest(),
        "relight.matte.version": f"mediapipe {MEDIAPIPE_VERSION}, {tflite_path.stem}, converted to ONNX opset {OPSET}",
        "relight.matte.licence": "Apache-2.0 (Google LLC, MediaPipe)",
        "relight.matte.input_spec": "image [1, 3, H, W] float32, RGB sRGB-encoded in [0, 1]; outputs "
                                    + ", ".join(o + (" (probabilities)" if o in sigmoid_names else "")
                                                for _, o in outputs_wanted),
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
    p.add_argument("--output", action="append", default=None, metavar="TFLITE_NAME:ONNX_NAME",
                   help="a TFLite output to convert and its ONNX name (repeatable; default: the only one, as mask)")
    p.add_argument("--sigmoid", action="store_true", help="the outputs are logits: end with a Sigmoid")
    p.add_argument("--sigmoid-output", action="append", default=None, metavar="ONNX_NAME",
                   help="only this output is logits (repeatable): end it with a Sigmoid")
    p.add_argument("--signed-input", action="store_true", help="the network takes [-1, 1]: map [0, 1] to it")
    p.add_argument("--fp16-weights", action="store_true", help="keep float16 weights as float16 (exact, half size)")
    args = p.parse_args(argv)
    wanted = None if args.output is None else [tuple(o.split(":", 1)) for o in args.output]
    sigmoid = True if args.sigmoid else frozenset(args.sigmoid_output or ())
    convert(args.tflite, args.out, wanted, sigmoid, args.signed_input, args.fp16_weights)
    return 0


if __name__ == "__main__":
    sys.exit(main())
