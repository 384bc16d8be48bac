"""CI guard: the shipped default model must relight unseen scenes better than doing nothing.

The farm renders a few small scenes lit only by the held-out maps
(`--light-pool heldout`, never seen in training). For every ordered pair of
a scene's lights (a, b), the registered default model decomposes the
path-traced image under a through relight.network.runtime (as a user would run it,
with the GT alpha as the mask) and relights it with light b's SH
coefficients from the sidecar, which are in the photo-camera frame the
network uses (docs/conventions.md, docs/dataset.md). The relit person is
compared with Cycles' image under b: PSNR over the person's fully covered
pixels (GT alpha > 0.999, as model/evaluate.py's default: edge pixels mix in
each light's own background), linear, peak 1 (model/scoring/metrics.py). Its mean over the pairs must beat the
identity baseline (image a as is) and the exposure-matched identity
(image a times L00_b / L00_a per channel) by the measured margins below.

No registered default model, or margins not yet measured: the guard FAILS.

To measure (prints the per-pair table and the means):

    .venv/bin/python tests/test_shipped_model.py [MODEL.onnx] [--scenes-dir DIR]
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent

# The scenes: deterministic for a seed (same bodies, poses, lights, samples).
SCENES, SEED, RES, LIGHTS, SAMPLES, ORDER = 3, 20250, 128, 2, 16, 4
# issue 37: the same guard on head-and-shoulders photos (the farm's framing), its own seed
CLOSE_FRAMING, CLOSE_SEED = "head-and-shoulders", 20251
# The runtime's working size: the default quality preset's, as a user gets it (relight/network/quality.py).
WORKING_SIZE = 128

# measured: geometry.onnx (sha256 982994b24958): mean PSNR model 18.49 dB, identity 13.91 dB,
# exposure-matched 15.68 dB over 6 pairs (`.venv/bin/python tests/test_shipped_model.py`; the farm's
# people of issue 20 make these scenes harder than the ones the margins were first measured on).
# Rule: tolerance = half the measured gain over identity (2.29 dB); each margin = measured
# advantage - tolerance, rounded down to 0.1 dB. So the guard demands a real gain over identity
# and over exposure-matched identity, each at least half of what the shipped model shows.
# Re-measured with its level prior (sha256 56ef1e26027c, 2026-11-26): 18.04 dB (+4.14 over
# identity, +2.36 over exposure-matched; the prior gains 0.40 dB on the 96 held-out pairs and
# loses 0.45 on these 6). The rule would now give 2.0 and 0.2; the stricter margins are kept.
MARGIN_OVER_IDENTITY_DB: float | None = 2.2
MARGIN_OVER_EXPOSURE_MATCHED_DB: float | None = 0.5
# measured, mean over the 6 images of each image's median normal error: geometry.onnx 21.3 deg
# (the model shipped before: 23.0); the paper-decomposition models, whose T came out near flat,
# 33.8 (the 2026-11-21 default) and 36.1 (trained with the first geometry model's 190 scenes and
# budget). Bound: half way to the nearer, rounded down.
MAX_MEDIAN_NORMAL_ERROR_DEG: float | None = 27.5
# Re-measured for the every-framing model (issue 37, sha256 caa9df63d60f, 2026-11-27): 18.34 dB
# (+4.44 over identity, +2.66 over exposure-matched), normals 20.4 deg; the margins above stand.
# Head-and-shoulders (`.venv/bin/python tests/test_shipped_model.py --close`), the same rule:
# every-framing model 24.83 dB, identity 22.58, exposure-matched 25.91 (+2.25 / -1.08 dB; one pair
# is a map against itself turned 60 degrees, where the exposure-matched photo scores 34 dB);
# tolerance 1.1 dB (half of +2.25), so margins +1.1 and -2.2. The full-body release it replaced:
# 22.23 dB (-0.35 / -3.68): it fails both. Normals: 18.9 deg against the release's 41.6; the bound
# is half way, rounded down.
CLOSE_MARGIN_OVER_IDENTITY_DB = 1.1
CLOSE_MARGIN_OVER_EXPOSURE_MATCHED_DB = -2.2
CLOSE_MAX_MEDIAN_NORMAL_ERROR_DEG = 30.0


# ------------------------------------------------------------------ the measurement


def default_model() -> Path:
    """The registry's default model file; raises ValueError naming what is missing."""
    from relight import models

    path = models.default_model_path()  # ValueError when no default is registered
    if not path.is_file():
        raise ValueError(f"relight/models/models.json names a default model, but {path} does not exist")
    return path


def render_scenes(folder: Path, framing: str = "full-body", seed: int = SEED) -> list[Path]:
    """The guard's scenes in `folder` (rendered by the farm; finished ones are kept)."""
    import importlib.util

    if importlib.util.find_spec("bpy") is None:
        raise RuntimeError("the shipped-model guard renders its scenes with the farm: "
                           "install bpy (pip install -e '.[farm]')")
    cmd = [sys.executable, "-m", "farm", "--out", str(folder), "--scenes", str(SCENES), "--seed", str(seed),
           "--framing", framing, "--res", str(RES), "--lights", str(LIGHTS), "--samples", str(SAMPLES), "--order", str(ORDER),
           "--light-pool", "heldout", "--workers", "1", "--resume", "--no-progress"]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"farm failed ({done.returncode}): {' '.join(cmd[1:])}\n{done.stderr[-2000:]}")
    from relight.files import dataset

    paths = dataset.list_finished_scenes(folder)
    if len(paths) != SCENES:
        raise RuntimeError(f"farm finished {len(paths)} of {SCENES} scenes in {folder}")
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


def normal_errors(model_path: Path, scene_paths: list[Path]) -> list[float]:
    """Median angle (degrees) per scene and light between the normals the model's transport
    implies (T's band-1 direction) and the farm's normal pass, over fully covered pixels."""
    from model.scoring import metrics
    from relight.files import dataset
    from relight.network.runtime import Relighter

    relighter = Relighter(model_path, working_size=WORKING_SIZE)
    out = []
    for path in scene_paths:
        scene = dataset.read_scene(path)
        weight = metrics.interior_weight(scene.alpha[..., 0]) > 0
        for image in scene.images:
            dec = relighter.decompose(image, mask=scene.alpha[..., 0])
            t = dec.transport
            d = np.stack([t[..., 3], t[..., 1], t[..., 2]], axis=-1)
            d /= np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)
            full = dec._to_full(np.ascontiguousarray(d, dtype=np.float32))  # to the scene's pixels
            full /= np.maximum(np.linalg.norm(full, axis=-1, keepdims=True), 1e-12)
            cos = np.clip((full * scene.normal).sum(-1), -1.0, 1.0)[weight]
            out.append(float(np.median(np.degrees(np.arccos(cos)))))
    return out


def model_relighter(model_path: Path):
    """relight_pair for pair_psnrs: the runtime's decompose (GT alpha as the mask) + relight."""
    from relight.network.runtime import Relighter

    relighter = Relighter(model_path, working_size=WORKING_SIZE)

    def relight_pair(scene, a, b):
        dec = relighter.decompose(scene.images[a], mask=scene.alpha[..., 0])
        light_b = scene.lights[b]["sh"][:(relighter.sh_order + 1) ** 2]
        return dec.relight(light_b)  # SH array: used as given (camera frame, no normalization)

    return relight_pair


def means(rows: list[dict]) -> dict[str, float]:
    return {k: float(np.mean([r[k] for r in rows])) for k in ("relit", "identity", "exposure-matched")}


def table(rows: list[dict], label: str) -> str:
    lines = [f"| scene | light a -> b | {label} | identity | exposure-matched |", "|---|---|---|---|---|"]
    lines += [f"| {r['scene']} | {r['a']} -> {r['b']} | {r['relit']:.2f} | {r['identity']:.2f} | "
              f"{r['exposure-matched']:.2f} |" for r in rows]
    m = means(rows)
    lines.append(f"| mean of {len(rows)} | | {m['relit']:.2f} | {m['identity']:.2f} | {m['exposure-matched']:.2f} |")
    return "\n".join(lines)


def shortfalls(rows: list[dict], over_identity: float, over_exposure_matched: float) -> list[str]:
    """Why the relit mean PSNR fails the margins ([] when it passes)."""
    m = means(rows)
    out = []
    for name, margin in (("identity", over_identity), ("exposure-matched", over_exposure_matched)):
        if not m["relit"] >= m[name] + margin:
            out.append(f"mean PSNR {m['relit']:.2f} dB does not beat {name} ({m[name]:.2f} dB) "
                       f"by {margin:.2f} dB")
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
    that the guard checks the registry before it spends a minute rendering."""
    return _lazy_scenes(tmp_path_factory, "heldout_scenes")


@pytest.fixture(scope="module")
def close_scenes(tmp_path_factory):
    """The same, framed head-and-shoulders (issue 37)."""
    return _lazy_scenes(tmp_path_factory, "heldout_close_scenes", framing=CLOSE_FRAMING, seed=CLOSE_SEED)


def test_shipped_default_model_beats_identity_on_held_out_lights(scenes):
    try:
        model = default_model()
    except ValueError as exc:  # a failure, not a skip: shipping without a model is the bug
        pytest.fail(f"no shipped default model to guard ({exc}); register one with `python -m export "
                    "WEIGHTS.safetensors --out relight/models/NAME.onnx --register NAME`")
    if MARGIN_OVER_IDENTITY_DB is None or MARGIN_OVER_EXPOSURE_MATCHED_DB is None:
        pytest.fail("tests/test_shipped_model.py: the margins are not measured yet; run "
                    "`.venv/bin/python tests/test_shipped_model.py` and fill in MARGIN_* and the "
                    "`# measured:` comment")
    rows = pair_psnrs(model_relighter(model), scenes())
    print(table(rows, model.name))
    problems = shortfalls(rows, MARGIN_OVER_IDENTITY_DB, MARGIN_OVER_EXPOSURE_MATCHED_DB)
    assert not problems, f"{model.name}: " + "; ".join(problems) + "\n" + table(rows, "model")


def test_shipped_default_model_relights_head_and_shoulders(close_scenes):
    """Issue 37: on head-and-shoulders photos the model must beat one exposure change, which the
    full-body-only release did not do by much (module docstring: the margins and their rule)."""
    rows = pair_psnrs(model_relighter(default_model()), close_scenes())
    print(table(rows, "head-and-shoulders"))
    problems = shortfalls(rows, CLOSE_MARGIN_OVER_IDENTITY_DB, CLOSE_MARGIN_OVER_EXPOSURE_MATCHED_DB)
    assert not problems, "head-and-shoulders: " + "; ".join(problems) + "\n" + table(rows, "model")
    errors = normal_errors(default_model(), close_scenes())
    print("median normal error per image (deg):", ", ".join(f"{e:.1f}" for e in errors))
    assert float(np.mean(errors)) < CLOSE_MAX_MEDIAN_NORMAL_ERROR_DEG, errors


def test_shipped_default_model_predicts_normals(scenes):
    """The geometry the relighting is built on: the median normal error over the guard's
    scenes stays below the measured bound (a model whose transport collapsed to flat
    shading, as the paper-layout models did, has no normal to speak of and fails it)."""
    if MAX_MEDIAN_NORMAL_ERROR_DEG is None:
        pytest.fail("tests/test_shipped_model.py: the normal bound is not measured yet")
    errors = normal_errors(default_model(), scenes())
    print("median normal error per image (deg):", ", ".join(f"{e:.1f}" for e in errors))
    assert float(np.mean(errors)) < MAX_MEDIAN_NORMAL_ERROR_DEG, errors


def test_guard_passes_the_true_decomposition(scenes):
    """The harness itself: the scene's own albedo and transport (GT), relit by the runtime with
    light b's sidecar coefficients, must clear the guard. This proves the frames, SH order and
    compositing line up, so a failing model is the model's fault, not the harness's."""
    from relight.network.runtime import Decomposition

    def relight_pair(scene, a, b):
        h, w = scene.resolution
        n = (ORDER + 1) ** 2
        gt = Decomposition(
            albedo=scene.albedo, transport=np.ascontiguousarray(scene.transport[..., :n]),
            residual=np.zeros((h, w, n), np.float32), light=scene.lights[a]["sh"][:n].astype(np.float32),
            alpha=scene.alpha[..., 0], box=(0, h, 0, w), working_size=(h, w), photo=scene.images[a],
            photo_working=scene.images[a], mask=scene.alpha[..., 0], sh_order=ORDER)
        return gt.relight(scene.lights[b]["sh"][:n])

    rows = pair_psnrs(relight_pair, scenes())
    print(table(rows, "GT decomposition"))
    # measured (these 6 pairs, fully covered pixels): GT 27.91 dB, identity 20.26, exposure-matched
    # 23.10 (+7.65, +4.81 dB). Margins: half of each advantage, rounded down to 0.1 dB, the rule
    # the model's margins follow. The same GT with light b turned 90 degrees about Z (a frame
    # error) measured 24.01 dB (+3.75, +0.91): it fails both. Order 4 and no residual
    # (specular, interreflection) keep even the GT well below the path-traced image.
    assert not shortfalls(rows, 3.8, 2.4), table(rows, "GT decomposition")


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # torch's legacy (TorchScript) exporter
def test_guard_rejects_a_random_weight_model(scenes, tmp_path):
    """The guard can fail: a seeded random-weight network run through the same runtime path
    gives finite PSNRs that do not even reach the identity baseline."""
    torch = pytest.importorskip("torch")
    pytest.importorskip("onnx")
    from export.random_model import export_random_model

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        path, _, _ = export_random_model(tmp_path / "random.onnx", seed=0, sh_order=ORDER)
    finally:
        torch.set_num_threads(before)
    rows = pair_psnrs(model_relighter(path), scenes())
    print(table(rows, "random weights"))
    assert all(np.isfinite(r["relit"]) for r in rows)
    assert len(shortfalls(rows, 0.0, 0.0)) == 2, table(rows, "random weights")


# ------------------------------------------------------------------ measuring the margins


def main(argv=None) -> int:
    import argparse
    import tempfile

    p = argparse.ArgumentParser(prog="tests/test_shipped_model.py",
                                description="Measure the guard's PSNRs for a model (default: the registered default).")
    p.add_argument("model", nargs="?", help="ONNX model (default: the registry's default)")
    p.add_argument("--scenes-dir", type=Path, help="keep the rendered scenes here (reused when finished)")
    p.add_argument("--close", action="store_true", help=f"the {CLOSE_FRAMING} scenes (seed {CLOSE_SEED})")
    args = p.parse_args(argv)
    try:
        model = Path(args.model) if args.model else default_model()
        folder = args.scenes_dir or Path(tempfile.mkdtemp(prefix="relight_guard_"))
        framing = dict(framing=CLOSE_FRAMING, seed=CLOSE_SEED) if args.close else {}
        scene_paths = render_scenes(folder, **framing)
        rows = pair_psnrs(model_relighter(model), scene_paths)
    except (ValueError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    from relight.files.fileio import file_sha256

    m = means(rows)
    print(table(rows, model.name))
    errors = normal_errors(model, scene_paths)
    print("median normal error per image (deg): " + ", ".join(f"{e:.1f}" for e in errors)
          + f"; mean {np.mean(errors):.1f}")
    print(f"\nmeasured: {model.name} (sha256 {file_sha256(model)[:12]}): mean PSNR model {m['relit']:.2f} dB, "
          f"identity {m['identity']:.2f} dB, exposure-matched {m['exposure-matched']:.2f} dB over {len(rows)} "
          f"pairs (scenes in {folder})")
    print(f"advantage: {m['relit'] - m['identity']:+.2f} dB over identity, "
          f"{m['relit'] - m['exposure-matched']:+.2f} dB over exposure-matched")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    os.chdir(ROOT)
    sys.exit(main())
