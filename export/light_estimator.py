"""Export the light estimator (model/light_estimator.py) to ONNX and check it against torch.

One input `x` [B, 4, 64, 64] (relight.light_estimate.estimator_input), two outputs `light`
[B, n, 3] and `albedo_mean` [B, 3]; the metadata says what it is, so the runtime's registry and a person can tell it
from a relighting network.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import torch

from export.onnx_export import OPSET, code_version, save_atomic, set_metadata
from relight.light_estimate import INPUT_SIZE
from relight.models import CONVENTION_VERSION

FORMAT = "relight-light-estimator/1"
PARITY_TOLERANCE = 1e-4  # relative to the light's largest coefficient


class _Outputs(torch.nn.Module):
    """The estimator's dict as the graph's two outputs, in order."""

    def __init__(self, net):
        super().__init__()
        self.net = net

    def forward(self, x):
        out = self.net(x)
        return out["light"], out["albedo_mean"]


def export_light_estimator(net, out, training_data: str) -> tuple[Path, str]:
    """Write `out` (.onnx, + .sha256) atomically; returns (path, SHA-256)."""
    import onnx

    net = net.cpu().eval()
    example = torch.zeros(1, 4, INPUT_SIZE, INPUT_SIZE)
    tmp = Path(out).with_suffix(".trace.onnx")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(_Outputs(net), (example,), str(tmp), input_names=["x"],
                          output_names=["light", "albedo_mean"],
                          dynamic_axes={"x": {0: "batch"}, "light": {0: "batch"}, "albedo_mean": {0: "batch"}},
                          opset_version=OPSET, dynamo=False)
    model = onnx.load(str(tmp))
    tmp.unlink()
    set_metadata(model, {
        "relight.format": FORMAT, "relight.conventions": CONVENTION_VERSION,
        "relight.sh_order": str(net.order), "relight.network_config": json.dumps(net.config(), sort_keys=True),
        "relight.input_spec": "x [B, 4, 64, 64] float32: relight.light_estimate.estimator_input; "
                              "outputs light [B, n, 3] (camera frame) and albedo_mean [B, 3]",
        "relight.code_version": code_version(), "relight.training_data": training_data,
    })
    return save_atomic(model, out)


def parity(net, path) -> float:
    """Largest |ONNX - torch| over random inputs and the bundled photo's crop, relative to each
    output's largest |value|."""
    import onnxruntime as ort

    from relight.light_estimate import estimator_input
    from relight.photo import read_photo

    photo = read_photo(Path(__file__).resolve().parent.parent / "relight" / "data" / "examples" / "astronaut.jpg")[0]
    rng = np.random.default_rng(0)
    inputs = [rng.uniform(-1, 1, (2, 4, INPUT_SIZE, INPUT_SIZE)).astype(np.float32),
              estimator_input(photo, np.ones(photo.shape[:2], np.float32))]
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    worst = 0.0
    for x in inputs:
        with torch.no_grad():
            want = net(torch.from_numpy(x))
        for name, got in zip(("light", "albedo_mean"), session.run(["light", "albedo_mean"], {"x": x})):
            ref = want[name].numpy()
            worst = max(worst, float(np.abs(got - ref).max() / max(np.abs(ref).max(), 1e-12)))
    return worst
