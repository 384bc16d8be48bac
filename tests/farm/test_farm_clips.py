"""farm.clips: ground-truth clips, one rigidly moving person per clip, one scene file per frame."""

from __future__ import annotations

import math

import numpy as np
import pytest

from farm import clips
from farm.cli import parse_args
from farm.synthesis.scene_options import SceneOptions as StillOptions

SMALL = {"resolution": 64, "lights": 2, "samples": 4, "denoise": False, "bake_directions": 64}


def test_clip_options_validate_and_round_trip_through_json():
    options = clips.SceneOptions(**SMALL, clip_frames=6, motion="sway")
    assert clips.SceneOptions.from_json(options.to_json()) == options
    assert options.scene_options() == StillOptions(**SMALL)
    for bad, message in (({"clip_frames": 1}, "clip_frames"), ({"motion": "jump"}, "motion")):
        with pytest.raises(ValueError, match=message):
            clips.SceneOptions(**SMALL, **bad).validate()


def test_the_command_line_picks_the_clip_job():
    config = parse_args(["--out", "x", "--scenes", "8", "--seed", "3", "--clip-frames", "4", "--motion", "sway"])
    assert config.job_module == "farm.clips"
    assert (config.scene.clip_frames, config.scene.motion) == (4, "sway")
    assert parse_args(["--out", "x", "--scenes", "8", "--seed", "3"]).job_module == "farm.scene"


def test_frames_map_to_clips_and_motions_are_rigid_and_bounded():
    assert [clips.clip_frame(i, 4) for i in (0, 3, 4, 9)] == [(0, 0), (0, 3), (1, 0), (2, 1)]
    for motion in clips.MOTIONS:
        for frame in range(5):
            rotation, angle = clips.motion_transform(motion, frame, 5)
            np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
            assert math.isclose(np.linalg.det(rotation), 1.0)
            limit = clips.TURN_DEGREES if motion == "turn" else clips.SWAY_DEGREES
            assert abs(angle) <= limit + 1e-9
    assert clips.motion_transform("turn", 4, 5)[1] == pytest.approx(clips.TURN_DEGREES)
    assert clips.motion_transform("sway", 0, 5)[1] == 0.0


@pytest.mark.anny
def test_frames_of_a_clip_share_the_scene_and_move_the_person():
    options = clips.SceneOptions(**SMALL, clip_frames=3, motion="turn")
    first, last, other = (clips.sample_frame(i, 5, options) for i in (0, 2, 3))
    # one clip: the same camera, lights and clothes; frame 2 turned by TURN_DEGREES about the vertical
    assert first.camera.as_dict() == last.camera.as_dict()
    assert [l.record() for l in first.lights] == [l.record() for l in last.lights]
    assert first.look == last.look
    v0, _, _ = first.mesh()
    v2, _, _ = last.mesh()
    np.testing.assert_allclose(v2[:, 2], v0[:, 2], atol=1e-9)  # heights kept: a turn about Z
    c0, c2 = v0[:, :2] - v0[:, :2].mean(0), v2[:, :2] - v2[:, :2].mean(0)
    turned = math.degrees(math.atan2(np.cross(c0, c2).sum(), (c0 * c2).sum()))
    assert turned == pytest.approx(clips.TURN_DEGREES, abs=0.5)
    assert first.record()["index"] == 0 and last.record()["index"] == 2
    assert last.record()["clip"] == {"clip": 0, "frame": 2, "frames": 3, "motion": "turn",
                                     "angle_deg": pytest.approx(clips.TURN_DEGREES)}
    # frame 3 starts clip 1: another drawn scene
    assert other.record()["clip"]["clip"] == 1 and other.look != first.look
