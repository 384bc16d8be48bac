"""Model registry: shipped ONNX files, their SHA-256 and the metadata keys inside them.

`models.json` (beside this file) lists the models that ship with the package:
``{"format": "relight-models/1", "default": NAME | null, "models": {NAME: {...}}}``
where each entry names its ``file`` (relative to this folder), ``sha256`` and
the metadata copied from the ONNX file. `python -m export ... --register NAME`
adds entries. Every ONNX file is loaded only after its SHA-256 matches the one
recorded here or in the ``MODEL.onnx.sha256`` file written next to it.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from relight.files.fileio import atomic_write_text, file_sha256  # file_sha256 is re-exported

REGISTRY_FORMAT = "relight-models/1"
REGISTRY_PATH = Path(__file__).with_name("models.json")

# Version of the conventions (axes, SH basis, colour, network I/O) a graph obeys.
CONVENTION_VERSION = "relight-conventions/1"
# Keys of the ONNX metadata_props that export writes and the runtime reads.
METADATA_KEYS = (
    "relight.format",          # ONNX_FORMAT
    "relight.sh_order",        # int
    "relight.size_multiple",   # int: H and W of the input must be multiples of it
    "relight.conventions",     # CONVENTION_VERSION
    "relight.training_data",   # free text: what the weights were trained on
    "relight.code_version",    # package version (+ git revision when known)
    "relight.input_spec",      # JSON: name, layout, encoding of the input
    "relight.network_config",  # JSON: RelightNet.config()
    "relight.precision",       # "fp32" or "fp16"
)
ONNX_FORMAT = "relight-onnx/1"
OUTPUT_NAMES = ("albedo", "transport", "residual", "light", "alpha")
INPUT_NAME = "image"
# The optional sixth output of a model with a depth head (issue 45): [B, 1, H, W], the person's depth
# along the view axis about its own mean, up to scale; its metadata key says what it is (JSON).
DEPTH_OUTPUT = "depth"
DEPTH_METADATA_KEY = "relight.depth"


def output_names(has_depth: bool) -> tuple[str, ...]:
    """The graph's outputs, in order: the five of every model, then `depth` when it has the head."""
    return OUTPUT_NAMES + ((DEPTH_OUTPUT,) if has_depth else ())


def sidecar_path(model_path: str | os.PathLike) -> Path:
    """Where the `sha256sum`-style hash file of a model lives: MODEL.onnx.sha256."""
    p = Path(model_path)
    return p.with_name(p.name + ".sha256")


def write_sidecar(model_path: str | os.PathLike, digest: str | None = None) -> Path:
    """Write MODEL.onnx.sha256 in `sha256sum` format (so `sha256sum -c` checks it)."""
    digest = digest or file_sha256(model_path)
    out = sidecar_path(model_path)
    atomic_write_text(out, f"{digest}  {Path(model_path).name}\n")
    return out


def read_sidecar(model_path: str | os.PathLike) -> str | None:
    """The hex digest recorded in MODEL.onnx.sha256, or None when there is no such file."""
    p = sidecar_path(model_path)
    if not p.is_file():
        return None
    fields = p.read_text(encoding="utf-8", errors="replace").split()
    if not fields or len(fields[0]) != 64 or any(c not in "0123456789abcdef" for c in fields[0].lower()):
        raise ValueError(f"{p}: not a SHA-256 file (expected '<64 hex digits>  {Path(model_path).name}')")
    return fields[0].lower()


# parsed registries by absolute path: ((mtime_ns, size, inode), data); a file replaced or
# rewritten (atomic_write_text makes a new inode) is parsed again
_PARSED: dict[str, tuple[tuple[int, int, int], dict]] = {}


def load_registry(path: str | os.PathLike = REGISTRY_PATH) -> dict:
    """The parsed registry; an absent file is an empty registry. Parsed once per file version
    (path, modification time, size): the caller gets the shared dict and must not change it
    (register_model changes a copy)."""
    path = Path(path)
    try:
        st = path.stat()
    except OSError:
        st = None
    if st is None or not path.is_file():
        return {"format": REGISTRY_FORMAT, "default": None, "models": {}}
    key, where = (st.st_mtime_ns, st.st_size, st.st_ino), os.path.abspath(path)
    cached = _PARSED.get(where)
    if cached is not None and cached[0] == key:
        return cached[1]
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: unreadable model registry ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != REGISTRY_FORMAT or not isinstance(data.get("models"), dict):
        raise ValueError(f"{path}: not a {REGISTRY_FORMAT} registry")
    _PARSED[where] = (key, data)
    return data


def register_model(name: str, model_path: str | os.PathLike, digest: str, metadata: dict,
                   registry_path: str | os.PathLike = REGISTRY_PATH, make_default: bool = False) -> Path:
    """Record `model_path` (which must sit in the registry's folder) under `name`."""
    registry_path = Path(registry_path)
    model_path = Path(model_path).resolve()
    if model_path.parent != registry_path.resolve().parent:
        raise ValueError(f"a registered model must live beside {registry_path.name} "
                         f"(in {registry_path.parent}), got {model_path}")
    data = json.loads(json.dumps(load_registry(registry_path)))  # a copy: the parsed one is shared
    data["models"][name] = {"file": model_path.name, "sha256": digest, "metadata": metadata}
    if make_default or not data.get("default"):
        data["default"] = name
    atomic_write_text(registry_path, json.dumps(data, indent=2, sort_keys=True) + "\n")
    return registry_path


def registered_digest(model_path: str | os.PathLike, registry_path: str | os.PathLike = REGISTRY_PATH) -> str | None:
    """The registry's SHA-256 for a model file, else None.

    An entry's ``file`` is resolved against the registry's folder, so an entry
    naming an absolute path (or ../) elsewhere is matched too: a model the
    registry lists is checked against the registry's hash wherever it lives,
    never only against a .sha256 file beside it. An entry that matches but
    records no valid SHA-256 is refused.
    """
    registry_path = Path(registry_path)
    model_path = Path(model_path).resolve()
    folder = registry_path.resolve().parent
    for name, entry in load_registry(registry_path)["models"].items():
        file = entry.get("file") if isinstance(entry, dict) else None
        if not isinstance(file, str) or not file or (folder / file).resolve() != model_path:
            continue
        digest = str(entry.get("sha256", "")).lower()
        if len(digest) != 64 or any(c not in "0123456789abcdef" for c in digest):
            raise ValueError(f"{registry_path}: model {name!r} ({file}) records no valid SHA-256")
        return digest
    return None


def default_model_path(registry_path: str | os.PathLike = REGISTRY_PATH) -> Path:
    """Path of the registry's default model; ValueError when none ships."""
    registry_path = Path(registry_path)
    data = load_registry(registry_path)
    name = data.get("default")
    if not name or name not in data["models"]:
        raise ValueError("no relighting model is installed yet: pass --model MODEL.onnx "
                         "(make one with `python -m export WEIGHTS.safetensors --out MODEL.onnx`)")
    return registry_path.parent / data["models"][name]["file"]


def expected_digest(model_path: str | os.PathLike, registry_path: str | os.PathLike = REGISTRY_PATH) -> str:
    """The SHA-256 a model must have: the registry's entry, else its .sha256 sidecar."""
    digest = registered_digest(model_path, registry_path) or read_sidecar(model_path)
    if digest is None:
        raise ValueError(f"{model_path}: no SHA-256 to check it against: expected "
                         f"{sidecar_path(model_path).name} beside it or an entry in {Path(registry_path).name}")
    return digest


def verify_model_file(model_path: str | os.PathLike, registry_path: str | os.PathLike = REGISTRY_PATH) -> str:
    """Check a model file against its recorded SHA-256; return the digest or raise ValueError."""
    p = Path(model_path)
    if not p.is_file():
        raise ValueError(f"model file not found: {p}")
    want = expected_digest(p, registry_path)
    got = file_sha256(p)
    if got != want:
        raise ValueError(f"{p}: SHA-256 mismatch (file {got[:16]}..., expected {want[:16]}...): "
                         "the model file is corrupt or was modified; refusing to load it")
    return got
