"""Runtime: hash check, decomposition, relighting maths, compositing, light sources, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from export.random_model import export_random_model
from relight.network import composite
from relight import models
from relight.lighting import sh
from relight.files.exr import write_exr
from relight.network.prt import to_network_input
from relight.network.decomposition import DETAIL_EPS, DETAIL_MAX
from relight.lighting.light import LightCache, sh_light
from relight.imaging.resample import bilinear_rows
from relight.network.runtime import Relighter

ORDER = 4
N = (ORDER + 1) ** 2
EPS32 = float(np.finfo(np.float32).eps)


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    path, _, _ = export_random_model(tmp_path_factory.mktemp("rt") / "tiny.onnx", seed=7,
                                     sh_order=ORDER, width=4, depth=2)
    return path


@pytest.fixture(scope="module")
def relighter(model_path):
    return Relighter(model_path, threads=1, working_size=64)


def _photo(h=48, w=64, seed=0):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w] / max(h, w)
    base = np.stack([0.3 + 0.4 * x, 0.2 + 0.5 * y, 0.5 - 0.3 * x * y], axis=-1)
    return (base * rng.uniform(0.7, 1.0, (h, w, 3))).astype(np.float32)


def _formula(d, L):
    """max(0, albedo * (T . L) + E . L) in float64, and a bound on its float32 rounding error."""
    L = np.asarray(L, np.float64)
    a, T, E = (np.asarray(v, np.float64) for v in (d.albedo, d.transport, d.residual))
    exact = a * (T @ L) + E @ L
    # float32 dot products of n terms: error <= n * eps * sum |terms| (Higham);
    # the light itself was rounded to float32 (relative eps per coefficient).
    # |max(0, x) - max(0, y)| <= |x - y|: the clamp keeps the bound
    bound = (N + 2) * EPS32 * (np.abs(a) * (np.abs(T) @ np.abs(L)) + np.abs(E) @ np.abs(L))
    return np.maximum(exact, 0.0), bound + 1e-30


def test_own_light_reproduces_the_networks_reconstruction(relighter):
    photo = _photo()
    mask = np.ones(photo.shape[:2], np.float32)
    d = relighter.decompose(photo, mask, augment=())  # the network once (the default, Balanced, adds a mirrored run)
    assert d.box == (0, 48, 0, 64) and d.working_size == (48, 64)
    # the network's own outputs for the same input
    raw = relighter.run(to_network_input(photo, mask).transpose(2, 0, 1)[None])
    np.testing.assert_array_equal(d.albedo, raw["albedo"][0].transpose(1, 2, 0))
    np.testing.assert_array_equal(d.light, raw["light"][0])
    out = d.relight(sh_light(d, ORDER))
    exact, bound = _formula(d, d.light)
    assert np.all(np.abs(out - exact) <= bound)


def test_sh_light_matches_the_formula_on_matte_pixels(relighter):
    photo = _photo(seed=1)
    mask = np.zeros(photo.shape[:2], np.float32)
    mask[5:40, 10:50] = 1.0
    d = relighter.decompose(photo, mask, working_size=44)  # the crop's own size: no resampling
    rng = np.random.default_rng(2)
    L = rng.normal(0, 0.3, (N, 3))
    out = d.relight(L)
    y0, y1, x0, x1 = d.box
    assert (y0, y1, x0, x1) == (3, 42, 8, 52)  # mask box + 2 px margin
    exact, bound = _formula(d, L.astype(np.float32))
    inside = mask[y0:y1, x0:x1] > 0
    assert np.all(np.abs(out[y0:y1, x0:x1][inside] - exact[inside]) <= bound[inside])


def test_outside_matte_pixels_are_untouched_bit_for_bit(relighter):
    photo = _photo(seed=2)
    mask = np.zeros(photo.shape[:2], np.float32)
    mask[10:30, 20:40] = np.linspace(0, 1, 20)[None, :]  # soft edge, zeros in column 20
    d = relighter.decompose(photo, mask)
    out = d.relight(sh_light("studio", ORDER, rotation_deg=45), exposure_ev=1.5)
    outside = mask == 0
    np.testing.assert_array_equal(out[outside], photo[outside])
    assert not np.allclose(out[~outside], photo[~outside])
    # and without a mask: pixels the predicted matte leaves out, and everything outside the crop
    d2 = relighter.decompose(photo, matte="network")
    out2 = d2.relight(sh_light("studio", ORDER))
    alpha = d2.full_alpha()
    np.testing.assert_array_equal(out2[alpha == 0], photo[alpha == 0])


def test_rotating_by_360_degrees_is_identity(relighter):
    d = relighter.decompose(_photo(seed=3), np.ones((48, 64), np.float32))
    L = np.random.default_rng(4).normal(0, 0.3, (N, 3))
    a, b = d.relight(L), d.relight(sh_light(L, ORDER, rotation_deg=360.0))
    np.testing.assert_array_equal(a, b)  # whole turns are recognised exactly
    c = d.relight(sh_light(L, ORDER, rotation_deg=360.0 + 1e-9))
    # a rotation matrix 1e-9 rad from identity: coefficients move by ~1e-9 * l
    np.testing.assert_allclose(c, a, atol=1e-6)
    Lr = sh_light(L, ORDER, rotation_deg=123.0)
    back = sh_light(Lr, ORDER, rotation_deg=237.0)
    np.testing.assert_allclose(back, L, atol=1e-9)


def test_exposure_plus_one_doubles_the_persons_radiance(relighter):
    mask = np.zeros((48, 64), np.float32)
    mask[4:44, 8:56] = 1.0
    d = relighter.decompose(_photo(seed=4), mask)
    L = sh_light("studio", ORDER)
    a, b = d.relight(L), d.relight(L, exposure_ev=1.0)
    person = mask == 1
    # scaling the light by 2 is exact in binary floating point, and alpha == 1 there
    np.testing.assert_array_equal(b[person], 2.0 * a[person])
    np.testing.assert_array_equal(b[~person], a[~person])


def test_sh_of_any_order_is_truncated_or_zero_padded(relighter):
    d = relighter.decompose(_photo(seed=5), np.ones((48, 64), np.float32))
    rng = np.random.default_rng(6)
    low = rng.normal(0, 0.3, (9, 3))
    padded = np.zeros((N, 3))
    padded[:9] = low
    np.testing.assert_array_equal(d.relight(low), d.relight(padded))
    high = rng.normal(0, 0.3, (49, 3))
    np.testing.assert_array_equal(d.relight(high), d.relight(high[:N]))


def test_light_transfer_uses_the_other_photos_light(relighter):
    mask = np.ones((48, 64), np.float32)
    d1 = relighter.decompose(_photo(seed=6), mask)
    d2 = relighter.decompose(_photo(seed=7)[::-1].copy(), mask)
    assert not np.allclose(d1.light, d2.light)
    np.testing.assert_array_equal(d1.relight(sh_light(d2, ORDER)), d1.relight(d2.light))


def test_hdr_map_light_is_projected_and_normalized(relighter, tmp_path):
    d = relighter.decompose(_photo(seed=8), np.ones((48, 64), np.float32))
    h, w = 64, 128
    value = 3.0
    path = tmp_path / "white.exr"
    write_exr(path, {c: np.full((h, w), value, np.float32) for c in "RGB"})
    # a constant map has only L00 = value * integral(Y00) = value * 2 sqrt(pi)
    cache = LightCache()
    raw = sh_light(str(path), ORDER, normalize=False, cache=cache)
    # (the row quadrature is midpoint-like: its error on the zonal terms falls as
    # 1/H^2, measured 5e-3 of L00 at H = 16, so 1e-3 holds with margin at H = 64)
    np.testing.assert_allclose(raw[0], value * 2 * math.sqrt(math.pi), rtol=1e-3)
    np.testing.assert_allclose(raw[1:], 0, atol=1e-3 * raw[0, 0])
    norm = sh_light(path, ORDER, cache=cache)
    assert sh.mean_luminance(norm) == pytest.approx(0.8, rel=1e-9)
    with pytest.raises(ValueError, match="SH coefficients"):
        d.relight(path)  # the runtime takes coefficients only: relight.lighting.light resolves files
    # the cache notices a changed file
    write_exr(path, {c: np.full((h, w), 2 * value, np.float32) for c in "RGB"})
    np.testing.assert_allclose(sh_light(path, ORDER, normalize=False, cache=cache), 2 * raw, rtol=1e-6)


def test_layers_recompose_the_relit_person(relighter):
    mask = np.zeros((48, 64), np.float32)
    mask[2:46, 2:62] = 1.0
    d = relighter.decompose(_photo(seed=9), mask)
    assert d.box == (0, 48, 0, 64) and d.working_size == (48, 64)  # no resampling
    L = np.random.default_rng(10).normal(0, 0.3, (N, 3))
    lay = d.layers(L)
    assert set(lay) == {"albedo", "shading", "residual", "alpha"}
    assert lay["albedo"].shape == (48, 64, 3) and lay["alpha"].shape == (48, 64)
    np.testing.assert_array_equal(lay["alpha"], mask)
    out = d.relight(L)
    person = mask == 1
    recomposed = lay["albedo"] * lay["shading"] + lay["residual"]
    assert recomposed[person].min() < 0  # this light rings below 0 on some pixels: the layers keep the sign
    # one extra float32 rounding each for the product and the sum; the relit pass is clamped at 0
    np.testing.assert_allclose(np.maximum(recomposed[person], 0), out[person], rtol=4 * EPS32, atol=1e-7)
    own = d.layers()
    exact, bound = _formula(d, d.light)
    y0, y1, x0, x1 = d.box
    np.testing.assert_allclose(own["shading"][y0:y1, x0:x1][person[y0:y1, x0:x1]],
                               (np.asarray(d.transport, np.float64) @ d.light)[person[y0:y1, x0:x1]],
                               rtol=1e-5, atol=1e-6)


def test_bilinear_upsampling_reproduces_affine_ramps():
    h, w = 5, 7
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    src = (0.5 * y - 0.25 * x + 1.0)[..., None].astype(np.float32)
    H, W = 15, 28
    out = bilinear_rows(src, H, W)[..., 0]
    # output pixel centres map to source coordinates (i + 0.5) * h / H - 0.5
    sy = (np.arange(H) + 0.5) * h / H - 0.5
    sx = (np.arange(W) + 0.5) * w / W - 0.5
    interior = (sy >= 0) & (sy <= h - 1)
    icol = (sx >= 0) & (sx <= w - 1)
    expect = 0.5 * sy[:, None] - 0.25 * sx[None, :] + 1.0
    np.testing.assert_allclose(out[np.ix_(interior, icol)], expect[np.ix_(interior, icol)], atol=1e-6)
    np.testing.assert_array_equal(bilinear_rows(src, h, w), src)  # same size: identity
    np.testing.assert_allclose(bilinear_rows(src, H, W, 3, 9), bilinear_rows(src, H, W)[3:9])


def test_large_photo_keeps_fine_detail_and_compositing_is_consistent(relighter):
    # 4x the working size: the network sees a box-filtered crop
    H, W = 192, 256
    rng = np.random.default_rng(11)
    photo = (0.4 + 0.2 * rng.uniform(size=(H, W, 3))).astype(np.float32)
    mask = np.ones((H, W), np.float32)
    d = relighter.decompose(photo, mask)
    assert d.working_size == (48, 64)
    # box filter of a 4x4 block is its mean
    np.testing.assert_allclose(d.photo_working, photo.reshape(48, 4, 64, 4, 3).mean(axis=(1, 3)),
                               rtol=1e-5)
    L = np.random.default_rng(12).normal(0, 0.3, (N, 3))
    L[0] = [2.0, 2.0, 2.0]
    flat = d.relight(L, detail=False)
    np.testing.assert_allclose(flat, bilinear_rows(d.relit_at_working_size(L), H, W), rtol=1e-6, atol=1e-7)
    detailed = d.relight(L)
    # detail: the full-resolution photo times the upsampled quotient relit / photo
    eps = 1e-3
    quotient = (d.relit_at_working_size(L) + eps) / (d.photo_working + eps)
    expect = np.maximum((photo + eps) * bilinear_rows(quotient, H, W) - eps, 0)
    np.testing.assert_allclose(detailed, expect, rtol=1e-5, atol=1e-6)
    # a smooth photo has no detail to restore: both ways agree to the resampling error
    smooth = np.broadcast_to(np.linspace(0.3, 0.6, W, dtype=np.float32)[None, :, None], (H, W, 3)).copy()
    ds = relighter.decompose(smooth, mask)
    np.testing.assert_allclose(ds.relight(L), ds.relight(L, detail=False), rtol=0.05, atol=1e-3)


def test_decompose_without_mask_finds_a_box_and_is_deterministic(relighter):
    photo = _photo(96, 128, seed=13)
    a, b = relighter.decompose(photo, matte="network"), relighter.decompose(photo, matte="network")
    y0, y1, x0, x1 = a.box
    assert 0 <= y0 < y1 <= 96 and 0 <= x0 < x1 <= 128
    assert a.box == b.box and max(a.working_size) == 64
    L = sh_light("studio", ORDER)
    np.testing.assert_array_equal(a.relight(L), b.relight(L))
    assert np.all((a.alpha == 0) | (a.alpha >= 1 / 255))


def test_tampered_model_is_refused(model_path, tmp_path):
    bad = tmp_path / "m.onnx"
    data = bytearray(model_path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    bad.write_bytes(bytes(data))
    models.sidecar_path(bad).write_text(models.sidecar_path(model_path).read_text())
    with pytest.raises(ValueError, match="SHA-256 mismatch.*refusing"):
        Relighter(bad)
    models.sidecar_path(bad).unlink()
    with pytest.raises(ValueError, match="no SHA-256"):
        Relighter(bad)
    with pytest.raises(ValueError, match="not found"):
        Relighter(tmp_path / "absent.onnx")


def test_graph_without_relight_metadata_is_refused(model_path, tmp_path):
    import onnx

    m = onnx.load(str(model_path))
    del m.metadata_props[:]
    path = tmp_path / "plain.onnx"
    onnx.save(m, str(path))
    models.write_sidecar(path)
    with pytest.raises(ValueError, match="not a relighting model"):
        Relighter(path)


@pytest.mark.parametrize("photo, mask, message", [
    (np.zeros((48, 64)), None, "shape"),
    (np.zeros((48, 64, 3), np.uint8), None, "floating"),
    (np.full((48, 64, 3), np.nan, np.float32), None, "NaN"),
    (np.zeros((1, 64, 3), np.float32), None, "too small"),
    (np.zeros((48, 64, 3), np.float32), np.ones((48, 63)), "mask must be"),
    (np.zeros((48, 64, 3), np.float32), np.zeros((48, 64)), "empty"),
    (np.zeros((48, 64, 3), np.float32), np.full((48, 64), 2.0), r"\[0, 1\]"),
    (np.zeros((48, 64, 3), np.float32), np.full((48, 64), np.nan), "finite"),
])
def test_bad_decompose_input(relighter, photo, mask, message):
    with pytest.raises(ValueError, match=message):
        relighter.decompose(photo, mask)


@pytest.mark.parametrize("kwargs, message", [
    (dict(coeffs=np.zeros((5, 3))), "coeff|square|order"),
    (dict(coeffs=np.full((9, 3), np.nan)), "NaN|finite"),
    (dict(coeffs=object()), "light must be"),
    (dict(coeffs="studio"), "SH coefficients"),
    (dict(coeffs=np.zeros((9, 3)), exposure_ev="bright"), "exposure"),
    (dict(coeffs=np.zeros((9, 3)), exposure_ev=1e6), "exposure"),
])
def test_bad_relight_input(relighter, kwargs, message):
    d = relighter.decompose(_photo(), np.ones((48, 64), np.float32))
    with pytest.raises(ValueError, match=message):
        d.relight(**kwargs)


@pytest.mark.parametrize("kwargs, message", [
    (dict(source=np.zeros((5, 3))), "coeff|square|order"),
    (dict(source=np.full((9, 3), np.nan)), "NaN|finite"),
    (dict(source=object()), "light must be"),
    (dict(source="no-such-preset"), "neither a file nor a preset"),
    (dict(source=""), "empty"),
    (dict(source=np.zeros((9, 3)), rotation_deg=float("nan")), "finite"),
    (dict(source=np.zeros((9, 3)), rotation_deg="west"), "degrees"),
])
def test_bad_light_source(kwargs, message):
    with pytest.raises(ValueError, match=message):
        sh_light(order=ORDER, **kwargs)


def test_bad_session_options(model_path):
    from relight.models.session import cores_available

    cores = cores_available()
    for threads in (0, -1, cores + 1, 1.5, True, "2"):  # bounded like `relight image --threads`
        with pytest.raises(ValueError, match=rf"threads must be an integer in \[1, {cores}\]"):
            Relighter(model_path, threads=threads)
    assert Relighter(model_path, threads=cores).session is not None
    with pytest.raises(ValueError, match="working size"):
        Relighter(model_path, working_size="draft")  # a preset's size is quality.preset(key).working_size
    with pytest.raises(ValueError, match="working size"):
        Relighter(model_path, working_size=8)


def test_sessions_do_not_spin_between_runs(model_path):
    """Every session the runtime opens (the network's and the segmenters') has onnxruntime's
    busy-waiting off: its pool threads would otherwise take the cores from the numpy work
    between runs (docs/TRADEOFFS.md measures what it cost)."""
    from relight.person import matte
    from relight.models.session import SPINNING_KEY

    sessions = [Relighter(model_path, threads=1).session] + \
        [matte._session(kind) for kind in ("selfie", "detector", "pose")]
    for s in sessions:
        assert s.get_session_options().get_session_config_entry(SPINNING_KEY) == "0"


def test_runtime_modules_import_neither_torch_nor_bpy_nor_onnx():
    import subprocess
    import sys

    code = ("import sys, relight.network.runtime, relight.files.photo, relight.command.cli_image, relight.models, relight.cli; "
            "relight.cli.build_parser(); "
            "print(sorted(m for m in ('torch', 'bpy', 'onnx', 'onnxconverter_common') if m in sys.modules))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "[]"


def _reference_relight(d, L, detail: bool, exposure_ev: float) -> np.ndarray:
    """relight() written out whole-frame with bilinear_rows and full_alpha (no tiles, no threads)."""
    s = np.float32(2.0 ** exposure_ev)
    eps = np.float32(DETAIL_EPS)
    y0, y1, x0, x1 = d.box
    crop = d.photo[y0:y1, x0:x1]
    relit = d.relit_at_working_size(L)
    if detail:
        q = np.clip((relit + eps) / (d.photo_working + eps), 0, DETAIL_MAX) * s
        person = np.maximum((crop + eps) * bilinear_rows(q, y1 - y0, x1 - x0) - eps * s, 0)
    else:
        person = bilinear_rows(relit * s, y1 - y0, x1 - x0)
    a = d.full_alpha()[y0:y1, x0:x1, None]
    out = d.photo.copy()
    out[y0:y1, x0:x1] = person * a + (1 - a) * crop
    return out


@pytest.mark.parametrize("masked", [True, False])
def test_tiled_threaded_compositing_equals_the_whole_frame_formula(relighter, monkeypatch, masked):
    # tiles of 2 rows and bands of 8: many tiles per band, several bands on the thread pool
    H, W = 150, 200
    monkeypatch.setattr(composite, "TILE_VALUES", 3 * W * 2)
    monkeypatch.setattr(composite, "BAND_ROWS", 8)
    photo = _photo(H, W, seed=15)
    mask = None
    if masked:
        mask = np.zeros((H, W), np.float32)
        mask[20:140, 30:170] = np.linspace(0, 1, 140)[None, :]  # soft edge
    d = relighter.decompose(photo, mask, matte="network")  # unmasked: the network's alpha (a random image)
    assert d.working_size != (d.box[1] - d.box[0], d.box[3] - d.box[2])  # resampled
    L = np.random.default_rng(16).normal(0, 0.3, (N, 3))
    L[0] = 2.0
    for detail in (True, False):
        for ev in (0.0, 1.3):
            # same float32 operations in the same order, only split into tiles: equal bit for bit
            np.testing.assert_array_equal(d.relight(L, exposure_ev=ev, detail=detail),
                                          _reference_relight(d, L, detail, ev))


def test_negative_light_is_clamped_and_counted(relighter):
    photo = _photo(seed=17)
    mask = np.zeros((48, 64), np.float32)
    mask[4:44, 6:58] = 1.0
    mask[4:44, 6:10] = 0.5
    d = relighter.decompose(photo, mask, working_size=58)
    assert d.working_size == (d.box[1] - d.box[0], d.box[3] - d.box[2])  # the crop's own size
    L = np.random.default_rng(18).normal(0, 0.3, (N, 3))  # no DC bias: T.L rings below 0 often
    small = d.relit_at_working_size(L)
    assert small.min() >= 0
    f = (np.asarray(d.albedo, np.float64) * (np.asarray(d.transport, np.float64) @ L)
         + np.asarray(d.residual, np.float64) @ L)
    _, bound = _formula(d, L.astype(np.float32))
    inside = d.alpha > 0
    # float32 rounding may flip the sign only where |f| is within the rounding bound
    surely = np.count_nonzero(inside & np.any(f < -bound, axis=-1))
    maybe = np.count_nonzero(inside & np.any(f < bound, axis=-1))
    stats = d.last_stats
    assert 0 < surely <= stats.clamped <= maybe
    assert stats.pixels == np.count_nonzero(inside)
    assert stats.fraction == stats.clamped / stats.pixels
    assert abs(stats.darkest - f[inside].min()) <= bound.max()
    # where the formula is clearly positive the clamp changes nothing
    clear = inside[..., None] & (f > bound)
    np.testing.assert_allclose(small[clear], f[clear], rtol=(N + 2) * EPS32 * 10, atol=bound.max())
    out = d.relight(L)
    assert out.min() >= 0 and d.last_stats == stats


def test_the_light_is_exposed_once_per_light_and_exposure(relighter):
    d = relighter.decompose(_photo(), np.ones((48, 64), np.float32))
    n = sh.num_coeffs(d.sh_order)
    light = np.random.default_rng(4).normal(0.0, 0.3, (sh.num_coeffs(d.sh_order + 1), 3))  # one band more: cut
    L = d.exposed_light(light, 1.0)
    assert L.shape == (n, 3) and L.dtype == np.float32 and not L.flags.writeable
    np.testing.assert_allclose(L, 2.0 * light[:n], rtol=1e-6)
    assert d.exposed_light(light.copy(), 1.0) is L  # the same values: the same exposed array
    assert d.exposed_light(light, 0.5) is not L and d.exposed_light(light[:n] * 1.5, 1.0) is not L
    layers = d.layers(light, 1.0)  # one exposed light for all layers, same values as one layer at a time
    for name in ("shading", "residual"):
        np.testing.assert_array_equal(layers[name], d.layer(name, light, 1.0))
    with pytest.raises(ValueError, match=r"exposure must be a finite number of EV within \+-64"):
        d.exposed_light(light, 64.5)


def test_albedo_layer_carries_the_photos_full_resolution_texture():
    """Resampled crop: the albedo layer is the full-resolution photo times the upsampled
    quotient albedo / photo of working resolution, so under a smooth shading S it is the
    textured photo / S, which plain upsampling of the working albedo would blur away."""
    from relight.network.decomposition import Decomposition
    from relight.imaging.resample import resize_linear

    H, W, h, w = 64, 96, 16, 24
    rng = np.random.default_rng(3)
    photo = rng.uniform(0.2, 0.4, (H, W, 3)).astype(np.float32)  # per-pixel texture
    photo_w = resize_linear(photo, h, w)
    shading = np.float32(0.8)
    transport = np.zeros((h, w, N), np.float32)
    transport[..., 0] = 1.0
    light = np.zeros((N, 3), np.float32)
    light[0] = shading
    alpha = np.ones((h, w), np.float32)
    d = Decomposition(albedo=photo_w / shading, transport=transport, residual=np.zeros_like(transport),
                      light=light, alpha=alpha, box=(0, H, 0, W), working_size=(h, w), photo=photo,
                      photo_working=photo_w, sh_order=ORDER)
    albedo = d.layer("albedo")
    # quotient (p_w / S + eps) / (p_w + eps) = 1/S (1 + eps (S - 1) / (p_w + eps)): relative error
    # below DETAIL_EPS / 0.2 per pixel, plus float32 rounding of the product
    np.testing.assert_allclose(albedo, photo / shading, rtol=DETAIL_EPS / 0.2 + 1e-5)
    np.testing.assert_array_equal(d.layers()["albedo"], albedo)  # layers() gives the same layer
    # the texture is there: far from what plain upsampling of the working albedo gives
    plain = d._to_full(photo_w / shading)
    assert np.abs(albedo - plain).mean() > 0.02


def test_a_bare_decompose_is_balanced():
    """Issue 48: Relighter().decompose(photo) with no options, as the docs show it, gives what
    Balanced (relight image's default) gives: the default model at Balanced's working size with
    Balanced's decompose_options. It gave the network once (up to 112 8-bit codes off Balanced on
    astronaut.jpg, 246 off Draft). The two are computed by one process: within the float32 rounding
    bound of the shipped graph (tests/relight/network/test_relit_golden.py: 2 * sum of gamma_n over its fan-ins,
    of each array's peak), and the network once is much farther than that from both."""
    from test_relit_golden import ROOT, graph_fan_ins, graph_rounding_bound

    from relight.files.photo import read_photo
    from relight.network.quality import preset

    photo, _ = read_photo(ROOT / "relight" / "data" / "examples" / "astronaut.jpg")
    balanced = preset("balanced")
    bare = Relighter(threads=1).decompose(photo)
    explicit = Relighter(models.default_model_path(), threads=1, working_size=balanced.working_size) \
        .decompose(photo, **balanced.decompose_options())
    once = Relighter(threads=1).decompose(photo, augment=())
    assert bare.choices == explicit.choices and bare.choices["augment"] == [[1.0, True]]
    bound = graph_rounding_bound(graph_fan_ins(models.default_model_path()))
    light = sh_light("studio", bare.sh_order, rotation_deg=90.0)
    far = []
    for name, get in (("light", lambda d: d.light), ("albedo", lambda d: d.albedo),
                      ("transport", lambda d: d.transport), ("relit", lambda d: d.relight(light))):
        ref = np.asarray(get(explicit), np.float64)
        tol = bound * np.abs(ref).max()
        assert np.abs(np.asarray(get(bare), np.float64) - ref).max() <= tol, name
        far.append(np.abs(np.asarray(get(once), np.float64) - ref).max() / tol)
    assert min(far) > 10, far  # the network once is no rounding away from Balanced


def _documented_calls(text: str) -> list[tuple[str, str]]:
    """(name, parameter list) of every `name(params)` on the indented lines of
    docs/ARCHITECTURE.md's "Runtime" section (its call forms)."""
    import re

    section = text.split("## Runtime (", 1)[1].split("\n## ", 1)[0]
    lines = [line for line in section.splitlines() if line.startswith("    ")]
    return [(m[0].rsplit(".", 1)[-1], m[1]) for line in lines for m in re.findall(r"([\w.]+)\(([^()]*)\)", line)]


def test_the_architectures_call_forms_bind_to_the_runtimes_signatures():
    """Issue 48: docs/ARCHITECTURE.md showed `sh_light(source, order, rotation_deg=0.0)`, so a
    reader passed the rotation third; it is keyword-only and that raised. Each form shown must
    bind: a parameter shown before `*` is positional in the code, every one shown exists, and a
    default shown is the code's."""
    import ast
    import inspect
    from pathlib import Path

    from relight.lighting.light import sh_light
    from relight.network.decomposition import Decomposition

    code = {"Relighter": Relighter.__init__, "decompose": Relighter.decompose, "sh_light": sh_light,
            "relight": Decomposition.relight}
    text = (Path(__file__).resolve().parents[3] / "docs" / "ARCHITECTURE.md").read_text(encoding="utf-8")
    calls = _documented_calls(text)
    assert sorted({name for name, _ in calls}) == sorted(code), calls
    for name, params in calls:
        shown = ast.parse(f"def f({params}): pass").body[0].args
        real = [p for p in inspect.signature(code[name]).parameters.values() if p.name != "self"]
        positional = [p.name for p in real if p.kind == p.POSITIONAL_OR_KEYWORD]
        assert [a.arg for a in shown.args] == positional[:len(shown.args)], (name, params)
        by_name = {p.name: p for p in real}
        defaults = dict(zip([a.arg for a in shown.args][::-1], shown.defaults[::-1]))
        defaults.update({a.arg: d for a, d in zip(shown.kwonlyargs, shown.kw_defaults) if d is not None})
        for arg, default in defaults.items():
            assert by_name[arg].default == ast.literal_eval(default), (name, arg)
        assert {a.arg for a in shown.kwonlyargs} <= set(by_name), (name, params)
