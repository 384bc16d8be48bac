"""Clip relighting against ground truth: `python -m model.evaluate_clips CLIP_DIR ... [--stability S]`.

Reads farm clips (`python -m farm ... --clip-frames F`, farm/clips.py: a person moving
in front of a fixed camera; light 0 is the shot's light, light 1 the target), relights
each clip's light-0 frames to light 1 with relight.command.clip.ClipRelighter, once frame by
frame independently (stability 0, `relight image` on each frame) and once for each
--stability and --mode, and measures, over the person:

* **flicker**: the mean absolute frame-to-frame change of the relit clip over the
  pixels either frame's true matte covers, divided by the clip's own mean there
  (relative to the image), averaged over the frame pairs; reported as the excess
  over the ground-truth clip's own flicker (its motion), so 0 is "as steady as the
  truth" and below 0 steadier;
* **PSNR** of each frame against the truth (model.scoring.metrics.psnr over the true
  matte), averaged over frames: stabilising must not cost per-frame accuracy;
* the milliseconds a frame takes (the whole ClipRelighter.relight call).

The truth of a relit frame is the person path-traced under light 1 over the
frame's own background (what a perfect relighter outputs). numpy + onnxruntime only.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from model.scoring.metrics import psnr

REGION_ALPHA = 0.5  # true alpha above which a pixel is the person, for the flicker region
SOURCES = ("prt", "pt")


def load_clips(folders, max_frames: int | None = None, source: str = "prt") -> list[dict]:
    """Each clip of the farm folders: {"name", "frames" [T, H, W, 3] (light 0), "alpha"
    [T, H, W], "truth" [T, H, W, 3] (light 1 over the light-0 background), "light" [n, 3]}.
    source "pt": the path-traced person; "prt": the PRT person (albedo x baked transport .
    light: noise-free), over the path-traced background either way."""
    if source not in SOURCES:
        raise ValueError(f"source must be one of {SOURCES}, got {source!r}")
    from relight.files.dataset import list_finished_scenes, read_scene

    clips = defaultdict(list)
    for folder in folders:
        for path in list_finished_scenes(folder):
            scene = read_scene(path)
            info = scene.meta.get("clip")
            if info is None:
                raise ValueError(f"{path}: not a clip frame (render clips with python -m farm --clip-frames F)")
            clips[(str(folder), info["clip"])].append((info["frame"], scene))
    out = []
    for (folder, clip), frames in sorted(clips.items()):
        frames.sort(key=lambda f: f[0])
        scenes = [s for _, s in frames][:max_frames]
        alpha = np.stack([s.alpha[..., 0] for s in scenes]).astype(np.float32)
        a = alpha[..., None]
        background = np.stack([s.images[0] for s in scenes]).astype(np.float32)
        person = {"pt": lambda k: np.stack([s.images[k] for s in scenes]),
                  "prt": lambda k: np.stack([s.prt[k] for s in scenes])}[source]
        before = a * person(0) + (1.0 - a) * background
        truth = a * person(1) + (1.0 - a) * background
        lights = [np.asarray(s.lights[1]["sh"], np.float32) for s in scenes]
        out.append({"name": f"{Path(folder).name}/clip{clip}", "frames": before, "alpha": alpha, "truth": truth,
                    "light": lights[0], "motion": scenes[0].meta["clip"]["motion"]})
    if not out:
        raise ValueError(f"no clip frames in {', '.join(map(str, folders))}")
    return out


def flicker(frames: np.ndarray, alpha: np.ndarray) -> float:
    """Mean over consecutive frame pairs of sum |X_t - X_{t-1}| / sum X_t over the pixels either
    frame's true alpha covers (> REGION_ALPHA): the clip's change relative to its own level."""
    values = []
    for t in range(1, len(frames)):
        region = (alpha[t] > REGION_ALPHA) | (alpha[t - 1] > REGION_ALPHA)
        if not region.any():
            continue
        change = np.abs(frames[t].astype(np.float64) - frames[t - 1])[region].sum()
        values.append(change / max(float(frames[t][region].sum(dtype=np.float64)), 1e-12))
    return float(np.mean(values)) if values else 0.0


def jitter(frames: np.ndarray, alpha: np.ndarray) -> float:
    """Mean over frame triples of sum |X_t - (X_{t-1} + X_{t+1}) / 2| / sum X_t over the pixels
    any of the three true alphas covers: the clip's change that is not steady over three
    frames (smooth motion cancels, frame-to-frame noise does not)."""
    values = []
    for t in range(1, len(frames) - 1):
        region = (alpha[t - 1] > REGION_ALPHA) | (alpha[t] > REGION_ALPHA) | (alpha[t + 1] > REGION_ALPHA)
        if not region.any():
            continue
        x = frames[t].astype(np.float64)
        change = np.abs(x - 0.5 * (frames[t - 1].astype(np.float64) + frames[t + 1]))[region].sum()
        values.append(change / max(float(x[region].sum()), 1e-12))
    return float(np.mean(values)) if values else 0.0


def relight_clip(clip: dict, relighter, stability: float, mode: str, matte: str,
                 light_window: int | None = None) -> tuple[np.ndarray, float]:
    """(relit frames [T, H, W, 3], mean ms per frame) of one clip. matte "gt": the true alpha is
    each frame's mask (the decomposition alone); "person"/"network": the runtime's mattes."""
    from relight.command.clip import ClipRelighter

    runner = ClipRelighter(relighter, clip["light"], stability=stability, mode=mode,
                           matte="network" if matte == "network" else "person",
                           light_window=light_window if stability > 0 else None)
    out, seconds = [], 0.0
    for t, frame in enumerate(clip["frames"]):
        mask = clip["alpha"][t] if matte == "gt" else None
        t0 = time.perf_counter()
        result = runner.relight(frame, mask)
        seconds += time.perf_counter() - t0
        out.append(result.image)
    return np.stack(out), 1000.0 * seconds / len(out)


def evaluate_clip(clip: dict, relit: np.ndarray) -> dict:
    truth = clip["truth"]
    weight = clip["alpha"]
    return {"flicker_excess": flicker(relit, weight) - flicker(truth, weight),
            "jitter_excess": jitter(relit, weight) - jitter(truth, weight),
            "psnr": float(np.mean([psnr(relit[t], truth[t], weight[t][..., None]) for t in range(len(relit))]))}


def evaluate(folders, model=None, quality: str = "balanced", stabilities=(0.5,), modes=("ema",), matte: str = "person",
             max_frames: int | None = None, threads: int | None = None, source: str = "prt",
             light_windows=(None,)) -> dict:
    """{"rows": [{"method", "flicker_excess", "psnr", "ms"}...], "clips": N, "frames": T}: per-frame
    processing first, then every (stability, mode); each figure the mean over clips."""
    from relight.network import quality as quality_presets
    from relight.network.runtime import Relighter

    clips = load_clips(folders, max_frames, source)
    path = model if model is not None else quality_presets.model_path(quality)
    relighter = Relighter(path, threads=threads, working_size=quality_presets.preset(quality).working_size)
    methods = [("per-frame", 0.0, "ema", None)] + [
        (f"{mode} s={s:g}" + (f" light {w}" if w is not None else ""), s, mode, w)
        for s in stabilities for mode in modes for w in light_windows]
    rows = []
    for name, stability, mode, window in methods:
        per_clip = []
        for clip in clips:
            relit, ms = relight_clip(clip, relighter, stability, mode, matte, window)
            per_clip.append({**evaluate_clip(clip, relit), "ms": ms})
        rows.append({"method": name, **{k: float(np.mean([c[k] for c in per_clip])) for k in per_clip[0]},
                     "per_clip": per_clip})
    base = rows[0]["flicker_excess"]
    for row in rows:
        row["flicker_ratio"] = row["flicker_excess"] / base if base > 0 else float("nan")
        row["psnr_delta"] = row["psnr"] - rows[0]["psnr"]
    return {"rows": rows, "clips": [c["name"] for c in clips], "frames": int(sum(len(c["frames"]) for c in clips)),
            "matte": matte, "quality": quality, "source": source}


def markdown(result: dict) -> str:
    lines = [f"{len(result['clips'])} clips, {result['frames']} frames, {result['source']} frames, matte "
             f"{result['matte']}, quality {result['quality']}", "",
             "| method | flicker excess (% of image) | vs per-frame | jitter excess (%) | PSNR dB | vs per-frame dB "
             "| ms/frame |",
             "|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        lines.append(f"| {r['method']} | {100 * r['flicker_excess']:+.3f} | {r['flicker_ratio']:+.2f} "
                     f"| {100 * r['jitter_excess']:+.3f} | {r['psnr']:.2f} | {r['psnr_delta']:+.2f} | {r['ms']:.1f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m model.evaluate_clips", description=__doc__.split("\n\n")[0])
    p.add_argument("clips", nargs="+", help="farm clip folders")
    p.add_argument("--model", default=None, help="ONNX model (default: the quality preset's)")
    p.add_argument("--quality", default="balanced", choices=("draft", "balanced", "best"))
    p.add_argument("--stability", type=float, nargs="+", default=[0.5])
    p.add_argument("--mode", nargs="+", default=["ema"], choices=("ema", "flow"))
    p.add_argument("--matte", default="person", choices=("person", "gt", "network"),
                   help="person: the segmenter (as `relight video`); gt: the true alpha as each frame's mask")
    p.add_argument("--source", default="prt", choices=SOURCES,
                   help="prt: the noise-free PRT person (default); pt: the path-traced person (each frame denoised "
                        "on its own, so its noise flickers in the input and in the truth)")
    p.add_argument("--frames", type=int, default=None, help="first N frames of each clip")
    p.add_argument("--light-window", type=int, nargs="+", default=[None],
                   help="frames the light is averaged over (default: relight.command.clip's, from the stability)")
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--json", default=None, help="also write the figures as JSON here")
    args = p.parse_args(argv)
    result = evaluate(args.clips, args.model, args.quality, args.stability, args.mode, args.matte, args.frames,
                      args.threads, args.source, args.light_window)
    print(markdown(result))
    if args.json:
        from relight.files.fileio import atomic_write_json

        atomic_write_json(args.json, result, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
