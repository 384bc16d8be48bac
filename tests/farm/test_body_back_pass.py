"""The `body_back` pass (farm/rendering/body_pass.py, relight/files/scene_passes.py): the depth where
the camera's rays leave the unclothed body. On a box its far face exactly; in a rendered scene
written, read back and equal to the body's far side cast again from the drawn scene."""

from __future__ import annotations

import numpy as np
import pytest

try:
    import bpy
except ImportError:
    bpy = None

from farm.rendering.body_pass import RAY_CAST_PASSES, body_back_depth, body_pass
from farm.synthesis.meshops import vertex_normals
from relight.files import dataset, scene_passes

FOCAL_MM, RES = 50.0, 24  # a 36 mm sensor: the film spans +-0.36 of the distance


def box(centre_y: float, half: float) -> tuple[np.ndarray, np.ndarray]:
    """A closed cube (outward triangles) of side 2 * half centred on the view axis at depth centre_y."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * half
    corners[:, 1] += centre_y
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    return corners, faces


def test_the_far_side_of_a_box_is_its_back_face():
    """Rays through the box's front face leave it through the back face at y = d + a where they stay
    within the box's width there (|x|, |z| <= a at depth d + a), else through a side, nearer."""
    d, a = 3.0, 0.5
    vertices, faces = box(d, a)
    back = body_back_depth(vertices, faces, RES, FOCAL_MM)
    front = body_pass(vertices, faces, vertex_normals(vertices, faces), RES, FOCAL_MM)
    hit = front.alpha == 1.0
    # a pixel's rays span film coordinates within 0.36 * (|c| + 1/2) / (RES / 2) of the axis, c its centre
    c = (np.arange(RES) + 0.5) / RES - 0.5
    reach = np.abs(c)[:, None] + 0.5 / RES
    through_back = (np.maximum(reach, reach.T) * 36.0 / FOCAL_MM * (d + a) <= a)
    assert through_back.sum() >= 16
    np.testing.assert_allclose(back[through_back], d + a, rtol=1e-6)  # float32 ray parameters
    np.testing.assert_allclose(front.depth[through_back], d - a, rtol=1e-6)
    assert np.all(back[hit] <= d + a + 1e-5) and np.all(back[hit] >= front.depth[hit])
    assert np.all(back[front.alpha == 0.0] == 0.0) and hit.sum() < RES * RES


def test_the_farm_casts_every_pass_it_does_not_render_with_cycles():
    assert set(RAY_CAST_PASSES) == set(scene_passes.CHOICES) - {"pt", "prt"}


@pytest.mark.skipif(bpy is None, reason="needs bpy (the farm extra)")
@pytest.mark.anny
def test_body_back_is_written_read_back_and_is_the_bodys_far_side(tmp_path):
    from farm.rendering.body_pass import scene_body_back
    from farm.scene import SceneOptions, render_scene, sample_scene

    options = SceneOptions(resolution=32, lights=1, samples=1, denoise=False, bake_directions=16,
                           passes=frozenset({"body", "body_back"}))
    scene = dataset.read_scene(render_scene(2, 49, options, tmp_path))
    assert scene.meta["passes"]["skipped"] == ["prt", "pt"]  # body_back asked; not a default pass anyway
    assert len(scene.meta["channels"]) == options.expected_channels() == 12 + 5 + 1
    back, front, body = scene.body_back_depth[..., 0], scene.body_depth[..., 0], scene.body_alpha[..., 0]
    again = scene_body_back(sample_scene(2, 49, options))["body_back_depth"]
    np.testing.assert_allclose(back, again, rtol=0, atol=1e-6)  # the same drawn body, cast again
    whole = body == 1.0
    assert whole.sum() >= 20
    thickness = back[whole] - front[whole]
    assert thickness.min() >= 0.0
    # a person's limbs and torso seen front on: centimetres to a few decimetres thick (here 0.13 m)
    assert 0.03 < np.median(thickness) < 0.4
    assert np.all(back[body == 0.0] == 0.0)
    plain = dataset.read_scene(render_scene(2, 49, SceneOptions(**dict(vars(options), passes=frozenset({"body"}))),
                                            tmp_path / "plain"))
    assert plain.body_back_depth is None and plain.meta["passes"]["skipped"] == ["prt", "pt"]
    np.testing.assert_array_equal(plain.body_depth, scene.body_depth)
