"""model.compare_sets: two evaluated sets compared per framing, the numbers worked out by hand."""

import json
import math

import numpy as np
import pytest

from model import compare_sets, evaluate

NAN = float("nan")
T95 = {1: 6.313752, 2: 2.919986}   # Student's t, one-sided 95 %, by degrees of freedom


def _write(folder, pairs, seed=7):
    """An evaluation.json as model.evaluate writes it (the keys compare_sets reads) in folder/eval:
    pairs are (index, framing, a, b, relit, matched, slope, correlation)."""
    per_pair = [{"scene": s, "light_a": f"l{a}", "light_b": f"l{b}", "framing": framing, "seed": seed,
                 "relit_psnr": relit, "matched_photo_psnr": matched, "light_slope": slope,
                 "light_correlation": corr} for s, framing, a, b, relit, matched, slope, corr in pairs]
    out = folder / "eval"
    out.mkdir(parents=True)
    (out / "evaluation.json").write_text(json.dumps(
        {"pairs": len(pairs), "pair_list": [[s, a, b] for s, _, a, b, *_ in pairs], "per_pair": per_pair}))
    return folder


HS, FB = "head-and-shoulders", "full-body"
FIRST = [(0, HS, 0, 1, 20.0, 18.0, 0.4, 0.6), (0, HS, 1, 0, 22.0, 19.0, NAN, NAN),
         (1, FB, 0, 1, 25.0, 20.0, 0.2, 0.3), (1, FB, 1, 0, 27.0, 24.0, 0.4, 0.5),
         (2, HS, 0, 1, 24.0, 21.0, 0.1, 0.2), (2, HS, 1, 0, 26.0, 22.0, 0.3, 0.4),
         (5, FB, 0, 1, 30.0, 25.0, 0.5, 0.5)]                                # scene 5: the first set's only
SECOND = [(0, HS, 0, 1, 19.0, 18.5, 0.3, 0.5), (0, HS, 1, 0, 20.0, 18.0, 0.1, 0.2),
          (1, FB, 0, 1, 26.0, 21.0, 0.2, 0.2), (1, FB, 1, 0, 27.0, 23.0, 0.2, 0.4),
          (1, FB, 2, 0, 24.0, 22.0, 0.2, 0.4),                               # lights the first set's scene 1 lacks
          (2, HS, 0, 1, 21.0, 20.0, 0.1, 0.1), (2, HS, 1, 0, 23.0, 20.0, 0.1, 0.1),
          (3, FB, 0, 1, 28.0, 26.0, 0.2, 0.2)]                               # scene 3: the second set's only


def test_the_table_is_the_hand_computed_means_differences_and_bounds(tmp_path, capsys):
    a, b = _write(tmp_path / "a", FIRST), _write(tmp_path / "b", SECOND)
    first = compare_sets.set_summary(compare_sets.read_pairs(a))
    # means over the pairs; slope and correlation leave the NaN pair (no true change) out
    assert first[HS] == pytest.approx({"scenes": 2, "pairs": 4, "relit": 23.0, "matched": 20.0, "gain": 3.0,
                                       "slope": 0.8 / 3, "correlation": 0.4})
    assert first[FB] == pytest.approx({"scenes": 2, "pairs": 3, "relit": 82 / 3, "matched": 23.0, "gain": 82 / 3 - 23,
                                       "slope": 1.1 / 3, "correlation": 1.3 / 3})
    assert first["all"]["pairs"] == 7 and first["all"]["relit"] == pytest.approx(174 / 7)

    result = compare_sets.compare(compare_sets.read_pairs(a), compare_sets.read_pairs(b))
    # per paired scene, the mean over its shared pairs of second - first:
    # scene 0: relit (-1, -2) -> -1.5, gain ((0.5 - 2), (2 - 3)) -> -1.25; scene 1: (1, 0) -> 0.5, (0, 1) -> 0.5;
    # scene 2: (-3, -3) -> -3, ((1 - 3), (3 - 4)) -> -1.5
    hs = result["rows"][HS]["relit"]
    assert hs["n"] == 2 and hs["mean"] == pytest.approx(-2.25) and hs["se"] == pytest.approx(0.75)
    assert hs["bound"] == pytest.approx(-2.25 - T95[1] * 0.75, abs=1e-5)
    assert result["rows"][HS]["gain"]["mean"] == pytest.approx(-1.375)
    assert result["rows"][HS]["gain"]["se"] == pytest.approx(0.125)
    fb = result["rows"][FB]["relit"]
    assert fb["n"] == 1 and fb["mean"] == pytest.approx(0.5) and math.isnan(fb["bound"])
    every = result["rows"]["all"]["relit"]
    d = np.array([-1.5, 0.5, -3.0])
    se = math.sqrt(((d - d.mean()) ** 2).sum() / 2 / 3)
    assert every["n"] == 3 and every["mean"] == pytest.approx(-4 / 3) and every["se"] == pytest.approx(se)
    assert every["bound"] == pytest.approx(-4 / 3 - T95[2] * se, abs=1e-5)
    assert result["rows"]["all"]["gain"]["mean"] == pytest.approx(-0.75)
    # what could not be paired is reported, not dropped
    assert result["only_first"] == [(7, 5)] and result["only_second"] == [(7, 3)]
    assert result["unmatched_pairs"] == 1 and result["reframed"] == []

    assert compare_sets.main([str(a), str(b), "--labels", "familiar", "unfamiliar"]) == 0
    out = capsys.readouterr().out
    assert f"| familiar | {HS} | 2 | 4 | 23.00 | 20.00 | +3.00 | 0.27 | 0.40 |" in out
    assert f"| {HS} | 2 | -2.25 +- 0.75 | {-2.25 - T95[1] * 0.75:+.2f} | no | -1.38 +- " in out
    assert f"| {FB} | 1 | +0.50 +- - | - | - |" in out
    assert f"| all | 3 | -1.33 +- {se:.2f} | {-4 / 3 - T95[2] * se:+.2f} | no |" in out
    assert "1 scenes of familiar only (seed:index), not paired: 7:5" in out
    assert "1 scenes of unfamiliar only (seed:index), not paired: 7:3" in out
    assert "1 pairs of paired scenes have lights the other set's scene lacks" in out
    # a wider margin turns the verdict
    assert compare_sets.main([str(a), str(b), "--margin", "20"]) == 0
    assert f"| {HS} | 2 | -2.25 +- 0.75 | {-2.25 - T95[1] * 0.75:+.2f} | yes |" in capsys.readouterr().out


def test_sets_without_a_shared_seed_get_welchs_unpaired_difference(tmp_path):
    """Per-scene means second (21, 23) and first (20, 24): difference 0, s.e. sqrt(1 + 4),
    Welch's degrees of freedom 25 / 17; every scene is listed as unpaired."""
    a = _write(tmp_path / "a", [(0, HS, 0, 1, 20.0, 19.0, 0.1, 0.1), (1, HS, 0, 1, 24.0, 19.0, 0.1, 0.1)], seed=1)
    b = _write(tmp_path / "b", [(0, HS, 0, 1, 21.0, 19.0, 0.1, 0.1), (1, HS, 0, 1, 23.0, 20.0, 0.1, 0.1)], seed=2)
    result = compare_sets.compare(compare_sets.read_pairs(a), compare_sets.read_pairs(b))
    relit = result["rows"][HS]["relit"]
    assert not relit["paired"] and relit["mean"] == pytest.approx(0.0) and relit["se"] == pytest.approx(math.sqrt(5))
    assert relit["bound"] == pytest.approx(-3.779831 * math.sqrt(5), abs=1e-5)   # t(0.95, 25/17)
    assert result["rows"][HS]["gain"]["mean"] == pytest.approx(((2 + 3) - (1 + 5)) / 2)
    assert result["only_first"] == [(1, 0), (1, 1)] and result["only_second"] == [(2, 0), (2, 1)]


def _one_error_line(capsys, argv) -> str:
    assert compare_sets.main(argv) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and len(captured.err.strip().splitlines()) == 1
    return captured.err


def test_a_missing_damaged_or_older_evaluation_is_one_line_naming_it_and_exit_2(tmp_path, capsys):
    good = _write(tmp_path / "good", FIRST)
    (tmp_path / "empty").mkdir()
    assert str(tmp_path / "empty" / "evaluation.json") in _one_error_line(capsys, [str(tmp_path / "empty"), str(good)])

    damaged = _write(tmp_path / "damaged", FIRST) / "eval" / "evaluation.json"
    damaged.write_text(damaged.read_text()[:100])
    assert f"{damaged}: not a readable evaluation.json" in _one_error_line(capsys, [str(good), str(damaged.parent)])

    older = _write(tmp_path / "older", FIRST) / "eval" / "evaluation.json"
    record = json.loads(older.read_text())
    for p in record["per_pair"]:
        del p["matched_photo_psnr"]
    older.write_text(json.dumps(record))
    assert f"{older}: pair 0 has no seed or matched_photo_psnr" in _one_error_line(capsys, [str(older), str(good)])

    broken = _write(tmp_path / "broken", FIRST) / "eval" / "evaluation.json"
    record = json.loads(broken.read_text())
    record["per_pair"][3]["relit_psnr"] = "high"
    broken.write_text(json.dumps(record))
    assert f"{broken}: pair 3 has no valid relit_psnr" in _one_error_line(capsys, [str(good), str(broken)])


def test_on_model_evaluates_output_the_set_means_are_its_table(tmp_path, capsys, one_thread):
    """model.evaluate records each pair's seed and exposure-matched PSNR: the command's set means are the
    evaluation's own table (ours, identity exposure-matched, light response), and a set against itself
    differs by 0 +- 0."""
    from export.random_model import random_relightnet
    from model.samples.synthetic import write_analytic_dataset
    from model.training.checkpoint import save_model

    data = tmp_path / "data"
    write_analytic_dataset(data, n_scenes=2, size=32, order=4, lights=("studio", "city", "venice"), seed=3)
    model = save_model(random_relightnet(1, sh_order=4, width=4, depth=2), tmp_path / "m" / "model.safetensors")
    evaluate.evaluate(model, data, data / "eval", size=32, sheet_rows=1)
    record = json.loads((data / "eval" / "evaluation.json").read_text())
    assert {p["seed"] for p in record["per_pair"]} == {3}
    summary = compare_sets.set_summary(compare_sets.read_pairs(data))["all"]
    assert summary["pairs"] == record["pairs"]
    assert summary["relit"] == pytest.approx(record["methods"]["ours"]["relighting/image"]["psnr"], rel=1e-12)
    matched = record["methods"]["identity, exposure-matched"]["relighting/image"]["psnr"]
    assert summary["matched"] == pytest.approx(matched, rel=1e-12)
    response = record["light_response"]["ours"]["-"]
    assert summary["slope"] == pytest.approx(response["slope"], rel=1e-12)
    assert summary["correlation"] == pytest.approx(response["correlation"], rel=1e-12)
    result = compare_sets.compare(compare_sets.read_pairs(data), compare_sets.read_pairs(data))
    assert result["rows"]["all"]["relit"] == pytest.approx({"n": 2, "mean": 0.0, "se": 0.0, "bound": 0.0,
                                                             "paired": True})
