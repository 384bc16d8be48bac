"""Quality presets: the one table that maps Draft / Balanced / Best to a model and a
working size. `relight image --quality`, `Relighter(working_size=preset("draft").working_size)` and the
Blender add-on (blender_addon/logic/quality.py) all read PRESETS.

`model` names an entry of the model registry (relight/models/models.json); the
precision is a property of that file (its `relight.precision` metadata), so an
fp16 preset would name an fp16 export (none ships: docs/model.md). None runs the
registry's default model. `working_size` is the longest side of the crop around
the person that the network sees (relight.network.runtime). The figures that should
decide this table come from benchmarks/bench_tradeoffs.py (docs/TRADEOFFS.md).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from relight.network.tta import AGREED, AUGMENTATIONS

__all__ = ["DEFAULT", "MATTE_COST_RANK", "PRESETS", "QualityPreset", "model_name", "model_path", "preset"]


MATTE_COST_RANK = {"selfie": 0, "pose": 1, "ensemble": 2}  # relight.person.matte's methods, cheapest first


@dataclass(frozen=True)
class QualityPreset:
    key: str             # "draft", "balanced", "best": the CLI choice (the add-on uses it upper-cased)
    label: str           # what a UI shows
    model: str | None    # registry name; None: the registry's default model
    working_size: int    # longest side, in pixels, of the crop the network sees
    description: str
    augment: tuple = ()  # relight.network.tta augmentations: [(scale, mirrored)] run and averaged
    refine: int = 0      # relight.network.refine iterations on the photo's light (0: off)
    matte_method: str = "ensemble"  # relight.person.matte's person segmenter ("selfie": faster)
    augment_until_agreed: float | None = None  # stop the augmentations when the first agrees (relight.network.tta.AGREED)
    ensemble: tuple = ()  # registry names of other networks whose answers join the average

    def work(self) -> tuple:
        """What the preset does, each part ordered by its cost: (working size, extra network runs,
        refinement iterations, the person segmenter's cost rank: selfie < pose < ensemble)."""
        return (self.working_size, len(self.augment), self.refine, MATTE_COST_RANK[self.matte_method])

    def decompose_options(self, working_size: bool = True) -> dict:
        """Relighter.decompose's keyword arguments for this preset. working_size=False: without
        the working size, for a Relighter opened at this preset's (Relighter(working_size=
        preset.working_size), as relight image's is): the size is then given once."""
        size = {"working_size": self.working_size} if working_size else {}
        return {**size, "augment": self.augment, "refine": self.refine, "matte_method": self.matte_method,
                "augment_until_agreed": self.augment_until_agreed, "ensemble": self.ensemble}

    def registry_name(self, registry: dict) -> str | None:
        """Registry name this preset runs: its own model when registered, else the registry's
        default, else None (no model installed)."""
        if self.model and self.model in registry["models"]:
            return self.model
        default = registry.get("default")
        return default if default and default in registry["models"] else None

    def model_file(self, registry_path: str | os.PathLike | None = None) -> Path:
        """The ONNX file this preset runs (see registry_name); ValueError when none is installed."""
        from relight import models

        registry_path = Path(models.REGISTRY_PATH if registry_path is None else registry_path)
        registry = models.load_registry(registry_path)
        name = self.registry_name(registry)
        if name is None:
            raise ValueError("no relighting model is installed yet: pass --model MODEL.onnx "
                             "(make one with `python -m export WEIGHTS.safetensors --out MODEL.onnx`)")
        return registry_path.parent / registry["models"][name]["file"]


# Fastest first. From the rule of benchmarks/bench_quality.py on the held-out set with the
# release of issue 25 and its level prior (docs/TRADEOFFS.md, "Speed for accuracy", 2026-11-26;
# 96 pairs, paired against the network alone at its trained size): Balanced was the network once at
# 128 px, the size it was trained at (21.96 dB, SI 24.42); Best = the fastest front point within
# 0.05 dB of the most accurate within 3 s: the network six times at 144 px (the crop mirrored, and
# at 0.75x / 1.25x: 108 and 180 px) and averaged, the last four skipped when the mirrored run
# agrees with the first (relight.network.tta.AGREED) (+0.66 +- 0.14 dB, SI +1.11; at 128 px +0.55; 160
# and 176 px tie with 144, 192 px loses); light refinement (+0.03 on top at 160 px, at 1.4x the
# time), a second network, runs at other exposures or turned in the image plane do not pay;
# Draft = the fastest front point that keeps >= 90% of the network alone's gain over identity (issue 26):
# the network once at 128 px, with the selfie segmenter alone (65 against 102 ms; its
# matte is less exact: mean IoU 0.944 against 0.97, docs/MATTE.md). 112 px was Draft before:
# -0.28 +- 0.16 dB (80% of the gain).
# Balanced since issue 37 (2026-11-27): the network once is far from mirror-equivariant (a side-lit
# person differs from its mirror image by 30-80 %: the estimated light), so Balanced averages it with
# its run on the mirrored crop, Best's first augmentation (equivariant by construction; held-out
# +0.44 +- 0.20 dB head-and-shoulders, +0.34 +- 0.13 waist-up, +0.34 +- 0.11 full-body, +0.37 +- 0.07
# on data/heldout256; 1.1-1.35x Balanced's time before;
# docs/TRADEOFFS.md, "Balanced averaged with its mirrored run"). Draft stays the network once.
PRESETS: tuple[QualityPreset, ...] = (
    QualityPreset("draft", "Draft", "geometry", 128,
                  "Fastest: the network once at 128 px (Balanced adds its run on the mirrored photo); a "
                  "quicker, rougher person matte",
                  matte_method="selfie"),
    QualityPreset("balanced", "Balanced", "geometry", 128,
                  "The network at 128 px, the size it was trained at, averaged with its run on the mirrored "
                  "photo: a light from one side relights the person as its mirror image would",
                  augment=AUGMENTATIONS[:1]),
    QualityPreset("best", "Best", "geometry", 144,
                  "Slowest: up to six network runs at 144 px (mirrored, three sizes) averaged; two when "
                  "the mirrored run agrees with the first", augment=AUGMENTATIONS, augment_until_agreed=AGREED),
)
DEFAULT = "balanced"


def preset(key: str) -> QualityPreset:
    """The preset called `key` (any case); ValueError otherwise."""
    for p in PRESETS:
        if isinstance(key, str) and p.key == key.lower():
            return p
    raise ValueError(f"unknown quality preset {key!r}; expected one of {', '.join(p.key for p in PRESETS)}")


def model_name(key: str, registry: dict) -> str | None:
    """Registry name the preset called `key` runs (QualityPreset.registry_name)."""
    return preset(key).registry_name(registry)


def model_path(key: str, registry_path: str | os.PathLike | None = None) -> Path:
    """The ONNX file the preset called `key` runs (QualityPreset.model_file); ValueError when none
    is installed."""
    return preset(key).model_file(registry_path)
