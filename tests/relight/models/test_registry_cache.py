"""relight.models.load_registry parses models.json once per file version (issue 39), and a
registry rewritten (register_model) is read again."""

import json

from relight import models


def _registry(tmp_path):
    path = tmp_path / "models.json"
    path.write_text(json.dumps({"format": models.REGISTRY_FORMAT, "default": None, "models": {}}))
    return path


def test_the_registry_is_parsed_once_per_file_version(tmp_path, monkeypatch):
    path = _registry(tmp_path)
    calls = []
    real = json.loads
    monkeypatch.setattr(models.json, "loads", lambda text, *a, **k: calls.append(1) or real(text, *a, **k))
    first = models.load_registry(path)
    assert models.load_registry(path) is first and len(calls) == 1
    model = tmp_path / "m.onnx"
    model.write_bytes(b"x")
    models.register_model("m", model, "0" * 64, {}, registry_path=path)
    assert first["models"] == {}  # the shared parse was not changed: register_model wrote a copy
    again = models.load_registry(path)
    assert again["models"]["m"]["file"] == "m.onnx" and again["default"] == "m"


def test_an_absent_registry_is_empty(tmp_path):
    assert models.load_registry(tmp_path / "none.json")["models"] == {}
