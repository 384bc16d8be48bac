"""tools/variety_subsets.py: the narrow half of the looks, and as many scenes of every look."""

import importlib.util
import json
from pathlib import Path

from relight.files.dataset import FORMAT

TOOL = Path(__file__).resolve().parents[2] / "tools" / "variety_subsets.py"
spec = importlib.util.spec_from_file_location("variety_subsets", TOOL)
variety = importlib.util.module_from_spec(spec)
spec.loader.exec_module(variety)

PATTERNS = ["none", "denim", "stripes", "checks"]
HAIR = ["short", "long", "afro", "bun", "bald", "medium"]


def _farm(folder: Path, n: int = 24) -> dict[int, bool]:
    """n scene sidecars (and empty EXRs but for scene 5's), their looks cycling; index -> narrow."""
    narrow = {}
    for i in range(n):
        top, bottom = PATTERNS[i % 4], PATTERNS[(i // 4) % 2]
        hair = HAIR[i % 6]
        look = {"garments": {"top": {"material": {"pattern": top}}, "bottom": {"material": {"pattern": bottom}}},
                "hair": {"style": hair}}
        meta = {"format": FORMAT, "index": i, "sh_order": 2, "lights": [], "resolution": [8, 8], "channels": [],
                "exr_sha256": "0" * 64, "appearance": look}
        (folder / f"scene_{i:06d}.json").write_text(json.dumps(meta))
        if i != 5:
            (folder / f"scene_{i:06d}.exr").write_bytes(b"")
            narrow[i] = top in ("none", "denim") and hair in ("short", "long", "bald", "medium")
    return narrow


def test_narrow_is_the_rule_broad_as_many_of_every_look(tmp_path):
    truth = _farm(tmp_path)
    sets = variety.subsets(tmp_path, exclude=(20, 22), seed=3)
    got = [int(p.stem[-6:]) for p in sets["narrow"]]
    assert got == [i for i, n in sorted(truth.items()) if n and not 20 <= i < 22]
    broad = [int(p.stem[-6:]) for p in sets["broad"]]
    assert len(broad) == len(got) and len(set(broad)) == len(broad)
    assert 5 not in broad and not {20, 21} & set(broad)  # no EXR; excluded
    assert any(not truth[i] for i in broad)  # every look: 16 of the 21 eligible scenes are not narrow
    assert variety.subsets(tmp_path, exclude=(20, 22), seed=3) == sets  # seeded


def test_links_point_at_both_files_and_a_rerun_keeps_them(tmp_path):
    farm, out = tmp_path / "farm", tmp_path / "out"
    farm.mkdir()
    _farm(farm)
    assert variety.main([str(farm), str(out)]) == 0
    names = sorted(p.name for p in (out / "narrow").iterdir())
    assert names and all((out / "narrow" / n).resolve().parent == farm.resolve() for n in names)
    assert {n[:-5] for n in names if n.endswith(".json")} == {n[:-4] for n in names if n.endswith(".exr")}
    assert variety.main([str(farm), str(out)]) == 0
    assert sorted(p.name for p in (out / "narrow").iterdir()) == names


def test_a_broken_sidecar_is_named(tmp_path, capsys):
    _farm(tmp_path, n=3)
    (tmp_path / "scene_000001.json").write_text("{")
    assert variety.main([str(tmp_path), str(tmp_path / "out")]) == 1
    assert "scene_000001.json" in capsys.readouterr().err
    (tmp_path / "scene_000001.json").write_text(json.dumps({"format": FORMAT, "index": 1}))
    assert variety.main([str(tmp_path), str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "scene_000001.json" in err and "lacks" in err and not (tmp_path / "out" / "narrow").exists()
