"""The per-scene options of the farm: one bpy-free class for the command line,
the workers and farm.scene (which needs bpy) alike. The passes are those of
relight/files/scene_passes.py, the scene files' one table."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from relight.files import scene_passes
from relight.lighting.sh import num_coeffs

SPECULAR_MODES = ("auto", "on", "off")
LIGHT_POOLS = ("train", "heldout")
LOOK_POOLS = ("train", "heldout")  # farm.synthesis.looks
# OIDN prefilter of the albedo/normal guides: "fast" trusts them as rendered (they are
# nearly noise-free: first-hit values through a box filter), "accurate" denoises them
# too, which cost 20% of path-tracing time (docs/benchmarks/farm_runner.md).
DENOISE_PREFILTERS = ("fast", "accurate")


@dataclass(frozen=True)
class SceneOptions:
    """What one scene renders; every field is recorded in its sidecar."""

    resolution: int = 256
    lights: int = 4
    samples: int = 64
    denoise: bool = True
    denoise_prefilter: str = "fast"
    sh_order: int = 4
    bake_directions: int = 256
    passes: frozenset = scene_passes.DEFAULT
    specular: str = "auto"
    light_pool: str = "train"
    # issue 37: the framings a scene draws from (farm.synthesis.camera.FRAMINGS, "all" or a comma list;
    # "full-body" draws nothing new: the scenes of before) and the share of lights that are hard
    # lights (farm.synthesis.hard_lights; 0 draws nothing new)
    framing: str = "full-body"
    hard_lights: float = 0.0
    # issue 47: people per scene, a count or a range drawn uniformly ("2-5"; farm.synthesis.people).
    # "1" draws nothing new and is left out of the sidecar: the scenes of before, byte for byte
    people: str = "1"
    # issue 45: the looks a person draws (farm.synthesis.looks): "train", the farm's of before, or
    # "heldout", the unfamiliar look training never sees. "train" is left out of the sidecar (the
    # sidecars of before, byte for byte): a sidecar without the key is of the train pool
    look_pool: str = "train"

    def validate(self) -> None:
        checks = (
            ("resolution", self.resolution, 8, 8192),
            ("lights", self.lights, 1, 64),
            ("samples", self.samples, 1, 1 << 16),
            ("sh_order", self.sh_order, 0, 16),
            ("bake_directions", self.bake_directions, 16, 1 << 16),
        )
        for name, value, lo, hi in checks:
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not lo <= value <= hi:
                raise ValueError(f"SceneOptions.{name} must be an integer in [{lo}, {hi}], got {value!r}")
        if not isinstance(self.denoise, bool):
            raise ValueError(f"SceneOptions.denoise must be a bool, got {self.denoise!r}")  # bad option values are ValueErrors project-wide
        if self.denoise_prefilter not in DENOISE_PREFILTERS:
            raise ValueError(f"SceneOptions.denoise_prefilter must be one of {DENOISE_PREFILTERS}, "
                             f"got {self.denoise_prefilter!r}")
        passes = frozenset(self.passes)
        if not passes <= set(scene_passes.CHOICES):
            raise ValueError(f"SceneOptions.passes must be a subset of {sorted(scene_passes.CHOICES)}, "
                             f"got {sorted(passes)}")
        if self.specular not in SPECULAR_MODES:
            raise ValueError(f"SceneOptions.specular must be one of {SPECULAR_MODES}, got {self.specular!r}")
        from farm.synthesis.camera import parse_framings

        parse_framings(self.framing)
        from farm.synthesis.people import parse_people

        parse_people(self.people)
        if isinstance(self.hard_lights, bool) or not isinstance(self.hard_lights, (int, float)) \
                or not 0.0 <= float(self.hard_lights) <= 1.0:
            raise ValueError(f"SceneOptions.hard_lights must be a share in [0, 1], got {self.hard_lights!r}")
        if self.look_pool not in LOOK_POOLS:
            raise ValueError(f"SceneOptions.look_pool must be 'train' or 'heldout', got {self.look_pool!r}")
        if self.light_pool not in LIGHT_POOLS:
            raise ValueError(f"SceneOptions.light_pool must be 'train' or 'heldout', got {self.light_pool!r}")

    def to_json(self) -> dict:
        """Plain JSON form (passes as a sorted list); `from_json` rebuilds it."""
        d = asdict(self)
        d["passes"] = sorted(self.passes)
        if d["people"] == "1":
            del d["people"]
        if d["look_pool"] == "train":
            del d["look_pool"]
        return d

    @classmethod
    def from_json(cls, settings: dict) -> "SceneOptions":
        # sidecars written before the prefilter was an option rendered with "accurate"
        settings = {"denoise_prefilter": "accurate", **settings}
        return cls(**dict(settings, passes=frozenset(settings["passes"])))

    def expected_channels(self) -> int:
        """Float32 channels a scene EXR holds for these options (relight/files/scene_passes.py)."""
        from farm.synthesis.people import parse_people

        return scene_passes.channel_count(self.passes, num_coeffs(self.sh_order), self.lights,
                                          parse_people(self.people)[1])

    def path_traced_images(self) -> int:
        """Path-traced images one scene yields when nothing is skipped."""
        return self.lights if "pt" in self.passes else 0
