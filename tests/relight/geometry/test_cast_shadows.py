"""Cast shadows (relight.geometry, relight.lighting.directional, relight.network.shadowing) against
analytic cases: a sphere over a plane (exact ray-sphere intersection), a step, and the extremes (a
grazing sun, a sun behind the person, along the view axis, a flat person)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from relight.geometry.relief import MAX_SLOPE, depth_from_normals, normals_from_transport
from relight.geometry.shadows import MIN_HALF_ANGLE_DEG, cast_visibility
from relight.lighting.directional import MIN_KEY_SHARE, directional_part, key_share
from relight.lighting.key_light import KeyLight
from relight.lighting.lamps import sun_light
from relight.network.prt import lambert_transport
from relight.network.shadowing import ShadowCaster

H = W = 96
R, CX, CY, ZC, PLANE = 16.0, 48.0, 48.0, 50.0, 90.0   # orthographic pixels: sphere in front of a plane


def _unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def _sphere_over_plane():
    rows, cols = np.mgrid[0:H, 0:W]
    dx, dz = cols + 0.5 - CX, -(rows + 0.5 - CY)
    r2 = np.maximum(R * R - dx * dx - dz * dz, 0.0)
    disc = dx * dx + dz * dz < R * R
    depth = np.where(disc, ZC - np.sqrt(r2), PLANE)
    thickness = np.where(disc, 2.0 * np.sqrt(r2), np.inf)  # the sphere's back: exact per pixel
    return depth, disc, thickness, (cols + 0.5, rows + 0.5)


def _exact_lit(depth, l, centres):
    """Whether each pixel's surface point sees the direction l past the sphere (ray-sphere test)."""
    u, v = centres
    P = np.stack([u, depth, -v], axis=-1)
    oc = P - np.array([CX, ZC, -CY])
    b, c = oc @ l, (oc * oc).sum(-1) - R * R
    disc = b * b - c
    far = -b + np.sqrt(np.maximum(disc, 0.0))
    near = -b - np.sqrt(np.maximum(disc, 0.0))
    return ~((disc > 0) & (near > 1e-6) & (far > 1e-6))


def _distance_to_edge(lit):
    """Pixels (chessboard) from each pixel to the nearest pixel of the other state."""
    dist = np.full(lit.shape, np.inf)
    ys, xs = np.nonzero(lit[:, 1:] != lit[:, :-1])
    edges = np.concatenate([np.stack([ys, xs], 1), np.stack(np.nonzero(lit[1:, :] != lit[:-1, :]), 1)])
    rows, cols = np.mgrid[0:lit.shape[0], 0:lit.shape[1]]
    for y, x in edges:
        np.minimum(dist, np.maximum(abs(rows - y), abs(cols - x)), out=dist)
    return dist


@pytest.mark.parametrize("direction", [(1.0, -1.2, 0.0), (1.0, -1.0, 0.5), (-1.0, -2.0, -0.3), (0.3, -1.0, -0.9)])
def test_sphere_over_plane_matches_the_exact_shadow(direction):
    """On the plane, the march agrees with the exact ray-sphere shadow wherever a pixel is farther from
    the shadow's edge than the penumbra's half-width (the longest march to the sphere times tan of the
    smallest half-angle) plus one pixel of nearest sampling."""
    l = _unit(direction)
    depth, disc, thickness, centres = _sphere_over_plane()
    vis = cast_visibility(depth, np.ones((H, W), bool), l, 0.0, thickness=thickness)
    lit = _exact_lit(depth, l, centres)
    assert (~lit & ~disc).sum() > 50, "the case must cast a shadow on the plane"
    sine = math.hypot(l[0], l[2])
    longest = (PLANE - (ZC - R)) / abs(l[1]) * sine + 2 * R    # screen pixels from the plane to past the sphere
    band = 1.0 + longest * math.tan(math.radians(MIN_HALF_ANGLE_DEG))
    judged = ~disc & (_distance_to_edge(lit) > band)
    assert judged.sum() > 0.5 * (~disc).sum()
    wrong = np.abs(vis - lit)[judged] > 0.5
    assert not wrong.any(), f"{wrong.sum()} plane pixels disagree with the exact shadow"


def test_the_lit_side_of_the_sphere_casts_nothing_on_itself():
    depth, disc, thickness, centres = _sphere_over_plane()
    u, v = centres
    normal = np.stack([u - CX, -np.sqrt(np.maximum(R * R - (u - CX) ** 2 - (CY - v) ** 2, 0)), CY - v], -1) / R
    for direction in [(1.0, -0.4, 0.0), (1.0, -1.0, 0.5), (-0.2, -1.0, 0.9)]:
        l = _unit(direction)
        vis = cast_visibility(depth, np.ones((H, W), bool), l, 0.0, thickness=thickness)
        facing = disc & (normal @ l > 0.2)
        assert facing.sum() > 100 and vis[facing].min() == 1.0


def test_a_step_shadows_exactly_its_length():
    """A plateau 10 px nearer the camera than the floor, a sun from the right at 45 degrees toward the
    camera (l = (1, -1, 0)/sqrt 2): the floor left of the step is in shadow for 10 px (the step's
    height over tan 45), then lit; the edge within the march's step there (2 px past 8 px,
    relight.geometry.shadows.march_steps) and a pixel of nearest sampling."""
    depth = np.full((32, 64), 40.0)
    depth[:, 32:] = 30.0                        # columns 32.. are the plateau
    vis = cast_visibility(depth, np.ones_like(depth, bool), _unit((1.0, -1.0, 0.0)), 0.0, thickness=np.inf)
    row = vis[16]
    assert np.all(row[32:] == 1.0)              # the plateau sees the sun
    assert np.all(row[25:32] == 0.0)            # 10 px of shadow: columns 22..31, less 3 px at its edge
    assert np.all(row[:19] == 1.0)


def test_penumbra_widens_with_the_lamp():
    depth = np.full((32, 96), 40.0)
    depth[:, 64:] = 30.0
    l = _unit((1.0, -1.0, 0.0))
    hard = cast_visibility(depth, np.ones_like(depth, bool), l, 0.0)[16]
    soft = cast_visibility(depth, np.ones_like(depth, bool), l, 10.0)[16]
    partial = lambda row: int(((row > 0.02) & (row < 0.98)).sum())
    assert partial(soft) > partial(hard) >= 0
    assert np.all((soft >= 0) & (soft <= 1))


def test_extremes_cast_no_shadow_or_refuse():
    depth, disc, thickness, _ = _sphere_over_plane()
    inside = np.ones((H, W), bool)
    # along the view axis, toward the camera: every shadow hides behind what casts it
    assert np.all(cast_visibility(depth, inside, (0.0, -1.0, 0.0), 1.0) == 1.0)
    # a flat person facing the camera, any lamp in front: nothing to cast a shadow
    flat = np.full((H, W), 20.0)
    for direction in [(1, -0.2, 0), (0, -1, 1), (-1, -1, -1)]:
        assert np.all(cast_visibility(flat, inside, _unit(direction), 0.0) == 1.0)
    # a grazing sun over a flat floor: a lamp of angular radius theta whose centre is e above the
    # horizon shows (tan theta + tan e) / (2 tan theta) of itself (plus the bias's 0.25 px over the
    # march's length, < 0.02 for the leftmost column's 199 px); 10 degrees up, all of it
    floor = np.full((8, 200), 20.0)
    theta = math.tan(math.radians(MIN_HALF_ANGLE_DEG))
    for e_deg in (0.0, 0.5, 1.0):
        e = math.radians(e_deg)
        grazing = cast_visibility(floor, np.ones_like(floor, bool), (math.cos(e), -math.sin(e), 0.0), 0.0)
        assert np.all(np.isfinite(grazing))
        expected = (theta + math.tan(e)) / (2 * theta)
        assert np.abs(grazing[:, 0] - expected).max() < 0.02
    assert np.all(cast_visibility(floor, np.ones_like(floor, bool), _unit((1.0, -0.18, 0.0)), 0.0) == 1.0)
    # a sun behind the person (away from the camera): the plane's points face away from it, and the
    # march's first step already passes behind the plane (away from the sphere and the grid's edge)
    behind = cast_visibility(depth, inside, _unit((0.3, 1.0, 0.2)), 0.0, thickness=thickness)
    rows, cols = np.mgrid[0:H, 0:W]
    clear = ((cols + 0.5 - CX) ** 2 + (rows + 0.5 - CY) ** 2 > (R + 3) ** 2) & (cols < W - 3) & (rows > 2)
    assert np.all(behind[clear] == 0.0)
    # outside `inside` and `where`, 1
    where = np.zeros((H, W), bool)
    assert np.all(cast_visibility(depth, inside, _unit((1, -1, 0.5)), 0.0, where=where) == 1.0)
    for bad in [dict(direction=(0, 0, 0)), dict(direction=(np.nan, 1, 0)), dict(half_angle_deg=-1.0)]:
        kwargs = {"direction": (1, -1, 0), "half_angle_deg": 0.0, **bad}
        with pytest.raises(ValueError):
            cast_visibility(depth, inside, kwargs["direction"], kwargs["half_angle_deg"])
    with pytest.raises(ValueError):
        cast_visibility(np.where(disc, np.nan, depth), inside, (1, -1, 0))


def test_pinhole_shadow_of_a_step_in_metres():
    """The same step seen by a pinhole at 2 m: the shadow's length on the floor is the step's height
    (0.1 m) over tan 45 degrees, 0.1 m, which is 0.1 * f / 2.1 pixels at the floor's depth, within the
    march's 2 px step spacing there and a pixel of nearest sampling."""
    f = 200.0
    depth = np.full((32, 96), 2.1)
    depth[:, 48:] = 2.0
    vis = cast_visibility(depth, np.ones_like(depth, bool), _unit((1.0, -1.0, 0.0)), 0.0, focal_px=f)
    shadow = int((vis[16, :48] < 0.5).sum())
    assert abs(shadow - 0.1 * f / 2.1) <= 3.0


def test_relief_of_a_sphere_recovers_its_shape():
    """A hemisphere's normals integrate to its depth up to a constant, within a pixel, away from the
    silhouette's last MAX_SLOPE-clamped ring."""
    rows, cols = np.mgrid[0:64, 0:64]
    dx, dz = cols + 0.5 - 32, -(rows + 0.5 - 32)
    r2 = 24.0 ** 2 - dx * dx - dz * dz
    inside = r2 > 0
    normals = np.stack([dx, -np.sqrt(np.maximum(r2, 0)), dz], -1) / 24.0
    depth = depth_from_normals(normals, inside)
    truth = -np.sqrt(np.maximum(r2, 0))
    # slopes are clamped past MAX_SLOPE, i.e. beyond MAX_SLOPE / sqrt(1 + MAX_SLOPE^2) (0.97) of the
    # radius: judged within 0.8 of it, clear of that ring and of the edge's half-covered pixels
    assert MAX_SLOPE / math.sqrt(1 + MAX_SLOPE ** 2) > 0.9
    core = dx * dx + dz * dz < (0.8 * 24.0) ** 2
    err = (depth - truth)[core]
    assert np.abs(err - err.mean()).max() < 1.0
    assert np.all(depth[~inside] == 0)


def test_normals_read_back_from_lambert_transport():
    rng = np.random.default_rng(4)
    n = rng.normal(size=(8, 8, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    back = normals_from_transport(lambert_transport(n, 4).astype(np.float32))
    assert np.abs(back - n).max() < 1e-5
    assert np.all(normals_from_transport(np.zeros((2, 2, 9))) == [0.0, -1.0, 0.0])


def test_directional_part_finds_a_sun_and_refuses_a_sky():
    light = sun_light(90.0, 10.0, 5.0, 4)
    key = directional_part(light)
    assert key is not None
    assert np.degrees(np.arccos(np.clip(key.direction @ _unit((1.0, 0.0, math.tan(math.radians(10)))), -1, 1))) < 1.0
    assert key_share(key, light) == pytest.approx(0.8, abs=0.05)   # sun_light's ambient is 0.2 of a facing surface
    constant = np.zeros((25, 3))
    constant[0] = 1.0
    assert directional_part(constant) is None
    assert directional_part(sun_light(0.0, 30.0, 5.0, 4, ambient=0.9)) is None   # the sun gives < MIN_KEY_SHARE
    assert MIN_KEY_SHARE > 0.1


def test_shadow_caster_dims_only_the_keys_share():
    """Over a step lit by a sun: where the key is blocked, the shading falls by exactly the key's part
    (T . K), and nowhere else."""
    h, w = 24, 48
    normals = np.tile(np.array([0.0, -1.0, 0.0]), (h, w, 1))
    transport = lambert_transport(normals, 4).astype(np.float32)
    alpha = np.ones((h, w), np.float32)
    caster = ShadowCaster(transport, alpha, np.arange(h * w))
    key = KeyLight(_unit((1.0, -1.0, 0.0)), np.ones(3), 0.0)
    caster._depth = np.where(np.arange(w) >= 24, 10.0, 20.0).astype(np.float32)[None].repeat(h, 0)
    blocked = caster.blocked_shading(key, transport.reshape(-1, 25), 4).reshape(h, w, 3)
    vis = caster.visibility(key)
    assert vis.min() == 0.0 and vis[:, 24:].min() == 1.0
    assert np.all(blocked[vis == 1.0] == 0)
    assert caster.visibility(key) is vis                 # made once per key


def test_relight_with_shadows_only_removes_light(tmp_path, capsys):
    """On a bundled photo: under a sun, `relight image --shadows` darkens the person (never brightens a
    pixel: shadows only remove the key's light) and records the key; under a map without a directional
    part it is the plain relight, bit for bit, and records why no shadow was cast."""
    import json

    from relight.cli import main
    from relight.files.photo import read_photo

    photo = "relight/data/examples/grace_hopper.jpg"
    outputs = {}
    for light, shadows in (("sun:90,10,5", False), ("sun:90,10,5", True), ("sunset", False), ("sunset", True)):
        out = tmp_path / f"{light.replace(':', '_')}_{shadows}.exr"
        argv = ["image", photo, "--light", light, "--quality", "draft", "--json", "--out", str(out)]
        assert main(argv + (["--shadows"] if shadows else [])) == 0
        line = json.loads(capsys.readouterr().out.splitlines()[0])
        outputs[light, shadows] = read_photo(out)[0], line["relight"].get("shadows")
    (plain, none), (shadowed, key) = outputs["sun:90,10,5", False], outputs["sun:90,10,5", True]
    assert none is None and key["lamp"] == "SUN" and abs(key["azimuth_deg"] - 90.0) < 1.0
    assert np.all(shadowed <= plain + 1e-6)              # EXR: linear float, no rounding between the two
    darker = plain - shadowed > 0.01 * plain.max()
    assert 0.01 < darker.mean() < 0.6                    # a shadow, not the whole photo
    assert np.array_equal(outputs["sunset", True][0], outputs["sunset", False][0])
    assert outputs["sunset", True][1].startswith("none")


def test_shadow_layer_is_one_off_the_person():
    """The Shadow layer: 1 wherever the full-resolution matte is 0 (the working matte's soft edge reaches a
    little past it: no dark fringe there), below 1 somewhere on the person under a side sun, in [0, 1]."""
    from relight.files.photo import read_photo
    from relight.network.quality import preset
    from relight.network.runtime import Relighter

    photo, _ = read_photo("relight/data/examples/grace_hopper.jpg")
    d = Relighter(working_size=128).decompose(photo, **preset("draft").decompose_options(working_size=False))
    layer = d.shadow_layer(sun_light(90.0, 10.0, 5.0, 4))
    alpha = d.full_alpha()
    assert layer.shape == alpha.shape and np.all((layer >= 0) & (layer <= 1))
    assert np.all(layer[alpha <= 0] == 1.0)
    assert (layer[alpha > 0.99] < 0.5).mean() > 0.01
    assert np.all(d.shadow_layer(sun_light(90.0, 10.0, 5.0, 4, ambient=0.95)) == 1.0)  # no directional part
