"""benchmarks/studies/study_light_maps.py: the light gap split by seen and unseen maps, and the line over
log2 K that says how many maps would close the gap."""

from __future__ import annotations

import argparse
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("study_light_maps", ROOT / "benchmarks" / "studies" / "study_light_maps.py")
study = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(study)


def _write_run(runs: Path, k: int, gap: float, maps: list[str], seen_pairs: list[dict] | None = None) -> None:
    """A run folder as model.train and model.evaluate leave it, with the numbers given."""
    (runs / f"k{k}").mkdir(parents=True)
    (runs / f"k{k}" / "model.json").write_text(json.dumps({"training": {"light_maps": maps}}))
    pairs = [{"light_a": "venice", "relit_psnr": 20.0 + s, "true_light_psnr": 20.0 + s + gap} for s in (-1.0, 1.0)]
    held = {"methods": {"ours": {"relighting/image": {"psnr": 20.0, "si_psnr": 25.0}}},
            "geometry": {"ours": {"light_colour_deg": 10.0, "relit_level_stops": 0.4}}, "per_pair": pairs}
    (runs / f"eval_k{k}").mkdir()
    (runs / f"eval_k{k}" / "evaluation.json").write_text(json.dumps(held))
    if seen_pairs is not None:
        (runs / f"seen_k{k}").mkdir()
        (runs / f"seen_k{k}" / "evaluation.json").write_text(json.dumps({"per_pair": seen_pairs}))


def test_gap_falls_on_a_line_in_log2_k_and_the_extrapolation_inverts_it(tmp_path):
    # gap = 6 - 1 x log2 K exactly: reaches 2 dB at K = 16
    for k in (2, 4, 8):
        _write_run(tmp_path, k, 6.0 - np.log2(k), ["a"])
    args = argparse.Namespace(runs=str(tmp_path), counts=[2, 4, 8])
    table = study.rows(args)
    assert [r["gap"] for r in table] == pytest.approx([5.0, 4.0, 3.0])
    assert [r["true_light"] for r in table] == pytest.approx([25.0, 24.0, 23.0])
    text = study.report(table)
    assert "6.00 -1.00 x log2 K" in text and "at K = 16 maps (an extrapolation)" in text
    # a gap that does not fall says so instead of extrapolating
    flat = [dict(r, gap=4.0) for r in table]
    assert "more maps alone would not close it" in study.report(flat)


def test_seen_scenes_split_by_whether_the_input_map_was_trained_on(tmp_path):
    seen = [{"light_a": "a", "relit_psnr": 24.0, "true_light_psnr": 25.0},
            {"light_a": "b", "relit_psnr": 20.0, "true_light_psnr": 25.0},
            {"light_a": "c", "relit_psnr": 21.0, "true_light_psnr": 25.0}]
    _write_run(tmp_path, 1, 3.0, ["a"], seen)
    args = argparse.Namespace(runs=str(tmp_path), counts=[1])
    row = study.rows(args)[0]
    assert row["seen_in"] == (pytest.approx(1.0), 1) and row["seen_out"] == (pytest.approx(4.5), 2)
    assert "| 1.00 (1) | 4.50 (2) |" in study.report([row, dict(row, k=2)])


def test_colour_error_regressed_on_the_lights_own_colour_reads_a_grey_estimate_as_slope_one(tmp_path):
    from model.scoring.metrics import colour_cast_deg
    from model.samples.synthetic import write_analytic_dataset
    from relight.files.dataset import light_map_name, read_sidecar

    data = tmp_path / "data"
    write_analytic_dataset(data, n_scenes=3, size=16, order=2, lights=("studio", "sunset", "venice"))
    pairs, own = [], []
    for path in sorted(data.glob("scene_*.json")):
        meta = read_sidecar(path)
        for light in meta["lights"]:
            angle = colour_cast_deg(light["sh"][0], (1.0, 1.0, 1.0))
            own.append(angle)
            # a grey estimate's colour error is the light's own colour, plus a constant 2 degrees here
            pairs.append({"scene": meta["index"], "light_a": light_map_name(light), "light_colour_deg": angle + 2.0})
    assert np.ptp(own) > 1.0  # the lights differ in colour, so the line is determined
    (tmp_path / "eval.json").write_text(json.dumps({"per_pair": pairs}))
    slope, intercept, r, mean = study.colour_against_own_colour(tmp_path / "eval.json", data)
    assert slope == pytest.approx(1.0, abs=1e-9) and intercept == pytest.approx(2.0, abs=1e-8)
    assert r == pytest.approx(1.0, abs=1e-12) and mean == pytest.approx(np.mean(own), rel=1e-12)
