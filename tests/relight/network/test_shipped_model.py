"""CI guard: what the shipped default model is shown to do on unseen scenes, each claim a
one-sided 95 % bound over the held-out scenes this guard renders.

The farm renders small scenes lit only by the held-out maps (`--light-pool heldout`, never
seen in training). For every ordered pair of a scene's lights (a, b), the registered default
model decomposes the path-traced image under a through relight.network.runtime as `relight
image` does by default (Balanced's options, the GT alpha as the mask) and relights it with
light b's SH coefficients from the sidecar, which are in the photo-camera frame the network
uses (docs/conventions.md, docs/dataset.md). The relit person is compared with Cycles' image
under b: PSNR over the person's fully covered pixels (GT alpha > 0.999, as model/evaluate.py's
default: edge pixels mix in each light's own background), linear, peak 1
(model/scoring/metrics.py). Baselines: identity (image a as it is) and exposure-matched
identity (image a times L00_b / L00_a per channel). Normals: the median angle between the
normals the model's transport implies (T's band 1) and the farm's normal pass, against a flat
person facing the camera (every normal -Y, "doing nothing" for geometry).

The rule, the same for every claim: the unit is a scene (its pairs share a person and its
lights, so they are not independent). d_s is the scene's paired difference (the model's PSNR
less the baseline's, or the flat normals' error less the model's, mean over the scene's
pairs or images); the claim holds when mean(d) - k * sd(d) / sqrt(n) > 0, k = Student's t
at 95 % with n - 1 degrees of freedom (1.895 for 8 scenes, 2.920 for 3). So the margin a
model must clear is the spread of its paired differences on these scenes, found when the
guard runs, not a number set from the shipped model's own gains.

What it guarantees (one-sided 95 %):
- full-body (8 scenes): relit better than identity and than exposure-matched identity;
- full-body and head-and-shoulders (3 scenes): normals closer to the truth than a flat person
  facing the camera;
- head-and-shoulders under a hard side sun (issue 45; 8 scenes, each photographed under a held-out
  HDR map and relit to a sun 40-140 degrees off the camera axis): the relit change of light follows
  the true one (model.scoring.metrics.light_response: the per-scene slope and correlation of the
  relit log-luminance change against the truth's, each bounded above 0, which is the untouched
  photo's and any exposure change's), and the relit photo is better than the untouched one.
  Measured (geometry.onnx sha256 2ba8009b936e, the release of 2026-11-28 half-way to its sun-response
  restart): slope 0.37 +- 0.16 (bound +0.27), correlation 0.48 +- 0.12 (bound +0.40), relit 26.99 dB,
  +10.57 +- 5.41 over identity (bound +6.94); not claimed over exposure-matched (+3.16 +- 4.20, bound
  +0.34, above 0 for the first time, not yet asserted). Before: b25ddc831627 0.31 / 0.41, 26.65 dB;
  caa9df63d60f 0.30 / 0.37, 26.07 dB. The true decomposition: slope 0.77, correlation 0.58; a
  random-weight network fails on the slope (bound -0.15).
What it does not claim: that the model relights head-and-shoulders better than identity or an
exposure change. Measured (geometry.onnx sha256 2ba8009b936e, Balanced, 8 scenes of seed 20251,
16 pairs): relit 23.48 dB, identity 22.27, exposure-matched 24.11; per scene +1.20 +- 5.24 dB over
identity (bound -2.31) and -0.64 +- 4.23 over exposure-matched (bound -3.47): worse than an
exposure change, and within its spread of identity (a map against itself turned 60 degrees scores
33.4 dB as it is); the models before: 23.21 (b25ddc831627), 23.32 dB. On the guard's 3 of them:
+1.83 / -1.49 dB.
Full-body, 8 scenes of seed 20250: relit 21.21 (before 21.02, 20.76), identity 17.42, exposure-matched
18.43; per scene +3.79 +- 2.24 (bound +2.29) and +2.78 +- 2.77 (bound +0.92); on the first 3
scenes alone the exposure-matched bound is negative, hence 8. Normals, per scene, the flat
person's error less the model's: full-body +15.8 +- 1.1 deg (8 scenes, bound +15.1; model 19.0,
flat 34.8), head-and-shoulders +19.5 +- 4.9 (3 scenes, bound +11.3; model 14.7, flat 34.2).

No registered default model: the guard FAILS. To measure (prints the per-pair table, the
per-scene differences and their bounds):

    .venv/bin/python tests/relight/network/test_shipped_model.py [MODEL.onnx] [--close | --sun] [--scenes-dir DIR]
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from model.samples.data_splits import side_sun_pairs, sun_off_axis_deg

ROOT = Path(__file__).resolve().parents[3]

# The scenes: deterministic for a seed and index (same bodies, poses, lights, samples).
SCENES, SEED, RES, LIGHTS, SAMPLES, ORDER = 8, 20250, 128, 2, 16, 4
# issue 37: head-and-shoulders photos (the farm's framing), their own seed; normals only (module docstring)
CLOSE_FRAMING, CLOSE_SEED, CLOSE_SCENES = "head-and-shoulders", 20251, 3
# issue 45: head-and-shoulders photos under an HDR map relit to a hard sun 40-140 degrees off the camera
# axis; the first SUN_SCENES indices of SUN_SEED whose two lights (half of them hard) are such a map and
# such a sun, as the farm draws them (farm.scene.sample_scene: `main --find-sun-scenes` lists them again)
SUN_SEED, SUN_HARD = 20252, 0.5  # the side: model.samples.data_splits.SIDE_SUN_DEG
SUN_INDICES = (2, 39, 40, 42, 64, 68, 72, 91)
CONFIDENCE = 0.95         # one-sided, over scenes (module docstring)
BASELINES = ("identity", "exposure-matched")
CAMERA_FACING = np.array([0.0, -1.0, 0.0], np.float32)  # toward the camera, which looks along +Y


# ------------------------------------------------------------------ the measurement


def default_model() -> Path:
    """The registry's default model file; raises ValueError naming what is missing."""
    from relight import models

    path = models.default_model_path()  # ValueError when no default is registered
    if not path.is_file():
        raise ValueError(f"relight/models/models.json names a default model, but {path} does not exist")
    return path


def render_scenes(folder: Path, framing: str = "full-body", seed: int = SEED, scenes: int = SCENES,
                  indices: tuple[int, ...] | None = None, hard_lights: float = 0.0) -> list[Path]:
    """The guard's scenes in `folder` (rendered by the farm; finished ones are kept): indices 0 to
    scenes - 1, or the given `indices`."""
    import importlib.util

    if importlib.util.find_spec("bpy") is None:
        raise RuntimeError("the shipped-model guard renders its scenes with the farm: "
                           "install bpy (pip install -e '.[farm]')")
    ranges = [(0, scenes)] if indices is None else [(i, 1) for i in indices]
    for first, count in ranges:
        cmd = [sys.executable, "-m", "farm", "--out", str(folder), "--scenes", str(count), "--first", str(first),
               "--seed", str(seed), "--framing", framing, "--res", str(RES), "--lights", str(LIGHTS),
               "--samples", str(SAMPLES), "--order", str(ORDER), "--light-pool", "heldout",
               "--hard-lights", str(hard_lights), "--workers", "1", "--resume", "--no-progress"]
        done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            raise RuntimeError(f"farm failed ({done.returncode}): {' '.join(cmd[1:])}\n{done.stderr[-2000:]}")
    from relight.files import dataset

    paths = dataset.list_finished_scenes(folder)
    want = scenes if indices is None else len(indices)
    if len(paths) != want:
        raise RuntimeError(f"farm finished {len(paths)} of {want} scenes in {folder}")
    return paths


def _light_label(light: dict) -> str:
    return f"{light['name']} @{light['rotation_deg']:.0f}"


def pair_psnrs(relight_pair, scene_paths: list[Path]) -> list[dict]:
    """Per ordered light pair (a, b): PSNR of relight_pair(scene, a, b) and of the two identities.

    relight_pair(scene, a, b) -> linear [H, W, 3]: the scene's image under a relit to light b.
    """
    from model.scoring import metrics
    from relight.files import dataset

    rows = []
    for path in scene_paths:
        scene = dataset.read_scene(path)
        if scene.images is None or len(scene.images) < 2:
            raise ValueError(f"{path.name}: the guard needs two path-traced lights")
        weight = metrics.interior_weight(scene.alpha[..., 0])
        for a in range(len(scene.images)):
            for b in range(len(scene.images)):
                if a == b:
                    continue
                target = scene.images[b]
                la, lb = scene.lights[a]["sh"][0], scene.lights[b]["sh"][0]
                rows.append({
                    "scene": scene.index, "a": _light_label(scene.lights[a]), "b": _light_label(scene.lights[b]),
                    "relit": metrics.psnr(relight_pair(scene, a, b), target, weight),
                    "identity": metrics.psnr(scene.images[a], target, weight),
                    "exposure-matched": metrics.psnr(scene.images[a] * (lb / la), target, weight),
                })
    return rows


def _balanced_relighter(model_path: Path):
    """The runtime as `relight image` runs by default: the default preset's working size and
    decompose options (relight/network/quality.py), and those options."""
    from relight.network.quality import DEFAULT, preset
    from relight.network.runtime import Relighter

    chosen = preset(DEFAULT)
    return Relighter(model_path, working_size=chosen.working_size), chosen.decompose_options(working_size=False)


def normal_errors(model_path: Path, scene_paths: list[Path]) -> list[dict]:
    """Per scene and light: the median angle (degrees) between the farm's normal pass and the
    normals the model's transport implies (T's band-1 direction), and a flat person facing the
    camera's, over fully covered pixels."""
    from model.scoring import metrics
    from relight.files import dataset

    relighter, options = _balanced_relighter(model_path)
    out = []
    for path in scene_paths:
        scene = dataset.read_scene(path)
        weight = metrics.interior_weight(scene.alpha[..., 0]) > 0
        flat = np.clip((scene.normal * CAMERA_FACING).sum(-1), -1.0, 1.0)[weight]
        for image in scene.images:
            dec = relighter.decompose(image, mask=scene.alpha[..., 0], **options)
            t = dec.transport
            d = np.stack([t[..., 3], t[..., 1], t[..., 2]], axis=-1)
            d /= np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)
            full = dec._to_full(np.ascontiguousarray(d, dtype=np.float32))  # to the scene's pixels
            full /= np.maximum(np.linalg.norm(full, axis=-1, keepdims=True), 1e-12)
            cos = np.clip((full * scene.normal).sum(-1), -1.0, 1.0)[weight]
            out.append({"scene": scene.index, "model": float(np.median(np.degrees(np.arccos(cos)))),
                        "flat": float(np.median(np.degrees(np.arccos(flat))))})
    return out


def model_relighter(model_path: Path):
    """relight_pair for pair_psnrs: the runtime's decompose (Balanced, GT alpha as the mask) + relight."""
    relighter, options = _balanced_relighter(model_path)

    def relight_pair(scene, a, b):
        dec = relighter.decompose(scene.images[a], mask=scene.alpha[..., 0], **options)
        light_b = scene.lights[b]["sh"][:(relighter.sh_order + 1) ** 2]
        return dec.relight(light_b)  # SH array: used as given (camera frame, no normalization)

    return relight_pair


def means(rows: list[dict]) -> dict[str, float]:
    return {k: float(np.mean([r[k] for r in rows])) for k in ("relit", *BASELINES)}


def table(rows: list[dict], label: str) -> str:
    lines = [f"| scene | light a -> b | {label} | identity | exposure-matched |", "|---|---|---|---|---|"]
    lines += [f"| {r['scene']} | {r['a']} -> {r['b']} | {r['relit']:.2f} | {r['identity']:.2f} | "
              f"{r['exposure-matched']:.2f} |" for r in rows]
    m = means(rows)
    lines.append(f"| mean of {len(rows)} | | {m['relit']:.2f} | {m['identity']:.2f} | {m['exposure-matched']:.2f} |")
    return "\n".join(lines)


def per_scene(rows: list[dict], better: str, worse: str) -> np.ndarray:
    """Each scene's paired difference: the mean over its rows of row[better] - row[worse]."""
    scenes = sorted({r["scene"] for r in rows})
    return np.array([np.mean([r[better] - r[worse] for r in rows if r["scene"] == s]) for s in scenes])


def lower_bound(differences: np.ndarray) -> dict:
    """The one-sided CONFIDENCE lower bound of the mean of per-scene `differences`:
    mean - k * sd / sqrt(n), k Student's t with n - 1 degrees of freedom (module docstring)."""
    from scipy import stats

    d = np.asarray(differences, np.float64)
    n = d.size
    if n < 2:
        raise ValueError(f"a bound over scenes needs at least 2 scenes, got {n}")
    k = float(stats.t.ppf(CONFIDENCE, n - 1))
    mean, sd = float(d.mean()), float(d.std(ddof=1))
    return {"n": n, "mean": mean, "sd": sd, "k": k, "bound": mean - k * sd / np.sqrt(n)}


def describe(b: dict, unit: str) -> str:
    return (f"{b['mean']:+.2f} +- {b['sd']:.2f} {unit} over {b['n']} scenes, one-sided {CONFIDENCE:.0%} bound "
            f"{b['bound']:+.2f} (k {b['k']:.3f})")


def shortfalls(rows: list[dict], baselines=BASELINES) -> list[str]:
    """Why the relit PSNR is not shown better than each baseline ([] when it is)."""
    out = []
    for name in baselines:
        b = lower_bound(per_scene(rows, "relit", name))
        if not b["bound"] > 0:
            out.append(f"not shown better than {name}: {describe(b, 'dB')}")
    return out


def normal_shortfall(errors: list[dict]) -> str | None:
    """Why the model's normals are not shown closer to the truth than a flat person facing the
    camera (None when they are)."""
    b = lower_bound(per_scene(errors, "flat", "model"))
    return None if b["bound"] > 0 else f"normals not shown better than a flat person: {describe(b, 'deg')}"


def true_relight_pair(scene, a, b):
    """relight_pair of the scene's own albedo and transport (GT, no residual) through the runtime's
    Decomposition: the harness's check."""
    from relight.network.runtime import Decomposition

    h, w = scene.resolution
    n = (ORDER + 1) ** 2
    gt = Decomposition(
        albedo=scene.albedo, transport=np.ascontiguousarray(scene.transport[..., :n]),
        residual=np.zeros((h, w, n), np.float32), light=scene.lights[a]["sh"][:n].astype(np.float32),
        alpha=scene.alpha[..., 0], box=(0, h, 0, w), working_size=(h, w), photo=scene.images[a],
        photo_working=scene.images[a], mask=scene.alpha[..., 0], sh_order=ORDER)
    return gt.relight(scene.lights[b]["sh"][:n])


def light_responses(relight_pair, scene_paths: list[Path]) -> list[dict]:
    """Per side-sun pair (side_sun_pairs): the light's response (model.scoring.metrics.light_response:
    slope and correlation of the relit log-luminance change against the true one, over the fully
    covered pixels) and the relit and identity PSNRs."""
    from model.scoring import metrics
    from relight.files import dataset

    rows = []
    for path in scene_paths:
        scene = dataset.read_scene(path)
        pairs = side_sun_pairs(scene.meta)
        if not pairs:
            raise ValueError(f"{path.name}: no HDR map and side sun pair (the farm draws other lights now?)")
        weight = metrics.interior_weight(scene.alpha[..., 0])
        for a, b in pairs:
            relit, photo, target = relight_pair(scene, a, b), scene.images[a], scene.images[b]
            response = metrics.light_response(photo, relit, target, weight)
            la, lb = scene.lights[a]["sh"][0], scene.lights[b]["sh"][0]
            rows.append({"scene": scene.index, "a": _light_label(scene.lights[a]),
                         "b": f"sun {sun_off_axis_deg(scene.lights[b]):.0f} deg",
                         "slope": response.slope, "correlation": response.correlation, "none": 0.0,
                         "relit": metrics.psnr(relit, target, weight), "identity": metrics.psnr(photo, target, weight),
                         "exposure-matched": metrics.psnr(photo * (lb / la), target, weight)})
    return rows


def response_table(rows: list[dict], label: str) -> str:
    lines = [f"| scene | light a -> b | {label}: slope | correlation | relit dB | identity dB | exposure-matched dB |",
             "|---|---|---|---|---|---|---|"]
    lines += [f"| {r['scene']} | {r['a']} -> {r['b']} | {r['slope']:.2f} | {r['correlation']:.2f} | {r['relit']:.2f} | "
              f"{r['identity']:.2f} | {r['exposure-matched']:.2f} |" for r in rows]
    return "\n".join(lines)


def response_shortfalls(rows: list[dict]) -> list[str]:
    """Why the relit change is not shown to follow the true one ([] when it is): the per-scene
    slope and correlation each bounded above 0, the photo's own response (it does not change)."""
    out = []
    for key in ("slope", "correlation"):
        b = lower_bound(per_scene(rows, key, "none"))
        if not b["bound"] > 0:
            out.append(f"light response {key} not shown above 0: {describe(b, '')}")
    return out


# ------------------------------------------------------------------ the tests


def _lazy_scenes(tmp_path_factory, name: str, **framing):
    rendered: list[Path] = []

    def get() -> list[Path]:
        if not rendered:
            try:
                rendered.extend(render_scenes(tmp_path_factory.mktemp(name), **framing))
            except RuntimeError as exc:
                pytest.fail(str(exc))
        return rendered

    return get


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """A function returning the rendered scenes (rendered on first call, once per module), so
    that the guard checks the registry before it spends minutes rendering."""
    return _lazy_scenes(tmp_path_factory, "heldout_scenes")


@pytest.fixture(scope="module")
def sun_scenes(tmp_path_factory):
    """Head-and-shoulders scenes under an HDR map and a hard side sun (issue 45)."""
    return _lazy_scenes(tmp_path_factory, "heldout_sun_scenes", framing=CLOSE_FRAMING, seed=SUN_SEED,
                        indices=SUN_INDICES, hard_lights=SUN_HARD)


@pytest.fixture(scope="module")
def close_scenes(tmp_path_factory):
    """Head-and-shoulders scenes (issue 37)."""
    return _lazy_scenes(tmp_path_factory, "heldout_close_scenes", framing=CLOSE_FRAMING, seed=CLOSE_SEED,
                        scenes=CLOSE_SCENES)


def test_shipped_default_model_beats_identity_on_held_out_lights(scenes):
    try:
        model = default_model()
    except ValueError as exc:  # a failure, not a skip: shipping without a model is the bug
        pytest.fail(f"no shipped default model to guard ({exc}); register one with `python -m export "
                    "WEIGHTS.safetensors --out relight/models/NAME.onnx --register NAME`")
    rows = pair_psnrs(model_relighter(model), scenes())
    print(table(rows, model.name))
    problems = shortfalls(rows)
    assert not problems, f"{model.name}: " + "; ".join(problems) + "\n" + table(rows, "model")


def test_shipped_default_model_predicts_normals_on_head_and_shoulders(close_scenes):
    """Issue 37's framing: the guarantee there is the geometry (module docstring: its relit PSNR
    is not shown better than identity or an exposure change, and is not claimed). The relit
    table is printed for the record."""
    rows = pair_psnrs(model_relighter(default_model()), close_scenes())
    print(table(rows, "head-and-shoulders"))
    for name in BASELINES:
        print(f"relit over {name}: {describe(lower_bound(per_scene(rows, 'relit', name)), 'dB')}")
    errors = normal_errors(default_model(), close_scenes())
    print("median normal error per image (deg), model / flat:",
          ", ".join(f"{e['model']:.1f} / {e['flat']:.1f}" for e in errors))
    problem = normal_shortfall(errors)
    assert problem is None, problem


def test_shipped_default_model_predicts_normals(scenes):
    """The geometry the relighting is built on, on the full-body scenes: closer to the farm's
    normals than a flat person facing the camera (a model whose transport collapsed to flat
    shading, as the paper-layout models did, has no normal to speak of and fails it)."""
    errors = normal_errors(default_model(), scenes())
    print("median normal error per image (deg), model / flat:",
          ", ".join(f"{e['model']:.1f} / {e['flat']:.1f}" for e in errors))
    problem = normal_shortfall(errors)
    assert problem is None, problem


def test_guard_passes_the_true_decomposition(scenes):
    """The harness itself: the scene's own albedo and transport (GT), relit by the runtime with
    light b's sidecar coefficients, must clear the guard's rule. This proves the frames, SH order
    and compositing line up, so a failing model is the model's fault, not the harness's."""
    rows = pair_psnrs(true_relight_pair, scenes())
    print(table(rows, "GT decomposition"))
    # Order 4 and no residual (specular, interreflection) keep even the GT well below the
    # path-traced image; it must still be shown better than both baselines. Measured (issue 48):
    # 26.43 dB; per scene +9.02 +- 3.91 over identity (bound +6.40), +8.00 +- 4.45 over
    # exposure-matched (bound +5.02)
    assert not shortfalls(rows), "; ".join(shortfalls(rows)) + "\n" + table(rows, "GT decomposition")


def test_shipped_default_model_follows_a_hard_side_sun(sun_scenes):
    """Issue 45's guard: relit from an HDR map to a hard sun 40-140 degrees off the camera axis, the
    person's change of light follows the true one: the per-scene slope and correlation of the relit
    log-luminance change against the truth's are each shown above 0 (the untouched photo's, and an
    exposure change's), and the relit photo is shown better than the untouched one. Not claimed:
    better than an exposure change (module docstring)."""
    rows = light_responses(model_relighter(default_model()), sun_scenes())
    print(response_table(rows, "model"))
    problems = response_shortfalls(rows) + shortfalls(rows, baselines=("identity",))
    assert not problems, "; ".join(problems) + "\n" + response_table(rows, "model")


def test_sun_guard_passes_the_true_decomposition(sun_scenes):
    """The harness: the scene's own albedo and transport clear the same rule."""
    rows = light_responses(true_relight_pair, sun_scenes())
    print(response_table(rows, "GT decomposition"))
    problems = response_shortfalls(rows) + shortfalls(rows)
    assert not problems, "; ".join(problems) + "\n" + response_table(rows, "GT decomposition")


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # torch's legacy (TorchScript) exporter
def test_sun_guard_rejects_a_random_weight_model(sun_scenes, tmp_path):
    """The light's response can fail: a seeded random-weight network's relit change is not shown
    to follow the sun (its slope swings from scene to scene)."""
    rows = light_responses(model_relighter(_random_model(tmp_path)), sun_scenes())
    print(response_table(rows, "random weights"))
    assert any("slope" in problem for problem in response_shortfalls(rows)), response_table(rows, "random weights")


def _random_model(tmp_path) -> Path:
    """The seeded random-weight network the rejection tests run (export.random_model), made on one thread."""
    torch = pytest.importorskip("torch")
    pytest.importorskip("onnx")
    from export.random_model import export_random_model

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        path, _, _ = export_random_model(tmp_path / "random.onnx", seed=0, sh_order=ORDER)
    finally:
        torch.set_num_threads(before)
    return path


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # torch's legacy (TorchScript) exporter
def test_guard_rejects_a_random_weight_model(scenes, tmp_path):
    """The guard can fail: a seeded random-weight network run through the same runtime path
    gives finite PSNRs that are shown better than neither baseline (measured, issue 48: 12.20 dB;
    per scene -5.22 +- 3.13 and -6.23 +- 4.19, bounds -7.31 and -9.04)."""
    rows = pair_psnrs(model_relighter(_random_model(tmp_path)), scenes())
    print(table(rows, "random weights"))
    assert all(np.isfinite(r["relit"]) for r in rows)
    assert len(shortfalls(rows)) == 2, table(rows, "random weights")


def test_the_bound_is_students_one_sided_95_percent():
    """lower_bound's k is the t quantile (1.895 for 8 scenes, 2.920 for 3), and a difference
    whose scenes all agree is bounded by its mean."""
    b = lower_bound(np.array([1.0, 3.0, 2.0]))
    assert b["k"] == pytest.approx(2.919986, abs=1e-6) and b["sd"] == pytest.approx(1.0)
    assert b["bound"] == pytest.approx(2.0 - 2.919986 / np.sqrt(3), abs=1e-6)
    assert lower_bound(np.full(8, 0.5))["bound"] == pytest.approx(0.5)
    assert lower_bound(np.arange(8.0))["k"] == pytest.approx(1.894579, abs=1e-6)
    with pytest.raises(ValueError, match="at least 2 scenes"):
        lower_bound(np.array([1.0]))


# ------------------------------------------------------------------ measuring


def find_sun_indices(count: int) -> list[int]:
    """The first `count` scene indices of SUN_SEED whose lights are an HDR map and a side sun, drawn as
    the farm draws them (farm.scene.sample_scene: no rendering)."""
    from farm.scene import SceneOptions, sample_scene

    options = SceneOptions(resolution=RES, lights=LIGHTS, samples=SAMPLES, sh_order=ORDER, light_pool="heldout",
                           framing=CLOSE_FRAMING, hard_lights=SUN_HARD)
    found, index = [], 0
    while len(found) < count:
        drawn = sample_scene(index, SUN_SEED, options)
        meta = {"lights": [{"hard": light.hard} if light.hard else {} for light in drawn.lights]}
        if side_sun_pairs(meta):
            found.append(index)
        index += 1
    return found


def measure_sun(model: Path, folder: Path | None) -> int:
    """The hard side sun's figures: per pair, the model's and the true decomposition's response and PSNR."""
    import tempfile

    folder = folder or Path(tempfile.mkdtemp(prefix="relight_guard_sun_"))
    paths = render_scenes(folder, framing=CLOSE_FRAMING, seed=SUN_SEED, indices=SUN_INDICES, hard_lights=SUN_HARD)
    for label, relight_pair in ((model.name, model_relighter(model)), ("GT decomposition", true_relight_pair)):
        rows = light_responses(relight_pair, paths)
        print(response_table(rows, label))
        for key in ("slope", "correlation"):
            print(f"{label} {key}: {describe(lower_bound(per_scene(rows, key, 'none')), '')}")
        for name in BASELINES:
            print(f"{label} relit over {name}: {describe(lower_bound(per_scene(rows, 'relit', name)), 'dB')}")
        m = means(rows)
        print(f"{label}: mean relit {m['relit']:.2f} dB, identity {m['identity']:.2f}, "
              f"exposure-matched {m['exposure-matched']:.2f} over {len(rows)} pairs (scenes in {folder})\n")
    return 0


def main(argv=None) -> int:
    import argparse
    import tempfile

    p = argparse.ArgumentParser(prog="tests/relight/network/test_shipped_model.py",
                                description="Measure the guard's figures for a model (default: the registered default).")
    p.add_argument("model", nargs="?", help="ONNX model (default: the registry's default)")
    p.add_argument("--scenes-dir", type=Path, help="keep the rendered scenes here (reused when finished)")
    p.add_argument("--close", action="store_true", help=f"the {CLOSE_FRAMING} scenes (seed {CLOSE_SEED})")
    p.add_argument("--scenes", type=int, default=None,
                   help=f"how many scenes (default: the guard's, {SCENES} full-body, {CLOSE_SCENES} close)")
    p.add_argument("--sun", action="store_true", help=f"the hard side sun's scenes (seed {SUN_SEED}, issue 45)")
    p.add_argument("--find-sun-scenes", type=int, metavar="N", default=None,
                   help=f"list the first N indices of seed {SUN_SEED} that draw an HDR map and a side sun")
    args = p.parse_args(argv)
    if args.find_sun_scenes is not None:
        print(find_sun_indices(args.find_sun_scenes))
        return 0
    if args.sun:
        return measure_sun(Path(args.model) if args.model else default_model(), args.scenes_dir)
    try:
        model = Path(args.model) if args.model else default_model()
        folder = args.scenes_dir or Path(tempfile.mkdtemp(prefix="relight_guard_"))
        framing = dict(framing=CLOSE_FRAMING, seed=CLOSE_SEED, scenes=CLOSE_SCENES) if args.close else {}
        if args.scenes is not None:
            framing["scenes"] = args.scenes
        scene_paths = render_scenes(folder, **framing)
        rows = pair_psnrs(model_relighter(model), scene_paths)
    except (ValueError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    from relight.files.fileio import file_sha256

    m = means(rows)
    print(table(rows, model.name))
    errors = normal_errors(model, scene_paths)
    print("median normal error per image (deg), model / flat: "
          + ", ".join(f"{e['model']:.1f} / {e['flat']:.1f}" for e in errors)
          + f"; mean {np.mean([e['model'] for e in errors]):.1f} / {np.mean([e['flat'] for e in errors]):.1f}")
    print(f"\nmeasured: {model.name} (sha256 {file_sha256(model)[:12]}): mean PSNR model {m['relit']:.2f} dB, "
          f"identity {m['identity']:.2f} dB, exposure-matched {m['exposure-matched']:.2f} dB over {len(rows)} "
          f"pairs (scenes in {folder})")
    for name in BASELINES:
        d = per_scene(rows, "relit", name)
        print(f"relit over {name}, per scene {np.round(d, 2).tolist()}: {describe(lower_bound(d), 'dB')}")
    d = per_scene(errors, "flat", "model")
    print(f"normals, the flat person's error less the model's, per scene {np.round(d, 1).tolist()}: "
          f"{describe(lower_bound(d), 'deg')}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    os.chdir(ROOT)
    sys.exit(main())
