"""Cast shadows on farm scenes relit by a hard light (issue 46): does the shadow pass pay, and its ceiling.

For each scene and each pair (photo under light a -> truth under a hard light b, the farm's sun /
studio key / lamp), the photo relit at the scene's size under b's SH light, five ways:

  network            the model's decomposition, SH shading only (today's relight)
  network+relief     the same with the cast shadows of its key (relight.lighting.directional) over the
                     relief of the network's own normals (the product's path: relight.network.shadowing)
  network+depth      the same over the farm's true depth pass (pinhole): the depth ceiling
  truth              the true albedo x the SH shading of the true normals (Lambert): no cast shadows
  truth+depth        the same with cast shadows over the true depth: the ceiling of SH + one shadowed key
  network+netdepth   (a model with the depth head, issue 45) shadows over the network's own depth, scaled
                     to its normals' slopes (relight.network.shadowing: the product's path with the head)
  truth+netdepth     the true shading with shadows over the network's depth: the depth's worth alone

Reported per variant: PSNR over the person (interior pixels), and the light's response: the least-squares
slope and the correlation of the relit log-luminance change (relit / photo) against the true change
(target / photo), means removed (1 and 1 = physics; model.scoring.metrics.light_response).

    PYTHONPATH=. .venv/bin/python benchmarks/bench_cast_shadows.py DATA [DATA ...] [--model M.onnx]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from model.samples.data import network_input
from model.scoring import metrics
from model.scoring.metrics import light_response
from model.scoring.predictor import Predictor
from relight.files.dataset import list_finished_scenes, read_scene, traced_lights
from relight.geometry.shadows import cast_visibility
from relight.lighting.directional import directional_part
from relight.lighting.key_light import key_coeffs
from relight.models import REGISTRY_PATH
from relight.network.prt import lambert_transport
from relight.network.shadowing import ShadowCaster

VARIANTS = ("network", "network+relief", "network+depth", "truth", "truth+depth", "truth+relief", "network+truerelief")
DEPTH_VARIANTS = ("network+netdepth", "truth+netdepth")   # models with the depth head only
THICKNESS_M = 0.3   # metres an occluder of the true depth pass reaches behind its front (a torso's depth)


def psnr(pred: np.ndarray, gt: np.ndarray, weight: np.ndarray) -> float:
    """model.scoring.metrics.psnr over weight > 0 of both images clipped to [0, 1], as this script always
    scored (so docs/EVALUATION.md's "Cast shadows" figures stay what it prints)."""
    return metrics.psnr(np.clip(pred, 0, 1), np.clip(gt, 0, 1), weight > 0)


def shade(transport: np.ndarray, light: np.ndarray) -> np.ndarray:
    return np.einsum("hwn,nc->hwc", transport, light)


def pairs_of(meta: dict) -> list[tuple[int, int]]:
    """(a, b): b a hard light, a any other path-traced light (maps first)."""
    traced = traced_lights(meta)
    hard = [k for k in traced if meta["lights"][k].get("hard")]
    return [(a, b) for b in hard for a in traced if a != b]


def run_scene(path: Path, predictor: Predictor, rows: dict) -> None:
    scene = read_scene(path)
    meta = scene.meta
    h, w = scene.resolution
    order = predictor.order
    n = (order + 1) ** 2
    weight = (scene.alpha[..., 0] > 0.99).astype(np.float32)
    focal_px = meta["camera"]["focal_mm_35mm_equivalent"] / meta["camera"]["sensor_width_mm"] * w
    normal = np.where(np.linalg.norm(scene.normal, axis=-1, keepdims=True) > 0, scene.normal, [0.0, -1.0, 0.0])
    true_t = lambert_transport(normal, order)
    for a, b in pairs_of(meta):
        photo, target = scene.images[a], scene.images[b]
        light_b = np.asarray(meta["lights"][b]["sh"], np.float64)[:n]
        key = directional_part(light_b)
        if key is None:
            continue
        out = predictor(network_input(photo.transpose(2, 0, 1), scene.alpha.transpose(2, 0, 1))[None])
        albedo = out["albedo"][0].transpose(1, 2, 0)
        transport = out["transport"][0].transpose(1, 2, 0)
        residual = out["residual"][0].transpose(1, 2, 0)
        alpha = out["alpha"][0, 0]
        key_sh = key_coeffs(key, order)
        base = shade(transport, light_b)
        key_shading = np.maximum(shade(transport, key_sh), 0.0)   # shadows remove light only
        E = shade(residual, light_b)
        caster = ShadowCaster(transport, alpha, np.arange(h * w))
        v_relief = caster.visibility(key)
        gt_inside = scene.alpha[..., 0] > 0.5
        v_depth = cast_visibility(scene.depth[..., 0], gt_inside, key.direction, math.degrees(key.half_angle),
                                  focal_px=focal_px, thickness=THICKNESS_M)
        true_base, true_key = shade(true_t, light_b), np.maximum(shade(true_t, key_sh), 0.0)
        v_true_relief = ShadowCaster(true_t, scene.alpha[..., 0] * gt_inside, np.arange(h * w)).visibility(key)
        relit = {
            "network": albedo * base + E,
            "network+relief": albedo * (base - (1 - v_relief)[..., None] * key_shading) + E,
            "network+depth": albedo * (base - (1 - v_depth)[..., None] * key_shading) + E,
            "truth": scene.albedo * true_base,
            "truth+depth": scene.albedo * (true_base - (1 - v_depth)[..., None] * true_key),
            "truth+relief": scene.albedo * (true_base - (1 - v_true_relief)[..., None] * true_key),
            "network+truerelief": albedo * (base - (1 - v_true_relief)[..., None] * key_shading) + E,
        }
        if "depth" in out:  # the depth head's answer, as the runtime casts shadows over it
            v_net = ShadowCaster(transport, alpha, np.arange(h * w), network_depth=out["depth"][0, 0]).visibility(key)
            relit["network+netdepth"] = albedo * (base - (1 - v_net)[..., None] * key_shading) + E
            relit["truth+netdepth"] = scene.albedo * (true_base - (1 - v_net)[..., None] * true_key)
        for name, image in relit.items():
            image = np.maximum(image, 0.0)
            slope, corr, _ = light_response(photo, image, target, weight)
            rows[name].append((psnr(image, target, weight), slope, corr))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", nargs="+", type=Path, help="farm output folders (scenes with hard lights)")
    parser.add_argument("--model", type=Path, default=None, help="ONNX model (default: the registry's default)")
    args = parser.parse_args(argv)
    model = args.model
    if model is None:
        from relight.models import load_registry
        registry = load_registry(REGISTRY_PATH)
        model = REGISTRY_PATH.parent / registry["models"][registry["default"]]["file"]
    predictor = Predictor(model)
    print(f"model {model.name}; light response = slope / correlation of the relit log-luminance change "
          f"against the truth's (1 / 1 = physics)\n")
    print("| set | pairs | variant | PSNR dB | slope | correlation |")
    print("|---|---|---|---|---|---|")
    for folder in args.data:
        rows = {name: [] for name in VARIANTS + (DEPTH_VARIANTS if predictor.has_depth else ())}
        for path in list_finished_scenes(folder):
            run_scene(path, predictor, rows)
        for name in rows:
            r = np.array(rows[name]) if rows[name] else np.full((1, 3), np.nan)
            print(f"| {folder.name} | {len(rows[name])} | {name} | {np.nanmean(r[:, 0]):.2f} | "
                  f"{np.nanmean(r[:, 1]):.2f} | {np.nanmean(r[:, 2]):.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
