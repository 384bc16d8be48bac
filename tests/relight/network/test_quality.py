"""relight/network/quality.py: the one Draft/Balanced/Best table that the CLI, the runtime and the
add-on read, and its model lookup."""

from __future__ import annotations

import json

import numpy as np
import pytest

from relight.person import matte
from relight import models
from relight.network import quality


def test_one_table_feeds_the_runtime_the_cli_and_the_addon():
    from blender_addon.logic import quality as addon_quality
    from relight.cli import build_parser
    from relight.network.runtime import DEFAULT_WORKING_SIZE

    assert [p.key for p in quality.PRESETS] == ["draft", "balanced", "best"]
    assert DEFAULT_WORKING_SIZE == quality.preset(quality.DEFAULT).working_size
    assert [key for key, _, _ in addon_quality.enum_items()] == [p.key.upper() for p in quality.PRESETS]
    assert all(addon_quality.preset(p.key.upper()) is p for p in quality.PRESETS)  # one table
    args = build_parser().parse_args(["image", "x.png", "--light", "studio"])
    assert args.quality == quality.DEFAULT
    assert quality.preset("BEST") is quality.preset("best")
    with pytest.raises(ValueError, match="unknown quality preset 'ultra'; expected one of draft, balanced, best"):
        quality.preset("ultra")


def _network_runs(relighter, photo, mask, **options) -> list[int]:
    """The longest side of each image the network ran on while `relighter` decomposed `photo`."""
    sides, run = [], type(relighter).run_crop
    relighter.run_crop = lambda linear, m: sides.append(max(linear.shape[:2])) or run(relighter, linear, m)
    try:
        relighter.decompose(photo, mask=mask, **options)
    finally:
        del relighter.run_crop
    return sides


def test_each_preset_runs_the_network_as_its_description_says(model):
    """What each preset promises, counted on a photo: Draft the network once at 128 px, Balanced at
    128 px and again on the mirrored crop, Best up to six runs at 144 px (mirrored, and at 0.75x and
    1.25x: 108 and 180 px), two when the mirrored run agrees with the first; the person segmenter
    Draft's quicker one, the others' the ensemble."""
    from relight.network.runtime import Relighter

    rng = np.random.default_rng(0)
    photo = (0.2 + 0.6 * rng.random((300, 200, 3))).astype(np.float32)
    yy, xx = np.mgrid[:300, :200]
    mask = (((yy - 150) / 120.0) ** 2 + ((xx - 100) / 60.0) ** 2 <= 1.0).astype(np.float32)
    relighter = Relighter(model, threads=1)
    runs = {p.key: _network_runs(relighter, photo, mask, **p.decompose_options()) for p in quality.PRESETS}
    assert runs["draft"] == [128]
    assert runs["balanced"] == [128, 128]
    assert runs["best"] in ([144, 144], [144, 144, 180, 180, 108, 108])
    every = _network_runs(relighter, photo, mask, **{**quality.preset("best").decompose_options(),
                                                     "augment_until_agreed": None})
    assert every == [144, 144, 180, 180, 108, 108]
    assert [p.matte_method for p in quality.PRESETS] == ["selfie", "ensemble", "ensemble"]
    assert quality.MATTE_COST_RANK["selfie"] < quality.MATTE_COST_RANK["ensemble"]


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

    from relight.network.runtime import DEFAULT_WORKING_SIZE

    text = (Path(__file__).resolve().parents[3] / "docs" / "runtime.md").read_text(encoding="utf-8")
    assert re.search(r"## Loading: `Relighter\(.*working_size=(\d+)\)`", text).group(1) == str(DEFAULT_WORKING_SIZE)
    stated = re.search(r'`quality.preset\("draft"\).working_size` (\d+), balanced (\d+), best (\d+)', text)
    assert [int(n) for n in stated.groups()] == [quality.preset(k).working_size for k in ("draft", "balanced", "best")]
