"""Export a RelightNet to ONNX and check it against torch.

The graph has one input, `image` [B, 3, H, W] float32 in [-1, 1], and exactly
the five outputs of docs/ARCHITECTURE.md (albedo, transport, residual, light,
alpha), plus `depth` [B, 1, H, W] when the network has the depth head (issue 45; the metadata's
relight.depth then says what it is); the positive/negative parts are folded inside (T = T+ - |T-|). Batch,
height and width are dynamic; H and W must be multiples of `size_multiple`,
which the metadata records.
"""

from __future__ import annotations

import json
import os
import subprocess
import warnings
from pathlib import Path

import numpy as np
import onnx
import torch

import relight
from relight.models import (CONVENTION_VERSION, DEPTH_METADATA_KEY, INPUT_NAME, ONNX_FORMAT,
                            file_sha256, output_names, write_sidecar)

OPSET = 17
DEFAULT_TRAINING_DATA = "unspecified (weights not trained by this package's pipeline)"
PARITY_TOLERANCE = 1e-4  # fp32 torch vs onnxruntime: summation order only (tests/export/test_export.py derives it)
REAL_PHOTO = Path(__file__).resolve().parent.parent / "relight" / "data" / "examples" / "astronaut.jpg"


def graph_outputs(net) -> tuple[str, ...]:
    """The outputs the graph of `net` has: the five runtime ones, and depth with the depth head."""
    return output_names(bool(getattr(net, "depth_head", False)))


class _FiveOutputs(torch.nn.Module):
    """Wraps RelightNet so the traced graph returns only the runtime outputs (graph_outputs)."""

    def __init__(self, net: torch.nn.Module):
        super().__init__()
        self.net = net
        self.names = graph_outputs(net)

    def forward(self, image: torch.Tensor):
        out = self.net(image)
        return tuple(out[name] for name in self.names)


def code_version() -> str:
    """Package version, plus the git revision when the source tree is a checkout."""
    version = relight.__version__
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=Path(__file__).parent,
                             capture_output=True, text=True, timeout=5)
        if rev.returncode == 0 and rev.stdout.strip():
            version += "+g" + rev.stdout.strip()
    except (OSError, subprocess.SubprocessError):
        pass
    return version


def build_metadata(net, training_data: str = DEFAULT_TRAINING_DATA, precision: str = "fp32") -> dict[str, str]:
    """The metadata_props written into every exported graph (all values strings)."""
    input_spec = {
        "name": INPUT_NAME, "shape": ["batch", 3, "height", "width"], "dtype": "float32",
        "encoding": "linear photo -> clip [0,1] -> sRGB encode -> x*2-1, times the mask if any",
        "height_width_multiple_of": int(net.size_multiple),
        "outputs": {"albedo": "[B,3,H,W] linear, [0,1]", "transport": "[B,n,H,W]",
                    "residual": "[B,n,H,W]", "light": "[B,n,3]", "alpha": "[B,1,H,W] in [0,1]"},
    }
    metadata = {
        "relight.format": ONNX_FORMAT,
        "relight.sh_order": str(int(net.sh_order)),
        "relight.size_multiple": str(int(net.size_multiple)),
        "relight.conventions": CONVENTION_VERSION,
        "relight.training_data": str(training_data),
        "relight.code_version": code_version(),
        "relight.input_spec": json.dumps(input_spec, sort_keys=True),
        "relight.network_config": json.dumps(net.config(), sort_keys=True),
        "relight.precision": precision,
    }
    if getattr(net, "depth_head", False):  # models without it keep their metadata as it was
        input_spec["outputs"]["depth"] = "[B,1,H,W] the person's depth about its mean, up to scale"
        metadata["relight.input_spec"] = json.dumps(input_spec, sort_keys=True)
        metadata[DEPTH_METADATA_KEY] = json.dumps({
            "output": "depth", "axis": "camera +Y (larger is farther)", "offset": "the alpha-weighted mean is 0",
            "scale": "arbitrary: trained scale-and-shift-invariant (model.networks.depth_loss); the runtime "
                     "scales it to the normals' slopes (relight.geometry.relief.scaled_to_normals)"},
            sort_keys=True)
    return metadata


def set_metadata(model: onnx.ModelProto, metadata: dict[str, str]) -> None:
    """Replace the graph's metadata_props with `metadata`."""
    del model.metadata_props[:]
    for key, value in sorted(metadata.items()):
        entry = model.metadata_props.add()
        entry.key, entry.value = key, str(value)


def read_metadata(model: onnx.ModelProto | str | os.PathLike) -> dict[str, str]:
    """metadata_props of an ONNX model (or file) as a dict."""
    if not isinstance(model, onnx.ModelProto):
        model = onnx.load(str(model), load_external_data=False)
    return {p.key: p.value for p in model.metadata_props}


def save_atomic(model: onnx.ModelProto, out: str | os.PathLike) -> tuple[Path, str]:
    """Check and write `model` to `out` atomically, then MODEL.onnx.sha256; returns (path, sha256)."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    onnx.checker.check_model(model, full_check=True)
    from relight.files.fileio import atomic_path

    with atomic_path(out) as tmp:
        tmp.write_bytes(model.SerializeToString())
    digest = file_sha256(out)
    write_sidecar(out, digest)
    return out, digest


def export_onnx(net, out: str | os.PathLike, training_data: str = DEFAULT_TRAINING_DATA,
                example_size: tuple[int, int] | None = None) -> tuple[Path, str]:
    """Trace `net` (a RelightNet) to an opset-17 ONNX file at `out`; returns (path, sha256).

    The network is put in eval mode first: tracing a module in training mode
    would run BatchNorm in batch-statistics mode and update its running stats.
    """
    net = net.eval()
    m = int(net.size_multiple)
    h, w = example_size or (2 * m, 3 * m)  # unequal sides so no axis is mistaken for another
    example = torch.zeros(1, 3, h, w)
    dyn = {"batch": 0, "height": 2, "width": 3}
    dynamic_axes = {INPUT_NAME: {0: "batch", 2: "height", 3: "width"}}
    names = graph_outputs(net)
    for name in names:
        dynamic_axes[name] = {0: "batch"} if name == "light" else {v: k for k, v in dyn.items()}
    before = {k: v.clone() for k, v in net.state_dict().items()}
    tmp = Path(out).with_name(f".{Path(out).name}.{os.getpid()}.trace.tmp")
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    try:
        with warnings.catch_warnings(), torch.no_grad():
            # the TorchScript exporter is deprecated but needs no onnxscript and
            # gives a plain graph of the network's few op types
            warnings.simplefilter("ignore", DeprecationWarning)
            torch.onnx.export(_FiveOutputs(net).eval(), (example,), str(tmp), dynamo=False,
                              opset_version=OPSET, input_names=[INPUT_NAME],
                              output_names=list(names), dynamic_axes=dynamic_axes,
                              do_constant_folding=True)
        model = onnx.load(str(tmp))
    finally:
        if tmp.exists():
            tmp.unlink()
    for k, v in net.state_dict().items():
        if not torch.equal(v, before[k]):
            raise RuntimeError(f"export changed network state {k}; refusing to write a mismatched graph")
    set_metadata(model, build_metadata(net, training_data, "fp32"))
    return save_atomic(model, out)


def torch_outputs(net, image: np.ndarray) -> dict[str, np.ndarray]:
    """The network's graph outputs (graph_outputs) in torch, for parity checks."""
    with torch.no_grad():
        out = net.eval()(torch.from_numpy(np.ascontiguousarray(image, dtype=np.float32)))
    return {k: out[k].numpy() for k in graph_outputs(net)}


def onnx_outputs(model_path: str | os.PathLike, image: np.ndarray) -> dict[str, np.ndarray]:
    """The graph's outputs from onnxruntime (CPU, one thread: deterministic): the five, and depth
    when the graph has it."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    sess = ort.InferenceSession(str(model_path), opts, providers=["CPUExecutionProvider"])
    names = [o.name for o in sess.get_outputs()]
    values = sess.run(names, {INPUT_NAME: np.ascontiguousarray(image, dtype=np.float32)})
    return dict(zip(names, values))


def max_abs_diff(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> dict[str, float]:
    """Per-output max |a - b| (shapes must agree)."""
    out = {}
    if set(a) != set(b):
        raise ValueError(f"outputs differ: {sorted(a)} != {sorted(b)}")
    for k in a:
        if a[k].shape != b[k].shape:
            raise ValueError(f"output {k}: shape {a[k].shape} != {b[k].shape}")
        out[k] = float(np.max(np.abs(a[k].astype(np.float64) - b[k].astype(np.float64))))
    return out


def _real_input(size_multiple: int) -> np.ndarray:
    """The bundled example photo as the network sees it (relight.network.prt.to_network_input), cropped
    to a multiple of size_multiple: parity on a real image, not only on noise."""
    from relight.files.photo import read_photo
    from relight.network.prt import to_network_input

    linear = read_photo(REAL_PHOTO)[0]
    h, w = (d - d % size_multiple for d in linear.shape[:2])
    return to_network_input(linear[:h, :w]).transpose(2, 0, 1)[None].astype(np.float32)


def parity_inputs(size_multiple: int, seed: int = 0) -> list[np.ndarray]:
    """Two noise batches of unequal sides and the bundled photo: what torch-vs-graph checks run on."""
    rng = np.random.default_rng(seed)
    m = size_multiple
    return [rng.uniform(-1, 1, (1, 3, 4 * m, 3 * m)).astype(np.float32),
            rng.uniform(-1, 1, (2, 3, 2 * m, 5 * m)).astype(np.float32),
            _real_input(m)]


def fp32_parity(net, model_path: str | os.PathLike) -> float:
    """Max |torch - onnxruntime| over the outputs and parity_inputs, each output's in units of its own
    size max(1, max |torch value|): compare with PARITY_TOLERANCE. Rounding grows with a value's size,
    and the light (a least-squares solve) reaches 8 on the noise inputs, where albedo, alpha and
    transport stay within 1 (their differences count as they are)."""
    worst = 0.0
    for x in parity_inputs(int(net.size_multiple)):
        ours = torch_outputs(net, x)
        diff = max_abs_diff(ours, onnx_outputs(model_path, x))
        worst = max(worst, max(d / max(1.0, float(np.max(np.abs(ours[k])))) for k, d in diff.items()))
    return worst
