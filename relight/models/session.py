"""The hash-checked onnxruntime session: how every ONNX file of the project is opened.

`open_session` reads a model file once, compares its SHA-256 with the registry's
entry or the .sha256 file beside it (relight.models) and only then hands the
bytes to onnxruntime, so nothing unchecked is ever loaded; the person matte's
networks use it directly. `ModelSession` adds the checks of a relighting
network (its metadata and its input/output names) and runs it; the runtime's
Relighter and model.scoring.predictor.Predictor both use it.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
from pathlib import Path

import numpy as np

from relight.models import (CONVENTION_VERSION, DEPTH_OUTPUT, INPUT_NAME, ONNX_FORMAT, OUTPUT_NAMES, REGISTRY_PATH,
                            expected_digest, output_names)

__all__ = ["ModelSession", "open_session", "cores_available"]


def cores_available() -> int:
    """CPU cores this process may run on (its affinity mask, not the host's count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


SPINNING_KEY = "session.intra_op.allow_spinning"  # onnxruntime's session option
# network_config "arch"s whose graph sends the residual output as transport * 0 (model.networks.geometry:
# the geometry-first network has no E): the runtime then neither copies nor scans it
ZERO_RESIDUAL_ARCHS = ("geometry",)


def open_session(path: str | os.PathLike, threads: int | None = None, providers: list | None = None,
                 registry_path: str | os.PathLike = REGISTRY_PATH):
    """(onnxruntime session, SHA-256) of a model file whose hash matches its record."""
    import onnxruntime as ort

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"model file not found: {path}")
    want = expected_digest(path, registry_path)
    data = path.read_bytes()  # hash exactly the bytes the session loads
    got = hashlib.sha256(data).hexdigest()
    if got != want:
        raise ValueError(f"{path}: SHA-256 mismatch (file {got[:16]}..., expected {want[:16]}...): "
                         "the model file is corrupt or was modified; refusing to load it")
    cores = cores_available()  # more intra-op threads than cores only slows onnxruntime down
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= cores):
        raise ValueError(f"threads must be an integer in [1, {cores}] (the CPU cores available) or None, "
                         f"got {threads!r}")
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads or 0
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    # no busy-waiting between runs: a run is followed by numpy work (and other sessions: the
    # segmenters'), which the spinning pool threads would take cores from. Measured on 2 cores
    # (docs/TRADEOFFS.md): a 512 px photo's Balanced 145 -> 93 ms; back-to-back runs alike.
    opts.add_session_config_entry(SPINNING_KEY, "0")
    try:
        session = ort.InferenceSession(data, opts, providers=providers or ["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own exception types
        raise ValueError(f"{path}: onnxruntime cannot load it ({exc})") from None
    return session, got


class ModelSession:
    """A relighting network's session: SHA-256 checked, metadata and graph names checked.

    path: the .onnx file; threads: intra-op threads (None: onnxruntime's default,
    all cores); providers: execution providers (default CPU only). Attributes:
    session, sha256, metadata, sh_order, size_multiple, model_path, network_config (the
    metadata's relight.network_config, {} when absent), residual_is_zero (the graph's residual
    output is zero by construction: ZERO_RESIDUAL_ARCHS).
    """

    def __init__(self, path: str | os.PathLike, threads: int | None = None, providers: list | None = None,
                 registry_path: str | os.PathLike = REGISTRY_PATH):
        self.model_path = Path(path)
        self.session, self.sha256 = open_session(self.model_path, threads, providers, registry_path)
        self.metadata = dict(self.session.get_modelmeta().custom_metadata_map)
        # the graph's metadata and signature, checked once here
        md, where = self.metadata, self.model_path
        if md.get("relight.format") != ONNX_FORMAT:
            raise ValueError(f"{where}: not a relighting model (metadata relight.format is "
                             f"{md.get('relight.format')!r}, expected {ONNX_FORMAT!r})")
        if md.get("relight.conventions") != CONVENTION_VERSION:
            raise ValueError(f"{where}: made for conventions {md.get('relight.conventions')!r}, "
                             f"this runtime implements {CONVENTION_VERSION!r}")
        try:
            self.sh_order = int(md["relight.sh_order"])
            self.size_multiple = int(md["relight.size_multiple"])
        except (KeyError, ValueError):
            raise ValueError(f"{where}: metadata lacks a valid relight.sh_order / relight.size_multiple") from None
        try:
            config = json.loads(md.get("relight.network_config") or "{}")
        except ValueError:
            raise ValueError(f"{where}: metadata relight.network_config is not JSON") from None
        self.network_config = config if isinstance(config, dict) else {}
        self.residual_is_zero = self.network_config.get("arch") in ZERO_RESIDUAL_ARCHS
        names = [o.name for o in self.session.get_outputs()]
        self.outputs = output_names(DEPTH_OUTPUT in names)  # + depth: a model with the depth head (issue 45)
        if sorted(names) != sorted(self.outputs) or [i.name for i in self.session.get_inputs()] != [INPUT_NAME]:
            raise ValueError(f"{where}: graph must map {INPUT_NAME!r} to {list(OUTPUT_NAMES)} (and {DEPTH_OUTPUT!r}), "
                             f"has {[i.name for i in self.session.get_inputs()]} -> {names}")

    def output_channels(self, name: str):
        """The channel count (axis 1) the graph declares for output `name` (None when symbolic)."""
        for o in self.session.get_outputs():
            if o.name == name:
                return o.shape[1] if isinstance(o.shape[1], int) else None
        raise KeyError(name)

    residual_is_zero = False  # set from the metadata (__init__)
    outputs = OUTPUT_NAMES  # the graph's outputs in order (__init__: with depth when it has the head)
    run_options = None  # onnxruntime RunOptions every run uses (cancellable: relight.models.session.cancellable)

    def run(self, net_input: np.ndarray, run_options=None) -> dict[str, np.ndarray]:
        """Run the graph on [B, 3, H, W] float32 (H, W multiples of size_multiple), with
        `run_options` or else the session's own (`cancellable`)."""
        feed = {INPUT_NAME: np.ascontiguousarray(net_input, np.float32)}
        values = self.session.run(list(self.outputs), feed, run_options or self.run_options)
        return dict(zip(self.outputs, values))


@contextlib.contextmanager
def cancellable(sessions, run_options):
    """Within the block, every run of `sessions` (ModelSession objects) uses onnxruntime's
    `run_options`, so that `run_options.terminate = True` from another thread stops the run
    in progress (it raises); one job uses a session at a time."""
    sessions = list(sessions)
    for s in sessions:
        s.run_options = run_options
    try:
        yield
    finally:
        for s in sessions:
            s.run_options = None
