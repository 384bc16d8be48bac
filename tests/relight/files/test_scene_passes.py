"""relight.files.scene_passes: the one table of render passes, held equal to what the scene reader
writes and reads back and to docs/dataset.md's channel table."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from relight.files import dataset, scene_passes
from relight.files.scene_passes import PER_LIGHT, PER_PERSON, SH

ROOT = Path(__file__).resolve().parents[3]
RNG = np.random.default_rng(49)
H, W, ORDER, LIGHTS, PEOPLE = 4, 5, 1, 2, 2
N = (ORDER + 1) ** 2


def every_channel() -> tuple[dict, dict]:
    """A two-person scene with every group of every pass of the table, random values."""
    f32 = lambda c: RNG.random((H, W, c)).astype(np.float32)
    channels = {}
    for group in scene_passes.GROUPS.values():
        if group.kind == SH:
            channels[group.name] = f32(N)
        elif group.kind == PER_LIGHT:
            channels.update({f"{group.name}.L{k}": f32(len(group.suffixes)) for k in range(LIGHTS)})
        elif group.kind == PER_PERSON:
            share = RNG.random((H, W, 1)).astype(np.float32)
            channels.update({f"{group.name}.P0": share, f"{group.name}.P1": (1 - share).astype(np.float32)})
        else:
            channels[group.name] = f32(len(group.suffixes))
    channels["alpha"] = (channels["person.P0"] + channels["person.P1"]).astype(np.float32)
    lights = [{"name": f"l{k}", "sh": RNG.normal(size=(N, 3)), "sh8": RNG.normal(size=(81, 3))} for k in range(LIGHTS)]
    return channels, {"index": 3, "sh_order": ORDER, "lights": lights, "people": {"count": PEOPLE}}


def test_every_pass_of_the_table_is_written_and_read_back(tmp_path):
    channels, meta = every_channel()
    dataset.write_scene(tmp_path / "scene_000003", channels, meta)
    scene = dataset.read_scene(tmp_path / "scene_000003")
    assert len(scene.meta["channels"]) == scene_passes.channel_count(scene_passes.CHOICES, N, LIGHTS, PEOPLE)
    for group in scene_passes.GROUPS.values():
        got = getattr(scene, group.name)
        if group.kind == PER_LIGHT:
            assert len(got) == LIGHTS
            for k in range(LIGHTS):
                np.testing.assert_array_equal(got[k], channels[f"{group.name}.L{k}"])
        elif group.kind == PER_PERSON:
            np.testing.assert_array_equal(np.stack(got), np.stack([channels["person.P0"], channels["person.P1"]]))
        else:
            np.testing.assert_array_equal(got, channels[group.name])
    assert scene.images is scene.image and scene.people is scene.person


def test_a_pass_left_out_reads_as_none_and_a_name_outside_the_table_is_refused(tmp_path):
    channels, meta = every_channel()
    body_back = {"body_back_depth"}
    dataset.write_scene(tmp_path / "scene_000003", {k: v for k, v in channels.items() if k not in body_back}, meta)
    scene = dataset.read_scene(tmp_path / "scene_000003")
    assert scene.body_back_depth is None and scene.body_depth is not None
    with pytest.raises(AttributeError, match="body_front"):
        scene.body_front
    with pytest.raises(ValueError, match="unknown scene pass 'body_front'"):
        dataset.write_scene(tmp_path / "scene_000003", dict(channels, body_front=channels["depth"]), meta)


def test_the_farms_choices_and_default():
    assert scene_passes.CHOICES == ("prt", "pt", "body", "body_back")  # the order of a sidecar's passes.skipped
    assert scene_passes.DEFAULT == {"prt", "pt", "body"}  # the farm's output of before, byte for byte
    # the geometry pass, one light, order 2, nothing else: 12 channels (head included)
    assert scene_passes.channel_count(set(), 9, 1) == 12
    assert scene_passes.channel_count({"prt", "body_back"}, 9, 2, people=3) == 12 + 3 + 9 + 2 * 3 * 2 + 1


def test_docs_dataset_lists_every_group_and_pass_of_the_table():
    text = (ROOT / "docs" / "dataset.md").read_text(encoding="utf-8")
    rows = re.findall(r"^\| `([\w.]+)", text.split("## Channels", 1)[1].split("\n## ", 1)[0], re.MULTILINE)
    documented = {row.split(".")[0] for row in rows}
    assert documented == set(scene_passes.GROUPS), "docs/dataset.md's channel table and relight/files/scene_passes.py differ"
    for render_pass in scene_passes.PASSES[1:]:
        assert f"`{render_pass.name}`" in text, f"docs/dataset.md does not name the pass {render_pass.name}"
