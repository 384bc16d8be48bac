"""relight/quality.py: the one Draft/Balanced/Best table that the CLI, the runtime and the
add-on read, and its model lookup."""

from __future__ import annotations

import json

import pytest

from relight import matte, models, quality


def test_one_table_feeds_the_runtime_the_cli_and_the_addon():
    from blender_addon import quality as addon_quality
    from relight.cli import build_parser
    from relight.runtime import DEFAULT_WORKING_SIZE

    keys = [p.key for p in quality.PRESETS]
    # fastest first: each preset does at least the work of the one before in every part, and more in one
    work = [p.work() for p in quality.PRESETS]
    assert keys == ["draft", "balanced", "best"] and len(set(work)) == 3
    assert all(all(x <= y for x, y in zip(a, b)) for a, b in zip(work, work[1:]))
    assert DEFAULT_WORKING_SIZE == quality.preset(quality.DEFAULT).working_size
    assert [key for key, _, _ in addon_quality.enum_items()] == [p.key.upper() for p in quality.PRESETS]
    assert all(addon_quality.preset(p.key.upper()) is p for p in quality.PRESETS)  # one table
    args = build_parser().parse_args(["image", "x.png", "--light", "studio"])
    assert args.quality == quality.DEFAULT
    assert quality.preset("BEST") is quality.preset("best")
    with pytest.raises(ValueError, match="unknown quality preset 'ultra'; expected one of draft, balanced, best"):
        quality.preset("ultra")


def test_every_segmenter_method_has_a_cost_rank():
    assert set(quality.MATTE_COST_RANK) == set(matte.METHODS)


def _registry(tmp_path, default, names):
    path = tmp_path / "models.json"
    entries = {n: {"file": f"{n}.onnx", "sha256": "0" * 64} for n in names}
    path.write_text(json.dumps({"format": models.REGISTRY_FORMAT, "default": default, "models": entries}))
    return path


def test_model_lookup_prefers_the_presets_model_then_the_default(tmp_path, monkeypatch):
    # best names its own model, draft none (the registry's default)
    monkeypatch.setattr(quality, "PRESETS", tuple(
        quality.QualityPreset(p.key, p.label, "big" if p.key == "best" else None, p.working_size, p.description)
        for p in quality.PRESETS))
    assert quality.preset("best").model == "big" and quality.preset("draft").model is None
    registry = models.load_registry(_registry(tmp_path, "base", ["base", "big"]))
    assert quality.model_name("best", registry) == "big"
    assert quality.model_name("draft", registry) == "base"
    registry = models.load_registry(_registry(tmp_path, "base", ["base"]))  # "big" not installed
    assert quality.model_name("best", registry) == "base"
    path = _registry(tmp_path, None, [])
    assert quality.model_name("best", models.load_registry(path)) is None
    with pytest.raises(ValueError, match="no relighting model is installed yet"):
        quality.model_path("best", path)
    path = _registry(tmp_path, "base", ["base", "big"])
    assert quality.model_path("best", path) == tmp_path / "big.onnx"


def test_shipped_presets_name_registered_models():
    """Every preset's model is in the shipped registry (else it would silently fall back)."""
    registry = models.load_registry(models.REGISTRY_PATH)
    for p in quality.PRESETS:
        assert p.model is None or p.model in registry["models"], p
        assert quality.model_path(p.key).is_file()


def test_docs_runtime_states_the_working_sizes_the_code_has():
    """Issue 40: docs/runtime.md said 512 by default and presets 96/128/128."""
    import re
    from pathlib import Path

    from relight.runtime import DEFAULT_WORKING_SIZE

    text = (Path(__file__).resolve().parents[1] / "docs" / "runtime.md").read_text(encoding="utf-8")
    assert re.search(r"## Loading: `Relighter\(.*working_size=(\d+)\)`", text).group(1) == str(DEFAULT_WORKING_SIZE)
    stated = re.search(r'`quality.preset\("draft"\).working_size` (\d+), balanced (\d+), best (\d+)', text)
    assert [int(n) for n in stated.groups()] == [quality.preset(k).working_size for k in ("draft", "balanced", "best")]
