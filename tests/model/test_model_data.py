"""Scene loading, cropping, splits (held-out lights never train), samples and their physics."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from model.samples import data, data_augment, data_crops, data_splits
from relight.imaging.box import Box
from model.samples.synthetic import GLOSS, write_analytic_dataset
from relight.lighting import presets
from relight.imaging.colour import LUMINANCE_WEIGHTS
from relight.network.prt import to_network_input

HELD_OUT = frozenset(presets.HELD_OUT)


pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    folder = tmp_path_factory.mktemp("analytic")
    return write_analytic_dataset(folder, n_scenes=4, size=32, order=4, lights=("studio", "city", "venice"))


def test_crop_box_is_a_padded_square_around_the_mask():
    alpha = np.zeros((20, 30))
    alpha[5:9, 10:20] = 1.0  # bbox 4 x 10
    box = data_crops.crop_box(alpha, padding=2)  # rows then columns, as every Box
    assert box == Box(0, 14, 8, 22)  # 14 wide with the padding; centred vertically: (14 - 8) // 2 = 3 above
    with pytest.raises(ValueError, match="empty alpha"):
        data_crops.crop_box(np.zeros((4, 4)), 1)


def test_crop_resize_zero_extends_and_is_linear():
    rng = np.random.default_rng(0)
    planes = rng.uniform(size=(10, 10, 2)).astype(np.float32)
    out = data_crops.crop_resize(planes, Box(-2, 10, -2, 10), 12)  # no resize: exact copy with a zero border
    assert out.shape == (2, 12, 12)
    np.testing.assert_array_equal(out[:, 2:, 2:], planes.transpose(2, 0, 1))
    assert not out[:, :2].any() and not out[:, :, :2].any()
    # resizing is linear: resize(a + 2b) = resize(a) + 2 resize(b) (float32 round-off)
    a, b = planes[..., :1], planes[..., 1:]
    lhs = data_crops.crop_resize(a + 2 * b, Box.whole(10, 10), 4)
    rhs = data_crops.crop_resize(a, Box.whole(10, 10), 4) + 2 * data_crops.crop_resize(b, Box.whole(10, 10), 4)
    np.testing.assert_allclose(lhs, rhs, rtol=1e-5, atol=1e-6)


def test_split_by_body_is_deterministic_and_disjoint(scenes):
    train, val = data_splits.split_by_body(scenes, 0.25, seed=3)
    assert (train, val) == data_splits.split_by_body(scenes, 0.25, seed=3)
    assert len(val) == 1 and len(train) == 3 and not set(train) & set(val)
    bodies = lambda ps: {data_splits.body_key(json.loads(p.read_text())) for p in ps}
    assert not bodies(train) & bodies(val)
    with pytest.raises(ValueError):
        data_splits.split_by_body(scenes, 1.0)


def test_training_samples_never_use_held_out_lights(scenes):
    bank = [("park", np.eye(25, 3, dtype=np.float32) + 1.0)]
    ds = data.TrainingScenes(scenes, 32, 4, padding=2, extra_lights=bank, extra_light_prob=0.5, held_out=HELD_OUT)
    seen = set()
    for epoch in range(6):
        for i in range(len(ds)):
            s = ds.item(i, epoch)
            seen |= {s["light_name"], s["target_light_name"]}
    # the scenes' venice renders exist but never reach training; the others do
    assert seen <= {"studio", "city", "park"} and {"studio", "city", "park"} <= seen
    with pytest.raises(AssertionError, match="held-out"):
        data.TrainingScenes(scenes, 32, 4, extra_lights=[("venice", bank[0][1])], held_out=HELD_OUT)


def test_light_map_names_tell_the_farms_maps_apart():
    # the farm records the map in `name` and only its kind in `source` ("blender", "bundled",
    # "sky"): Blender's forest and the bundled forest are different maps
    farm = [{"name": "blender:forest", "source": "blender"}, {"name": "forest", "source": "bundled"},
            {"name": "procedural:sky", "source": "sky"}]
    assert [data_splits.light_name(light) for light in farm] == ["blender:forest", "forest", "procedural:sky"]
    assert data_splits.light_name({"source": "maps/Venice.exr"}) == "venice"  # no name: the file's stem
    assert data_splits.is_held_out({"name": "venice", "source": "bundled"}, HELD_OUT)


def test_light_maps_limit_the_training_samples_to_those_maps(scenes):
    bank = [("park", np.eye(25, 3, dtype=np.float32) + 1.0), ("lab", np.eye(25, 3, dtype=np.float32) + 2.0)]
    names = data_splits.training_map_names(scenes, [n for n, _ in bank], held_out=HELD_OUT)
    assert names == ["city", "lab", "park", "studio"]  # venice is held out
    for count in range(1, len(names) + 1):
        maps = data_splits.first_maps(names, count)
        assert len(maps) == count and maps <= data_splits.first_maps(names, min(count + 1, len(names)))
        ds = data.TrainingScenes(scenes, 32, 4, padding=2, extra_lights=bank, extra_light_prob=0.5,
                                 held_out=HELD_OUT, light_maps=maps)
        seen = set()
        for epoch in range(4):
            for i in range(len(ds)):
                s = ds.item(i, epoch)
                seen |= {s["light_name"], s["target_light_name"]}
        assert seen == maps  # only those maps, and (over 32 samples) every one of them
    with pytest.raises(ValueError, match="maps asked for"):
        data_splits.first_maps(names, len(names) + 1)
    with pytest.raises(ValueError, match="at least one map"):
        data.TrainingScenes(scenes, 32, 4, extra_lights=bank, held_out=HELD_OUT, light_maps=frozenset())
    # without it, nothing changes: the same samples as before
    plain = data.TrainingScenes(scenes, 32, 4, padding=2, extra_lights=bank, held_out=HELD_OUT)
    every = data.TrainingScenes(scenes, 32, 4, padding=2, extra_lights=bank, held_out=HELD_OUT,
                                light_maps=frozenset(names))
    assert torch.equal(plain.item(2, 1)["input"], every.item(2, 1)["input"])


def test_preset_light_bank_excludes_held_out_maps():
    names = [name for name, _ in data_augment.preset_training_lights(2)]
    assert names and not set(names) & HELD_OUT
    assert all(light.shape == (9, 3) for _, light in data_augment.preset_training_lights(2)[:1])


def test_training_sample_ranges_physics_and_determinism(scenes):
    ds = data.TrainingScenes(scenes, 32, 4, padding=2, extra_lights=[], extra_light_prob=0.5, held_out=HELD_OUT)
    a, b = ds.item(1, 0), ds.item(1, 0)
    for key in a:
        if isinstance(a[key], torch.Tensor):
            assert torch.equal(a[key], b[key]), key
    assert any(not torch.equal(ds.item(1, e)["input"], a["input"]) for e in range(1, 4))
    for epoch in range(4):
        s = ds.item(0, epoch)
        assert s["input"].shape == (3, 32, 32) and s["transport"].shape == (25, 32, 32)
        assert s["light"].shape == (25, 3) and s["alpha"].shape == (1, 32, 32)
        assert s["input"].min() >= -1 and s["input"].max() <= 1
        assert s["alpha"].min() >= 0 and s["alpha"].max() <= 1
        assert all(torch.isfinite(v).all() for v in s.values() if isinstance(v, torch.Tensor))
        # on fully covered pixels the target is the PRT rendering rho * S (extra light) or
        # the analytic "path tracer" (rho + GLOSS) * S (scene light), S = T . L. Exact up to
        # resampling: resize(rho S) - resize(rho) resize(S) is a covariance over the filter
        # footprint, <= stripe contrast (0.34) x shading change over ~2 source pixels (~0.03)
        inner = s["alpha"][0] > 0.999
        shading = torch.einsum("nhw,nc->chw", s["transport"], s["target_light"])
        prt = s["albedo"] * shading
        err = torch.minimum((s["target_image"] - prt).abs(), (s["target_image"] - prt - GLOSS * shading).abs())
        assert float(err[:, inner].max()) < 0.01
        assert float(err[:, inner].median()) < 1e-5


def test_light_tint_keeps_luminance_and_varies_colour():
    rng = np.random.default_rng(3)
    tints = np.array([data_augment.random_light_tint(rng, 0.3) for _ in range(200)])
    # float32 factors: luminance 1 to float32 rounding
    np.testing.assert_allclose(tints @ LUMINANCE_WEIGHTS, 1.0, atol=1e-6)
    assert (tints > 0).all()
    # log(R/B) = N_r - N_b has std sigma * sqrt(2) = 0.42; 200 draws give it within ~10%
    assert 0.36 < np.std(np.log(tints[:, 0] / tints[:, 2])) < 0.49
    with pytest.raises(ValueError, match="light_tint"):
        data.TrainingScenes([Path("x.json")], 32, 4, light_tint=float("nan"))


def test_tinted_samples_stay_physically_consistent(scenes):
    """Tinted light and image together: image = rho (T . L) still holds for both lights."""
    plain = data.TrainingScenes(scenes, 32, 4, padding=2, extra_lights=[], held_out=HELD_OUT)
    tinted = data.TrainingScenes(scenes, 32, 4, padding=2, extra_lights=[], held_out=HELD_OUT, light_tint=0.3)
    ratios = []
    for epoch in range(6):
        s = tinted.item(0, epoch)
        inner = s["alpha"][0] > 0.999
        for light, image in (("light", "image"), ("target_light", "target_image")):
            shading = torch.einsum("nhw,nc->chw", s["transport"], s[light])
            prt = s["albedo"] * shading
            err = torch.minimum((s[image] - prt).abs(), (s[image] - prt - GLOSS * shading).abs())
            # same resampling bound as the untinted test, the tint (< e^1.2 here) scales it
            assert float(err[:, inner].max()) < 0.01 * 3.4
        dc = s["light"][0]
        ratios.append(float(dc[0] / dc[2]))
        assert float(LUMINANCE_WEIGHTS @ dc.double().numpy()) > 0
    untinted = [float(plain.item(0, e)["light"][0][0] / plain.item(0, e)["light"][0][2]) for e in range(6)]
    # the tint changes the light colours it is given (same scene, same epochs)
    assert max(abs(np.log(r / u)) for r, u in zip(ratios, untinted)) > 0.05


def test_reference_radiance_of_extra_lights():
    rng = np.random.default_rng(0)
    from relight.lighting import sh

    base = np.random.default_rng(1).normal(size=(9, 3)) * 0.3
    base[0] += 3.0  # a positive mean light
    for _ in range(5):
        light = data_augment.random_reference_light(base, rng)
        # float32 storage of the scaled light: relative error ~1e-7
        assert 0.7 - 1e-6 <= sh.mean_luminance(light) <= 0.9 + 1e-6
        # a Z rotation keeps band energies: |L_l| unchanged up to the scale
        scale = sh.mean_luminance(light) / sh.mean_luminance(base)
        np.testing.assert_allclose(np.linalg.norm(light[1:4]), scale * np.linalg.norm(base[1:4]), rtol=1e-5)


def test_mixed_lights_are_new_lights_at_the_reference_radiance(scenes):
    """random_mixed_light: at the reference radiance, a mix of its two lights (a sum of turned
    and tilted lights keeps the weights' DC), not either alone, seeded; with light_mix=1 the
    bank lights are mixes named by both maps, and the PRT image under them is exact."""
    from relight.lighting import sh
    from relight.lighting.light import sh_light

    first, second = sh_light("sunset", 4), sh_light("studio", 4)
    lights = [data_augment.random_mixed_light(first, second, np.random.default_rng(s)) for s in range(6)]
    for light in lights:
        assert 0.7 - 1e-5 <= sh.mean_luminance(light) <= 0.9 + 1e-5
        # a rotation keeps each band's energy; a mix of two different lights has another one
        for base in (first, second):
            scale = sh.mean_luminance(light) / sh.mean_luminance(base)
            assert abs(np.linalg.norm(light[1:4]) / (scale * np.linalg.norm(base[1:4])) - 1) > 1e-3
    np.testing.assert_array_equal(lights[0], data_augment.random_mixed_light(first, second, np.random.default_rng(0)))
    assert max(float(np.abs(a - b).max()) for a, b in zip(lights, lights[1:])) > 0.01

    mixing = data.TrainingScenes(scenes, 32, 4, padding=2, extra_lights=[], held_out=HELD_OUT, light_mix=1.0,
                                 extra_light_prob=1.0)
    for epoch in range(3):
        s = mixing.item(0, epoch)
        assert "+" in s["light_name"] and not set(s["light_name"].split("+")) & HELD_OUT
        prt = s["albedo"] * torch.einsum("nhw,nc->chw", s["transport"], s["light"])
        torch.testing.assert_close(s["image"], prt, rtol=1e-5, atol=1e-6)
    # off by default, and then no extra draws: the samples are those of before
    plain = data.TrainingScenes(scenes, 32, 4, padding=2, extra_lights=[], held_out=HELD_OUT)
    off = data.TrainingScenes(scenes, 32, 4, padding=2, extra_lights=[], held_out=HELD_OUT, light_mix=0.0)
    assert torch.equal(plain.item(1, 2)["input"], off.item(1, 2)["input"])
    with pytest.raises(ValueError, match="light_mix"):
        data.TrainingScenes([Path("x.json")], 32, 4, light_mix=1.5)


def test_evaluation_pairs_target_held_out_lights(scenes):
    pairs = data.EvaluationPairs(scenes[:2], 32, 4, padding=2, held_out_only=True, held_out=HELD_OUT)
    assert len(pairs) == 4  # per scene: (studio -> venice), (city -> venice)
    for i in range(len(pairs)):
        s = pairs[i]
        assert s["light_b"] == "venice" and s["light_a"] in ("studio", "city")
        expected = to_network_input(s["image"].numpy().transpose(1, 2, 0), s["alpha"].numpy()[0])
        np.testing.assert_allclose(s["input"].numpy().transpose(1, 2, 0), expected, rtol=0, atol=1e-6)


def test_missing_dataset_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match="no finished scenes"):
        data_splits.find_scenes(tmp_path)
    with pytest.raises(ValueError, match="does not exist"):
        data_splits.find_scenes(tmp_path / "nope")


def test_mirror_signs_match_the_sh_basis_and_keep_shading():
    from relight.lighting import sh

    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(50, 3))
    mirrored = dirs * [-1.0, 1.0, 1.0]
    signs = data_augment.mirror_signs(4)
    np.testing.assert_allclose(sh.sh_basis(mirrored, 4), sh.sh_basis(dirs, 4) * signs, rtol=1e-12, atol=1e-12)
    assert signs[:4].tolist() == [1, 1, 1, -1]  # Y00, y, z unchanged; x flips


def test_flipped_samples_are_mirror_images(scenes):
    kw = dict(padding=2, extra_lights=[], held_out=HELD_OUT, mask_prob=1.0)
    plain = data.TrainingScenes(scenes, 32, 4, flip_prob=0.0, **kw)
    flipped = data.TrainingScenes(scenes, 32, 4, flip_prob=1.0, **kw)
    a, b = plain.item(2, 5), flipped.item(2, 5)  # same seed: same lights and background
    signs = torch.from_numpy(data_augment.mirror_signs(4))
    torch.testing.assert_close(b["input"], a["input"].flip(-1))
    torch.testing.assert_close(b["transport"], a["transport"].flip(-1) * signs[:, None, None])
    torch.testing.assert_close(b["light"], a["light"] * signs[:, None])
    # shading is a mirror image: (s T) . (s L) = T . L
    shade = lambda s: torch.einsum("nhw,nc->chw", s["transport"], s["target_light"])
    torch.testing.assert_close(shade(b), shade(a).flip(-1), rtol=1e-5, atol=1e-6)


def test_lambertian_samples_are_prt_renderings(scenes):
    """--lambertian trains on PRT images only: targets are exactly rho * (T . L), never the gloss."""
    ds = data.TrainingScenes(scenes, 32, 4, padding=2, extra_lights=[], held_out=HELD_OUT, lambertian=True)
    for epoch in range(3):
        s = ds.item(0, epoch)
        for light, image in (("light", "image"), ("target_light", "target_image")):
            prt = s["albedo"] * torch.einsum("nhw,nc->chw", s["transport"], s[light])
            # computed from the same float32 crops: float32 round-off only
            torch.testing.assert_close(s[image], prt, rtol=1e-5, atol=1e-6)


def test_exposure_jitter_scales_the_input_light_and_image_and_keeps_the_albedo(scenes):
    """image = rho (T . L) still holds for the jittered input light; the target light and the
    albedo are untouched; the input light's scale varies by 2^N(0, 0.5^2)."""
    # no mirror: the jitter's extra draw would change which samples are mirrored
    plain = data.TrainingScenes(scenes, 32, 4, padding=2, extra_lights=[], held_out=HELD_OUT, flip_prob=0.0)
    jittered = data.TrainingScenes(scenes, 32, 4, padding=2, extra_lights=[], held_out=HELD_OUT,
                                   exposure_jitter=0.5, flip_prob=0.0)
    scales = []
    for epoch in range(8):
        s = jittered.item(0, epoch)
        inner = s["alpha"][0] > 0.999
        shading = torch.einsum("nhw,nc->chw", s["transport"], s["light"])
        prt = s["albedo"] * shading
        err = torch.minimum((s["image"] - prt).abs(), (s["image"] - prt - GLOSS * shading).abs())
        # the untinted resampling bound (0.01) times the largest gain 8 draws of 2^N(0, 0.25) reach
        assert float(err[:, inner].max()) < 0.01 * 2.0 ** 1.5
        assert torch.equal(s["albedo"], plain.item(0, epoch)["albedo"])
        scales.append(float(s["light"][0].sum() / plain.item(0, epoch)["light"][0].sum()))
    assert max(scales) / min(scales) > 1.2  # the exposure really varies
    with pytest.raises(ValueError, match="exposure_jitter"):
        data.TrainingScenes([Path("x.json")], 32, 4, exposure_jitter=-1.0)


def test_body_prior_channels_follow_the_scene_and_mirror(tmp_path):
    """With body_prior the input carries the body's unit normal and coverage (in [-1, 1]) after the
    photo's channels, cropped like every other map; a mirrored sample mirrors them and flips the
    normal's x, as it does the target normal. Packs keep them."""
    paths = write_analytic_dataset(tmp_path / "d", n_scenes=2, size=32, order=2, lights=("studio", "city"),
                                   body=True)
    kw = dict(padding=2, extra_lights=[], held_out=HELD_OUT, mask_prob=1.0, body_prior=True)
    plain = data.TrainingScenes(paths, 32, 2, flip_prob=0.0, **kw).item(1, 3)
    flipped = data.TrainingScenes(paths, 32, 2, flip_prob=1.0, **kw).item(1, 3)
    x = plain["input"]
    assert x.shape == (7, 32, 32)
    inside = plain["alpha"][0] > 0.999
    # the analytic body is the person itself: its normal is the target normal, its coverage the alpha
    torch.testing.assert_close(x[3:6][:, inside], plain["normal"][:, inside], atol=1e-5, rtol=0)
    torch.testing.assert_close((x[6] + 1) / 2, plain["alpha"][0], atol=1e-6, rtol=0)
    mirror = torch.tensor([1, 1, 1, -1, 1, 1, 1.0])[:, None, None]
    torch.testing.assert_close(flipped["input"], x.flip(-1) * mirror)
    torch.testing.assert_close(flipped["normal"][0], -plain["normal"][0].flip(-1))
    pairs = data.EvaluationPairs(paths, 32, 2, padding=2, held_out=HELD_OUT, body_prior=True)
    assert pairs[0]["input"].shape == (7, 32, 32)
    packed = data_crops.pack_scenes(paths, tmp_path / "p.npz", 32, 2, padding=2, held_out=HELD_OUT)
    from_pack = data.TrainingScenes(paths, 32, 2, flip_prob=0.0, pack=packed, **kw).item(1, 3)["input"]
    torch.testing.assert_close(from_pack[3:], x[3:], atol=2e-3, rtol=0)  # float16 in the pack
    no_body = write_analytic_dataset(tmp_path / "n", n_scenes=1, size=32, order=2, lights=("studio", "city"))
    with pytest.raises(ValueError, match="has no body pass"):
        data.TrainingScenes(no_body, 32, 2, **kw).item(0, 0)


def _sun(deg: float) -> dict:
    """A hard sun `deg` off the camera's axis (the camera looks along +Y: -Y is toward it)."""
    t = np.radians(deg)
    return {"hard": {"kind": "sun", "lobes": [{"direction_camera": [float(np.sin(t)), -float(np.cos(t)), 0.0]}]}}


def test_side_sun_pairs_are_a_map_then_a_sun_off_the_axis():
    lamp = {"hard": {"kind": "lamp", "lobes": [{"direction_camera": [1.0, 0.0, 0.0]}]}}
    lights = [{"map": "a"}, _sun(90), _sun(10), _sun(165), lamp, {"map": "b"}, _sun(41), _sun(139),
              _sun(39), _sun(141)]
    assert data_splits.sun_off_axis_deg(_sun(90)) == pytest.approx(90.0, abs=1e-9)
    assert data_splits.sun_off_axis_deg(lamp) is None and data_splits.sun_off_axis_deg({"map": "a"}) is None
    # a photo under a map (0, 5), relit to a sun 40-140 degrees off the axis (1, 6, 7); never sun -> sun
    assert data_splits.side_sun_pairs({"lights": lights}) == [(0, 1), (5, 1), (0, 6), (5, 6), (0, 7), (5, 7)]
    assert data_splits.side_sun_pairs({"lights": lights}, side_deg=(0.0, 20.0)) == [(0, 2), (5, 2)]


def test_side_sun_evaluation_pairs_need_a_map_and_a_side_sun(scenes):
    # the analytic scenes are lit by maps only: no pair, and the message says what was missing
    with pytest.raises(ValueError, match="hard side sun"):
        data.EvaluationPairs(scenes[:2], 32, 4, padding=2, held_out=HELD_OUT, side_sun=True)
    assert len(data.EvaluationPairs(scenes[:2], 32, 4, padding=2, held_out=HELD_OUT)) > 0
