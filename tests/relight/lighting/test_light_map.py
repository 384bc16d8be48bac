"""The photo's light as a non-negative equirect map (relight.lighting.light_map) and `relight light`."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from relight.lighting import sh, sh_projection
from relight.lighting.light import directional_light, sh_light
from relight.files.exr import read_exr, write_exr
from relight.lighting.light_colour import bound_saturation, colour_envelope, project_colours, saturation
from relight.lighting.light_map import (
    COLOUR_FIT_HEIGHT, REGULARISATION, _fitted_bands, check_width, irradiance_error, light_map,
)
from relight.network.quality import preset
from light_colour_support import ASTRONAUT_DRAFT, lit_saturation, most_saturated, sun_and_sky

DRAFT_SIZE = preset("draft").working_size  # the Draft preset's working size

ORDER = 4
A = sh.clamped_cosine_coeffs(ORDER)
BAND = np.repeat(np.arange(ORDER + 1), 2 * np.arange(ORDER + 1) + 1)


def delta(direction, rgb=(1.0, 1.0, 1.0)):
    """SH of all the energy in one direction: Y_k(d) per unit of integral."""
    return np.outer(sh.sh_basis(np.asarray(direction, float), ORDER), rgb)


def camera_left_light():
    """A white light from camera-left (-X), 20 degrees up, a fifth of the irradiance ambient."""
    return directional_light(-90.0, ORDER, elevation_deg=20.0, ambient=0.2)


def texel_of(pixels, direction):
    """(row, col) of the texel whose centre is nearest `direction` in Blender's mapping."""
    dirs, _ = sh_projection.equirect_directions(*pixels.shape[:2])
    return np.unravel_index(np.argmax(dirs @ np.asarray(direction, float)), pixels.shape[:2])


def test_a_light_that_is_non_negative_is_its_own_sh():
    L = np.zeros((25, 3))
    L[0] = [2.0, 1.5, 1.0]        # a constant ...
    L[1:4] = [[0.2, 0.1, 0.0]] * 3  # ... with a gentle gradient: >= 0 everywhere
    m = light_map(L, 64)
    assert not m.fitted and m.pixels.shape == (32, 64, 3) and m.pixels.dtype == np.float32
    dirs, _ = sh_projection.equirect_directions(32, 64)
    np.testing.assert_allclose(m.pixels, sh.sh_basis(dirs, ORDER) @ L, rtol=1e-6)
    # what is left is the midpoint rule's error on 32 rows: h^2 / 24 * l(l+1) <= 8e-4 for band 1,
    # h = pi / 32
    assert irradiance_error(L, m.pixels) < 1e-3


@pytest.mark.parametrize("name, light, bound", [
    # measured 0.0069 (docs/conventions.md); the bound leaves room for other BLAS kernels
    ("camera-left + ambient", camera_left_light(), 0.012),
    # all energy in one direction: no non-negative map has the order-4 SH irradiance
    # of a delta exactly (the SH irradiance itself dips to -3.2 % of its peak); measured 0.034
    ("delta", delta([0.3, -0.5, 0.8]), 0.045),
    ("red delta", delta([0.0, 0.0, 1.0], (1.0, 0.0, 0.0)), 0.045),
    ("very bright", 1e30 * camera_left_light(), 0.012),
])
def test_extreme_lights_give_a_finite_non_negative_map_close_in_irradiance(name, light, bound):
    m = light_map(light)
    assert m.fitted  # each of these rings below 0 as plain SH
    assert np.all(np.isfinite(m.pixels)) and m.pixels.min() >= 0.0
    assert irradiance_error(light, m.pixels) < bound
    dirs, _ = sh_projection.equirect_directions(*m.pixels.shape[:2])
    assert (sh.sh_basis(dirs, ORDER) @ light).min() < 0  # so windowing was needed


def test_black_light_gives_a_black_map():
    m = light_map(np.zeros((25, 3)))
    assert not m.fitted and not m.pixels.any()
    assert irradiance_error(np.zeros((25, 3)), m.pixels) == 0.0


def test_the_fit_matches_the_irradiance_coefficients_up_to_the_regularisation():
    # stationarity of the convex problem: A_l^2 (L_lm - f_lm) = lambda c_lm on the fitted bands,
    # f the map's own SH; on the grid the fit runs on (64 x 32: the three channels are fitted
    # together) the residual is the Newton tolerance plus float32 texels (~1e-7)
    L = camera_left_light()
    m = light_map(L, 2 * COLOUR_FIT_HEIGHT)
    f = sh_projection.project_equirect(m.pixels, ORDER, precision="float64")
    keep, _ = _fitted_bands(ORDER)
    assert list(keep) == [k for k in range(25) if BAND[k] != 3]  # band 3: A_3 = 0, not fitted
    lhs = (A[BAND] ** 2)[:, None] * (L - f)
    scale = A[0] ** 2 * np.abs(L[0]).max()
    np.testing.assert_allclose(lhs[keep], REGULARISATION * m.map_coeffs[keep], atol=1e-6 * scale)
    assert not m.map_coeffs[BAND == 3].any()


def test_scaling_the_light_scales_the_map():
    # the problem is homogeneous of degree 2 in (c, L): the map of s L is s times the map of L
    L = camera_left_light()
    np.testing.assert_allclose(light_map(1e6 * L).pixels, 1e6 * light_map(L).pixels, rtol=1e-5,
                               atol=1e-5 * 1e6 * light_map(L).pixels.max())


@pytest.mark.parametrize("direction, where", [
    ((1.0, 0.0, 0.0), "centre"), ((0.0, 1.0, 0.0), "quarter"), ((0.0, -1.0, 0.0), "three quarters"),
    ((0.0, 0.0, 1.0), "top"),
])
def test_the_map_is_in_blenders_world_mapping(direction, where):
    # docs/conventions.md: the centre column looks along +X, a quarter from the left along +Y
    # (the photo camera's view), three quarters along -Y (behind the camera), row 0 is +Z
    light = np.zeros((25, 3))
    light[0] = 0.5
    light += 0.4 * delta(direction)
    m = light_map(light, 64)
    row, col = np.unravel_index(np.argmax(m.pixels[..., 1]), m.pixels.shape[:2])
    expected_col = {"centre": 32, "quarter": 16, "three quarters": 48}.get(where)
    if where == "top":
        assert row == 0
    else:
        assert abs(row - 15.5) <= 0.5 and abs(col - (expected_col - 0.5)) <= 0.5


def test_irradiance_error_sees_a_turned_map():
    L = camera_left_light()
    m = light_map(L, 128)
    turned = np.roll(m.pixels, 32, axis=1)  # 90 degrees about Z
    assert irradiance_error(L, turned) > 0.3 > 10 * irradiance_error(L, m.pixels)


@pytest.mark.parametrize("coeffs, width, match", [
    (np.zeros((24, 3)), 512, "not \\(order\\+1\\)\\^2"),
    (np.full((25, 3), np.nan), 512, "NaN"),
    (np.zeros((25, 3)), 511, "even"),
    (np.zeros((25, 3)), 4, "8..4096"),
    (np.zeros((25, 3)), 8192, "8..4096"),
    (np.zeros((25, 3)), 512.0, "integer"),
    (1e38 * camera_left_light(), 64, "too bright"),  # its hot spot is ~12x the mean
])
def test_bad_input_is_refused(coeffs, width, match):
    with pytest.raises(ValueError, match=match):
        light_map(coeffs, width)


def test_check_width():
    assert check_width(np.int64(16)) == 16
    with pytest.raises(ValueError):
        check_width(True)


# ------------------------------------------------------------------ colour: no fringes

@pytest.mark.parametrize("order", [4, 8])
def test_a_sun_and_a_sky_of_other_colours_give_no_texel_more_saturated_than_they_are(order):
    """Per-channel ringing of a two-colour light made fringes (a channel clamped at 0 where the others are
    lit: saturation 1); the map's colours now stay within the light's own."""
    pixels, L = sun_and_sky(order)
    most = most_saturated()
    m = light_map(L, 256)
    assert m.fitted  # the sun rings below 0
    # the envelope is a positive average of the light: within its colours (float64 round-off)
    field, bound = colour_envelope(L, 128)
    assert field.min() >= 0.0 and bound <= most + 1e-9
    # float32 texels: 1e-6 of relative round-off in the saturation
    assert lit_saturation(m.pixels).max() <= bound + 1e-5
    # the fit keeps the irradiance under the bound: measured 0.77 % (order 4) and 0.34 % (order 8), 0.21 %
    # and 0.26 % with the fringes; the bound is a little below the sky's own 0.65 (0.61, 0.64)
    assert irradiance_error(L, m.pixels) < 0.012
    assert m.saturation_bound == bound  # found on one grid whatever the map's size


def test_the_fringes_of_an_estimated_light_are_gone():
    L = ASTRONAUT_DRAFT
    m = light_map(L, 256)
    assert m.fitted and m.saturation_bound < 0.8  # the light's own most saturated lit colour: 0.66
    assert saturation(m.pixels).max() <= m.saturation_bound + 1e-5
    assert np.mean(lit_saturation(m.pixels, 0.01) > 0.8) == 0.0  # was 0.65 of the lit texels
    # and it keeps the estimate's irradiance (measured 0.77 %; 0.41 % with the fringes)
    assert irradiance_error(L, m.pixels) < 0.012


def test_the_colour_projection_is_the_nearest_colour_in_the_cone():
    """project_colours against a brute-force search over the cone's colours (a fine grid of its
    generators' non-negative combinations): never farther, and inside."""
    rng = np.random.default_rng(1)
    values = rng.normal(0.0, 1.0, (200, 3))
    values[:3] = [[0.5, 0.5, 0.5], [-1.0, -2.0, -0.5], [1.0, 0.0, 0.0]]
    for bound in (0.0, 0.3, 0.8, 1.0):
        x, derivative = project_colours(values, bound, jacobian=True)
        assert np.all(saturation(np.maximum(x, 0.0)) <= bound + 1e-12) and x.min() >= -1e-12
        # the cone: colours whose smallest channel is >= (1 - bound) of the largest
        grid = np.stack(np.meshgrid(*[np.linspace(0.0, 3.0, 41)] * 3, indexing="ij"), -1).reshape(-1, 3)
        inside = grid[grid.min(-1) >= (1.0 - bound) * grid.max(-1) - 1e-12]
        brute = np.array([np.min(np.linalg.norm(inside - v, axis=1)) for v in values])
        assert np.all(np.linalg.norm(values - x, axis=1) <= brute + 1e-12)
        # the derivative is the projection onto the face the colour lands on: P(v + e) = P(v) + D e
        # for a small e that stays on that face (checked along the colour itself: the cone is a cone)
        np.testing.assert_allclose(np.einsum("nij,nj->ni", derivative, values), x, atol=1e-9)


def test_bounding_the_saturation_moves_only_the_texels_above_it_and_keeps_their_sum():
    _, L = sun_and_sky(4)
    field, bound = colour_envelope(L, 16)
    rng = np.random.default_rng(0)
    pixels = rng.uniform(0.0, 1.0, (16, 32, 3)).astype(np.float32)
    pixels[0, 0] = [0.5, 0.5, 0.5]                        # grey: within any bound
    out = bound_saturation(pixels, L)
    over = saturation(pixels) > bound
    assert over.any() and not over.all()
    np.testing.assert_array_equal(out[~over], pixels[~over])
    assert saturation(out).max() <= bound + 1e-5
    np.testing.assert_allclose(out.sum(-1), pixels.sum(-1), rtol=1e-5)
    # moved toward the envelope's own colour in that direction, not toward some other hue
    target = field / field.sum(-1, keepdims=True)
    moved = out / out.sum(-1, keepdims=True)
    before = pixels / pixels.sum(-1, keepdims=True)
    assert np.all(np.linalg.norm(moved - target, axis=-1)[over] <= np.linalg.norm(before - target, axis=-1)[over] + 1e-6)


# ------------------------------------------------------------------ relight light

def _photo(path, h=40, w=30, seed=0):
    from PIL import Image

    rng = np.random.default_rng(seed)
    Image.fromarray(rng.integers(30, 220, (h, w, 3), dtype=np.uint8)).save(path)
    return path


def _run(capsys, *argv):
    from relight.cli import main

    code = main(["light", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


def test_relight_light_writes_the_map_of_the_estimated_light(model, tmp_path, capsys):
    from relight.files.photo import read_photo
    from relight.network.runtime import Relighter

    photo = _photo(tmp_path / "p.png")
    out = tmp_path / "light.exr"
    code, stdout, err = _run(capsys, photo, "--out", out, "--width", 64, "--json", "--model", model,
                             "--quality", "draft", "--matte", "network", "--threads", 1, "--lamp-free")
    assert code == 0, err
    data = json.loads(stdout)
    assert data["key"] is None
    image, _ = read_photo(photo)
    d = Relighter(model, working_size=DRAFT_SIZE).decompose(image, matte="network", augment=())  # Draft's
    np.testing.assert_allclose(data["coeffs"], d.light, atol=5e-9)  # printed with 9 decimals
    expected = light_map(d.light, 64)
    planes = read_exr(out)
    pixels = np.stack([planes[c] for c in "RGB"], axis=-1)
    np.testing.assert_array_equal(pixels, expected.pixels)  # same float32 values, lossless EXR
    assert data["map"]["width"] == 64 and data["map"]["height"] == 32
    assert data["map"]["fitted"] == expected.fitted
    np.testing.assert_allclose(data["map"]["coeffs"], expected.map_coeffs, atol=5e-9)
    assert math.isclose(data["map"]["irradiance_error"], irradiance_error(d.light, pixels), abs_tol=1e-6)

    code, stdout, _ = _run(capsys, photo, "--out", out, "--width", 64, "--model", model, "--quality", "draft",
                           "--matte", "network", "--lamp-free")
    assert code == 0 and stdout.startswith(f"wrote {out} (its irradiance is within ")


def test_relight_light_prints_the_key_light_and_writes_the_smooth_world(model, tmp_path, capsys):
    from relight.lighting.key_light import split_irradiance_error, split_light
    from relight.files.photo import read_photo
    from relight.network.runtime import Relighter

    photo = _photo(tmp_path / "p.png")
    out = tmp_path / "light.exr"
    code, stdout, err = _run(capsys, photo, "--out", out, "--width", 64, "--json", "--model", model,
                             "--quality", "draft", "--matte", "network", "--threads", 1)
    assert code == 0, err
    data = json.loads(stdout)
    image, _ = read_photo(photo)
    d = Relighter(model, working_size=DRAFT_SIZE).decompose(image, matte="network", augment=())  # Draft's
    split = split_light(d.light, 64)
    planes = read_exr(out)
    np.testing.assert_array_equal(np.stack([planes[c] for c in "RGB"], axis=-1), split.pixels)
    key = data["key"]
    assert set(key) >= {"direction", "azimuth_deg", "elevation_deg", "colour", "strength", "angle_deg", "lamp"}
    np.testing.assert_allclose(key["direction"], split.key.direction, atol=1e-6)
    assert abs(np.linalg.norm(key["direction"]) - 1.0) < 1e-5
    np.testing.assert_allclose(key["colour"], split.key.colour, atol=1e-6)
    assert max(key["colour"]) == pytest.approx(1.0, abs=1e-6) or split.key.strength == 0.0
    assert key["strength"] == pytest.approx(split.key.blender_strength, abs=1e-6)
    assert key["angle_deg"] == pytest.approx(split.key.angle_deg, abs=1e-3)
    assert data["map"]["irradiance_error"] == pytest.approx(split_irradiance_error(split, ORDER), abs=1e-6)
    code, stdout, _ = _run(capsys, photo, "--out", out, "--width", 64, "--model", model, "--quality", "draft",
                           "--matte", "network")
    assert code == 0 and "key light from azimuth" in stdout


def test_relight_light_refuses_an_output_that_is_its_photo_and_a_second_writer(model, tmp_path, capsys):
    from fuzz_support import writer_holding

    photo = tmp_path / "p.exr"  # an EXR photo is a valid input and a valid --out
    write_exr(photo, {c: np.full((40, 30), 0.3, np.float32) for c in "RGB"})
    before = photo.read_bytes()
    code, _, err = _run(capsys, photo, "--out", photo, "--model", model, "--quality", "draft", "--matte", "network")
    assert code == 2 and err.count("\n") == 1 and "is the photo" in err, err
    assert photo.read_bytes() == before
    out = tmp_path / "light.exr"
    with writer_holding(out) as other:
        code, _, err = _run(capsys, photo, "--out", out, "--model", model, "--quality", "draft", "--matte", "network")
        assert code == 2 and f"(process {other.pid}) is writing {out}" in err, err
        assert not out.exists()
    # issue 48: the same map by another name of its folder shares the lock
    (tmp_path / "up").symlink_to(tmp_path, target_is_directory=True)
    with writer_holding(out) as other:
        code, _, err = _run(capsys, photo, "--out", tmp_path / "up" / "light.exr", "--model", model, "--quality",
                            "draft", "--matte", "network")
        assert code == 2 and f"(process {other.pid}) is writing {tmp_path / 'up' / 'light.exr'}" in err, err
        assert not out.exists()
    code, _, err = _run(capsys, photo, "--out", out, "--model", model, "--quality", "draft", "--matte", "network")
    assert code == 0 and out.is_file(), err
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no lock file left


def test_relight_image_takes_a_sun(model, tmp_path, capsys):
    from relight.cli import main
    from relight.files.photo import read_photo
    from relight.network.runtime import Relighter

    photo = _photo(tmp_path / "p.png")
    out = tmp_path / "relit.exr"
    code = main(["image", str(photo), "--light", "sun:30,45,10", "--out", str(out), "--model", model,
                 "--quality", "draft", "--matte", "network", "--threads", "1"])
    _, err = capsys.readouterr()
    assert code == 0, err
    image, _ = read_photo(photo)
    d = Relighter(model, working_size=DRAFT_SIZE).decompose(image, matte="network", augment=())  # Draft's
    relit = d.relight(sh_light("sun:30,45,10", d.sh_order))
    got = np.stack([read_exr(out)[c] for c in "RGB"], axis=-1)
    np.testing.assert_allclose(got, relit, atol=1e-5, rtol=1e-4)
    for bad in ("sun:30", "sun:30,100", "sun:a,b"):
        code = main(["image", str(photo), "--light", bad, "--out", str(tmp_path / "x.png"), "--model", model,
                     "--matte", "network"])
        _, err = capsys.readouterr()
        assert code == 2 and len(err.strip().splitlines()) == 1 and "sun:AZIMUTH,ELEVATION" in err, err
        assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("argv, match", [
    (["{photo}", "--out", "{tmp}/l.png"], "--out must end in .exr"),
    (["{tmp}/missing.jpg", "--out", "{tmp}/l.exr"], "no such file"),
    (["{photo}", "--out", "{tmp}/no/such/folder/l.exr"], "output folder does not exist"),
    (["{photo}", "--out", "{tmp}/l.exr", "--width", "513"], "even"),
    (["{photo}", "--out", "{tmp}/l.exr", "--width", "wide"], "invalid int"),
    (["{photo}", "--out", "{tmp}/l.exr", "--mask", "{tmp}/missing_mask.png"], "missing_mask"),
    (["{photo}"], "required"),
])
def test_bad_input_one_line_exit_2_nothing_written(model, tmp_path, capsys, argv, match):
    photo = _photo(tmp_path / "p.png")
    existing = tmp_path / "l.exr"
    existing.write_bytes(b"keep me")  # a failed run leaves a previous output as it was
    argv = [a.format(photo=photo, tmp=tmp_path) for a in argv] + ["--model", model, "--matte", "network"]
    code, out, err = _run(capsys, *argv)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and match in err, err
    assert existing.read_bytes() == b"keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["l.exr", "p.png"]
