"""The add-on's Relight Sequence: a movie or image sequence relit frame by frame into a new
image sequence beside the .blend (blender_addon/worker/sequence.py without Blender, the operator
under headless bpy)."""

from __future__ import annotations

import sys

import numpy as np
import pytest

import bpy

import blender_addon
from blender_addon.worker import engine, sequence
from clip_support import background, person_clip, write_frames
from relight.network import quality
from relight.files.photo import read_photo


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """Six frames of a person (the fourth without one) as a PNG sequence shot_0001.png ..."""
    folder = tmp_path_factory.mktemp("sequence")
    clip = person_clip(6)
    clip[3] = background()
    write_frames(folder, clip, prefix="shot_")
    write_frames(folder, person_clip(2), prefix="other_")  # another sequence in the same folder
    return folder


def _plan(frames, folder, **extra):
    from relight.lighting.light import sh_light

    return dict(path=str(frames / "shot_0001.png"), source="SEQUENCE", folder=str(folder),
                model_path=str(quality.model_path("draft")), long_side=96, light=sh_light("studio", 4),
                rotation=0.0, exposure=0.0, stability=0.5, person=None, **extra)


def test_sequence_files_are_one_sequence_in_number_order(frames, tmp_path):
    files = sequence.sequence_files(frames / "shot_0003.png")
    assert [p.name for p in files] == [f"shot_{i:04d}.png" for i in range(1, 7)]
    assert sequence.output_folder(str(tmp_path / "scene.blend"), "shot_0001.png") == tmp_path / "shot_0001_relit"
    with pytest.raises(ValueError, match="Save the .blend"):
        sequence.output_folder("", "shot_0001.png")


def test_a_sequence_relights_into_whole_frames_and_keeps_the_frame_without_a_person(frames, tmp_path):
    progress, token = sequence.SequenceProgress(), engine.CancelToken()
    result = sequence.relight_sequence(_plan(frames, tmp_path / "out"), progress, token)
    assert result["written"] == 6 and result["nobody"] == [3]
    out = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert out == [f"frame_{i:06d}.png" for i in range(1, 7)]
    np.testing.assert_array_equal(read_photo(tmp_path / "out" / "frame_000004.png")[0],
                                  read_photo(frames / "shot_0004.png")[0])
    assert "no person in frames 4: kept as they were" in sequence.nobody_note(result["nobody"])


def test_esc_keeps_the_frames_done(frames, tmp_path):
    progress, token = sequence.SequenceProgress(), engine.CancelToken()
    original = progress.enter

    def enter(stage, fraction):  # Esc while the third frame is being relit
        if stage.startswith("Frame 3"):
            token.cancel()
        original(stage, fraction)

    progress.enter = enter
    with pytest.raises(engine.Cancelled):
        sequence.relight_sequence(_plan(frames, tmp_path / "out"), progress, token)
    # the token is checked between frames: the third, in progress at Esc, is finished; no fourth
    assert progress.written == 3
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [f"frame_{i:06d}.png" for i in (1, 2, 3)]


def test_a_movie_without_pyav_is_one_clear_message(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "av", None)  # import av raises ImportError
    with pytest.raises(ValueError, match="needs PyAV in Blender's Python"):
        sequence.open_frames(str(tmp_path / "clip.mp4"), "MOVIE")


@pytest.fixture
def addon(frames, tmp_path):
    blender_addon.register()
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    image = bpy.data.images.load(str(frames / "shot_0001.png"))
    image.source = "SEQUENCE"
    s = bpy.context.scene.relight_photo
    s.quality, s.light_kind, s.preset, s.model_path = "DRAFT", "PRESET", "studio", ""
    yield image
    bpy.data.images.remove(image)
    blender_addon.unregister()


def test_the_operator_writes_a_sequence_beside_the_blend_and_loads_it(addon, tmp_path):
    assert bpy.ops.relight_photo.relight_sequence(image_name=addon.name, synchronous=True) == {"FINISHED"}
    folder = tmp_path / "shot_0001_relit"
    assert len(list(folder.glob("frame_*.png"))) == 6
    loaded = [i for i in bpy.data.images if i.filepath and i.filepath.endswith("frame_000001.png")]
    assert loaded and loaded[0].source == "SEQUENCE"
    message = bpy.context.window_manager.relight_photo_status.message
    assert "Relit 6 frames" in message and "no person in frames 4" in message
    bpy.data.images.remove(loaded[0])


def test_the_operator_refuses_a_still_photo(addon, frames):
    still = bpy.data.images.load(str(frames / "other_0001.png"))
    with pytest.raises(RuntimeError, match="movie or an image sequence"):
        bpy.ops.relight_photo.relight_sequence(image_name=still.name, synchronous=True)
    bpy.data.images.remove(still)


def test_a_second_run_refuses_to_overwrite_the_first_runs_frames_until_asked(addon, tmp_path):
    """Issue 40: run twice, Relight Sequence silently replaced the first run's frames."""
    folder = tmp_path / "shot_0001_relit"
    assert bpy.ops.relight_photo.relight_sequence(image_name=addon.name, synchronous=True) == {"FINISHED"}
    first = {p.name: p.stat().st_mtime_ns for p in folder.glob("frame_*.png")}
    assert len(first) == 6
    (folder / "frame_000009.png").write_bytes((folder / "frame_000001.png").read_bytes())  # a longer run's
    (folder / "notes.txt").write_text("the artist's own file")
    status = bpy.context.window_manager.relight_photo_status
    with pytest.raises(RuntimeError):
        bpy.ops.relight_photo.relight_sequence(image_name=addon.name, synchronous=True)
    assert status.is_error and status.message == (
        "'shot_0001_relit' beside the .blend holds 7 frames of an earlier Relight Sequence: tick Overwrite next "
        "to Relight Sequence to replace them, or move or rename that folder to keep them.")
    assert {p.name: p.stat().st_mtime_ns for p in folder.glob("frame_00000[1-6].png")} == first  # untouched
    # the panel's Overwrite, ticked: this run replaces them all (none of the earlier run's left behind)
    settings = bpy.context.scene.relight_photo
    settings.overwrite_frames = True
    assert bpy.ops.relight_photo.relight_sequence(image_name=addon.name, synchronous=True) == {"FINISHED"}
    assert "replacing the 7 frames there before" in status.message and not status.is_error
    now = sorted(p.name for p in folder.iterdir())
    assert now == [f"frame_{i:06d}.png" for i in range(1, 7)] + ["notes.txt"]
    assert all(p.stat().st_mtime_ns != first[p.name] for p in folder.glob("frame_*.png"))
    assert settings.overwrite_frames is False  # one run's permission: a third run asks again
    with pytest.raises(RuntimeError, match="holds 6 frames of an earlier Relight Sequence"):
        bpy.ops.relight_photo.relight_sequence(image_name=addon.name, synchronous=True)
    # a script says so with the operator's own option
    assert bpy.ops.relight_photo.relight_sequence(image_name=addon.name, synchronous=True,
                                                  overwrite=True) == {"FINISHED"}
    for image in [i for i in bpy.data.images if i.filepath.endswith("frame_000001.png")]:
        bpy.data.images.remove(image)
