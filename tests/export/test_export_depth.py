"""Export of a model with the depth head (issue 45): a sixth output `depth` and the metadata saying
what it is, only when the network has the head; the graph matches torch; the runtime's session
reads it; a model without the head exports exactly the five outputs as before."""

from __future__ import annotations

import json

import numpy as np
import onnx
import pytest

from export.onnx_export import PARITY_TOLERANCE, fp32_parity, onnx_outputs, read_metadata
from export.random_model import export_random_model
from relight.models import DEPTH_METADATA_KEY, OUTPUT_NAMES
from relight.models.session import ModelSession

GEOMETRY = dict(arch="geometry", sh_order=2, width=4, depth=2, decoder_width=4)

pytestmark = [pytest.mark.usefixtures("one_thread"),
              pytest.mark.filterwarnings("ignore::DeprecationWarning")]  # torch's TorchScript exporter


@pytest.mark.parametrize("head", [True, False])
def test_depth_output_and_metadata_only_with_the_head(tmp_path, head):
    config = dict(GEOMETRY, depth_head=True) if head else GEOMETRY
    path, _, net = export_random_model(tmp_path / "m.onnx", seed=5, **config)
    names = [o.name for o in onnx.load(str(path)).graph.output]
    meta = read_metadata(path)
    assert names == list(OUTPUT_NAMES) + (["depth"] if head else [])
    assert (DEPTH_METADATA_KEY in meta) == head
    assert json.loads(meta["relight.network_config"]).get("depth_head", False) == head
    assert fp32_parity(net, path) <= PARITY_TOLERANCE   # every output, depth included
    session = ModelSession(path)
    x = np.random.default_rng(0).uniform(-1, 1, (1, 3, 16, 12)).astype(np.float32)
    out = session.run(x)
    assert set(out) == set(names)
    if head:
        assert json.loads(meta[DEPTH_METADATA_KEY])["output"] == "depth"
        depth = out["depth"][0, 0].astype(np.float64)
        alpha = out["alpha"][0, 0].astype(np.float64)
        assert out["depth"].shape == (1, 1, 16, 12)
        # about the person's own mean: its alpha-weighted mean is 0 (float32 sums of 192 values)
        assert abs((depth * alpha).sum() / alpha.sum()) < 1e-5 * max(1.0, np.abs(depth).max())
        assert np.array_equal(out["depth"], onnx_outputs(path, x)["depth"])
