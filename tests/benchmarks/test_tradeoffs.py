"""benchmarks/bench_tradeoffs.py: the Pareto front, the SH-order error against known
answers (the analytic data set), and one quick end-to-end run with a random model."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
_spec = importlib.util.spec_from_file_location("bench_tradeoffs", ROOT / "benchmarks" / "bench_tradeoffs.py")
bt = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bt)


# ------------------------------------------------------------------ Pareto front

@pytest.mark.parametrize("points, expected", [
    ([], []),
    ([(5.0, 1.0)], [True]),
    # (3, 4) is slower and worse than (2, 3); the others trade time for error
    ([(1, 5), (2, 3), (3, 4), (4, 1)], [True, True, False, True]),
    # equal time: the lower error wins; equal error: the faster wins
    ([(1, 2), (1, 3)], [True, False]),
    ([(1, 2), (3, 2)], [True, False]),
    # duplicates do not dominate each other: both stay on the front
    ([(1, 1), (1, 1), (2, 2)], [True, True, False]),
    # ... unless a third point beats them in one coordinate and ties in the other
    ([(2, 2), (2, 2), (1, 2)], [False, False, True]),
    # the same point twice far from the rest, and a strictly better point
    ([(3, 3), (3, 3), (1, 1)], [False, False, True]),
    # order of the input does not matter
    ([(4, 1), (3, 4), (2, 3), (1, 5)], [True, False, True, True]),
    # negative errors (e.g. -PSNR) are fine
    ([(10.0, -30.0), (20.0, -31.0), (30.0, -30.5)], [True, True, False]),
])
def test_pareto_front_hand_examples(points, expected):
    times = [p[0] for p in points]
    errors = [p[1] for p in points]
    assert bt.pareto_front(times, errors) == expected


def test_pareto_front_refuses_bad_input():
    with pytest.raises(ValueError, match="equal length"):
        bt.pareto_front([1, 2], [1])
    with pytest.raises(ValueError, match="finite"):
        bt.pareto_front([1, float("nan")], [1, 2])


def test_quality_proposal_follows_the_front():
    rows = [{"total_ms": t, "psnr_interior": p, "front": f, "name": n} for t, p, f, n in [
        (10, 20.0, True, "a"), (20, 25.0, True, "b"), (30, 25.3, True, "c"), (40, 24.0, False, "d")]]
    picks = {r["preset"]: r["name"] for r in bt.propose_quality(rows, balanced_db=0.5)}
    # Balanced: fastest front point within 0.5 dB of the best (25.3): b at 25.0
    assert picks == {"draft": "a", "balanced": "b", "best": "c"}
    assert bt.propose_quality([]) == []


# ------------------------------------------------------------------ inputs and document

def test_models_must_be_named_onnx_files(tmp_path):
    model = tmp_path / "m.onnx"
    model.write_bytes(b"x")
    assert bt.parse_models([f"a={model}"]) == {"a": model}
    for bad, message in ((str(model), "NAME=PATH"), (f"a={tmp_path / 'absent.onnx'}", "not an .onnx"),
                         ("a|b=" + str(model), "markdown")):
        with pytest.raises(ValueError, match=message):
            bt.parse_models([bad])
    with pytest.raises(ValueError, match="twice"):
        bt.parse_models([f"a={model}", f"a={model}"])


def test_sections_replace_their_block_and_keep_the_rest():
    doc = "# Title\n\nkept text\n"
    once = bt.replace_section(doc, "sh", "## SH\n\nfirst\n")
    assert once.startswith(doc.rstrip()) and "first" in once
    twice = bt.replace_section(once, "sh", "## SH\n\nsecond\n")
    assert "first" not in twice and "second" in twice and "kept text" in twice
    assert twice.count("bench_tradeoffs:sh begin") == 1
    both = bt.replace_section(twice, "network", "## Net\n")
    assert both.index("second") < both.index("## Net")
    broken = twice + "<!-- bench_tradeoffs:sh begin -->\n"
    with pytest.raises(ValueError, match="duplicated"):
        bt.replace_section(broken, "sh", "x")


# ------------------------------------------------------------------ SH order: known answers

@pytest.fixture(scope="module")
def analytic(tmp_path_factory):
    from model.samples.synthetic import write_analytic_dataset

    folder = tmp_path_factory.mktemp("analytic")
    write_analytic_dataset(folder, n_scenes=3, size=32, order=4)
    return folder


def test_sh_order_error_matches_the_analytic_answer(analytic):
    from model.samples.synthetic import GLOSS
    from relight.files.dataset import list_finished_scenes, read_scene

    scenes = [read_scene(p) for p in list_finished_scenes(analytic)]
    for s in scenes:
        for k in range(len(s.images)):
            # at the data's own order the truncated render is the scene's own prt pass
            assert np.allclose(bt.prt_image(s, k, 4), s.prt[k], rtol=1e-5, atol=1e-6)
    info, rows = bt.sh_order_points(analytic, (2, 3, 4, 6), repeat=1, timing_pixels=1 << 16)
    assert info["data_order"] == 4 and info["skipped"] == [6]
    by_order = {r["order"]: r for r in rows}
    assert sorted(by_order) == [2, 3, 4]
    # Lambert transport has no band 3 (A_3 = 0): order 3 relights exactly like order 2
    assert by_order[3]["l1_interior"] == pytest.approx(by_order[2]["l1_interior"], rel=1e-6)
    # fully covered pixels of the analytic "path tracer" differ from PRT by GLOSS * (T . L) only
    expected = np.mean([np.mean(GLOSS * s.shading[k][s.alpha[..., 0] > bt.INTERIOR_ALPHA])
                        for s in scenes for k in range(len(s.images))])
    assert by_order[4]["l1_interior"] == pytest.approx(expected, rel=1e-4)
    # truncating to order 2 adds error on top of the gloss
    assert by_order[2]["l1_interior"] > by_order[4]["l1_interior"]
    assert all(r["relight_ms_per_mp"] > 0 for r in rows)
    _assert_front(rows, "relight_ms_per_mp")


def _assert_front(rows, time_key):
    """The rows' front flags are the Pareto front of (time, -PSNR) by brute force: a row
    is on it exactly when no row is at least as fast and as good and better in one."""
    def dominated(r):
        return any(o[time_key] <= r[time_key] and o["psnr_interior"] >= r["psnr_interior"]
                   and (o[time_key] < r[time_key] or o["psnr_interior"] > r["psnr_interior"]) for o in rows)
    assert [r["front"] for r in rows] == [not dominated(r) for r in rows]
    # the fastest and the most accurate rows are always on it
    assert max(rows, key=lambda r: (r["psnr_interior"], -r[time_key]))["front"]
    assert min(rows, key=lambda r: (r[time_key], -r["psnr_interior"]))["front"]


# ------------------------------------------------------------------ end to end

def test_end_to_end_with_a_random_model(analytic, tmp_path):
    from export.random_model import export_random_model

    model, _, _ = export_random_model(tmp_path / "tiny.onnx", seed=5, sh_order=4, width=4, depth=2)
    doc = tmp_path / "TRADEOFFS.md"
    doc.write_text("# Trade-offs\n\nAn existing section that must survive.\n", encoding="utf-8")
    plot = tmp_path / "tradeoffs.png"
    argv = ["--data", str(analytic), "--model", f"tiny={model}", "--sizes", "32,64", "--orders", "2,4",
            "--repeats", "1", "--max-pairs", "3", "--doc", str(doc), "--plot", str(plot)]
    results = bt.run(argv)
    info, rows = results["network"]
    assert [(r["model"], r["working_size"]) for r in rows] == [("tiny", 32), ("tiny", 64)]
    assert info["models"]["tiny"]["training_data"].startswith("none: seeded random")
    for r in rows:
        assert r["decompose_ms"] > 0 and r["relight_ms"] > 0
        assert np.isfinite(r["psnr"]) and np.isfinite(r["psnr_interior"]) and r["l1"] >= 0
    _assert_front(rows, "total_ms")
    text = doc.read_text(encoding="utf-8")
    assert "An existing section that must survive." in text
    assert "Random-weight models (tiny)" in text and text.count("**front**") >= 2
    assert "| 2 | 9 |" in text and "| 4 | 25 |" in text
    from PIL import Image

    with Image.open(plot) as im:
        assert im.format == "PNG" and im.size[0] > im.size[1] > 100
    # a second run replaces its sections instead of adding copies
    bt.run(argv[:-4] + ["--sections", "sh", "--doc", str(doc), "--plot", str(plot)])
    again = doc.read_text(encoding="utf-8")
    assert again.count("bench_tradeoffs:sh begin") == 1 and again.count("bench_tradeoffs:network begin") == 1


def test_command_line_errors_exit_2(analytic, tmp_path, capsys):
    assert bt.main(["--data", str(analytic), "--sections", "nope", "--doc", str(tmp_path / "d.md")]) == 2
    assert "--sections" in capsys.readouterr().err
    assert bt.main(["--sections", "network", "--doc", str(tmp_path / "d.md")]) == 2
    assert "--data" in capsys.readouterr().err
    assert bt.main(["--data", str(analytic), "--sections", "network", "--doc", str(tmp_path / "d.md")]) == 2
    assert "--model" in capsys.readouterr().err
    assert not (tmp_path / "d.md").exists()
    assert json.dumps(bt.int_list("1,2", "--x", 0, 3)) == "[1, 2]"
    with pytest.raises(ValueError, match="distinct"):
        bt.int_list("2,2", "--sizes", 16, 4096)
