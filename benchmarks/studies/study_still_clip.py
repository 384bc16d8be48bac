"""What moves from frame to frame when a still shot with sensor noise is relit (issue 40, "Clips").

    .venv/bin/python benchmarks/studies/study_still_clip.py [--photos astronaut grace_hopper obama_standing]
        [--height 512] [--frames 12] [--revision REV] [--cli]

A still shot: one bundled photo (evaluation/data/matte_eval/NAME.jpg, resized to --height) repeated
--frames times with independent Gaussian noise of 2 codes on its 8-bit sRGB values, seeded
(tests/support/clip_support.noisy_still). Measured over the photo's hand-made person matte (its reference
in evaluation/data/matte_eval/reference): the low-pass frame-to-frame change of
tests/support/clip_support.lowpass_flicker (model.evaluate_clips.flicker on means over blocks of 1/32 of
the height), as a ratio to the input's own. Relit to the "studio" preset at Balanced (the CLI's
default), stability 0 (each frame alone) and 0.5 (the default).

Then each part that could move is switched to its first-frame value (or the first frame's crop)
and the stabilised clip measured again: what is left when a part is held is that part's share.
Parts: the segmenter's matte (the network's input, its crop box and the composite's alpha), the
crop box alone, the composite's matte alone, the network's light estimate, the level prior's
gains, the shot's light, the transport, the albedo, the working photo (albedo and detail
transfer). `--revision REV`: relight/command/clip.py and relight/command/clip_maps.py as they were at git
revision REV (e.g. the commit before a change), the rest of the project as it is. `--cli`: also
the issue's own path, the frames written as PNG and relit by `relight video FRAMES --light studio`
in a fresh process, the output PNGs read back and measured.
"""

from __future__ import annotations

import argparse
import dataclasses
import subprocess
import sys
import tempfile
import types
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))
EVAL = REPO / "evaluation" / "data" / "matte_eval"
PARTS = ("matte", "box", "composite matte", "light estimate", "level prior", "shot light", "transport",
         "albedo", "working photo", "matte + shot light + transport")


def load_revision(rev: str) -> None:
    """relight.command.clip_maps and relight.command.clip from git revision `rev`, in place of the working tree's."""
    import relight.command

    for name in ("clip_maps", "clip"):
        source = subprocess.run(["git", "show", f"{rev}:relight/command/{name}.py"], cwd=REPO, check=True,
                                capture_output=True, text=True).stdout
        module = types.ModuleType(f"relight.command.{name}")
        module.__file__ = f"{rev}:relight/command/{name}.py"
        sys.modules[module.__name__] = module
        exec(compile(source, module.__file__, "exec"), module.__dict__)
        setattr(relight.command, name, module)


def _onto(value: np.ndarray, d0, d) -> np.ndarray:
    """A working-resolution map of decomposition d0 on d's grid."""
    from relight.command.clip_maps import grid_axes, sample_separable

    if tuple(d0.box) == tuple(d.box) and d0.working_size == d.working_size:
        return value
    gy, gx = grid_axes(d0.box, d0.working_size, d.box, d.working_size)
    h, w = d0.working_size
    out, _ = sample_separable(value, np.clip(gy, 0, h - 1), np.clip(gx, 0, w - 1))
    return out


class _Network:
    """The relighter, its level prior applied here so that the light estimate or the gains can be
    held at the first frame's."""

    def __init__(self, relighter, hold: set):
        self.relighter, self.hold = relighter, hold
        self.first_light = self.first_gains = None

    def __getattr__(self, name):
        return getattr(self.relighter, name)

    def decompose(self, *args, **kwargs):
        d = self.relighter.decompose(*args, level=False, **kwargs)
        if self.first_light is None:
            self.first_light = d.light.copy()
        if "light estimate" in self.hold:
            d = dataclasses.replace(d, light=self.first_light)
        gains = self.relighter.level_prior.gains(d.transport, d.light, d.alpha)
        if self.first_gains is None:
            self.first_gains = gains
        if "level prior" in self.hold:
            gains = self.first_gains
        return dataclasses.replace(d, light=(d.light / gains[None, :]).astype(np.float32))


def held_clip(relighter, light, frames, hold: set, stability: float = 0.5):
    """The frames relit by a ClipRelighter with the parts in `hold` held at the first frame's."""
    import relight.network.runtime as runtime
    from relight.command.clip import ClipRelighter, _with_mask
    from relight.person.matte import person_matte
    from relight.network.quality import preset

    method = preset("balanced").matte_method

    class Held(ClipRelighter):
        first = first_matte = first_albedo = None

        def analyse(self, frame, mask=None):
            if self.first_matte is None or not hold & {"matte", "composite matte"}:
                return super().analyse(frame, mask)
            if "matte" in hold:
                return super().analyse(frame, self.first_matte)
            a = super().analyse(frame, mask)  # the network's own matte; the composite's held in finish
            return a

        def finish(self, analysis, layers=False):
            if self.first_matte is None and analysis.decomposition is not None:
                self.first_matte = analysis.decomposition.mask
            elif "composite matte" in hold:
                analysis.decomposition = _with_mask(analysis.decomposition, self.first_matte)
                analysis.smooth_matte = False
            return super().finish(analysis, layers)

        def _stabilised(self, d, *args):
            self.first = self.first or d
            if "transport" in hold:
                d = dataclasses.replace(d, transport=_onto(self.first.transport, self.first, d))
            if "working photo" in hold:
                d = dataclasses.replace(d, photo_working=_onto(self.first.photo_working, self.first, d))
            out = super()._stabilised(d, *args)
            if "albedo" in hold:
                self.first_albedo = self.first_albedo or out
                out = dataclasses.replace(out, albedo=_onto(self.first_albedo.albedo, self.first_albedo, out))
            return out

    # the level prior applied by _Network only when a part of it is held: otherwise the runtime's own
    network = _Network(relighter, hold) if hold & {"light estimate", "level prior"} else relighter
    runner = Held(network, light, stability=stability, threads=1, matte_method=method)
    if "shot light" in hold:
        update, given = runner.shot_light.update, []

        def first_light(*args):
            given.append(update(*args))
            return given[0]
        runner.shot_light.update = first_light
    with_margin = runtime._with_margin
    if "box" in hold:
        box = with_margin(person_matte(frames[0], None, threads=1, method=method).box, *frames[0].shape[:2])
        runtime._with_margin = lambda *_: box
    try:
        results = [runner.relight(f) for f in frames]
    finally:
        runtime._with_margin = with_margin
    return [r.image for r in results], len({tuple(r.changed) for r in results})


def cli_ratio(frames, region, source: float) -> float:
    """The issue's path: PNG frames through `relight video --light studio` (Balanced, defaults)."""
    from clip_support import lowpass_flicker, write_frames
    from relight.files.photo import read_photo

    with tempfile.TemporaryDirectory() as tmp:
        src = write_frames(Path(tmp) / "in", frames)
        out = Path(tmp) / "out"
        subprocess.run([sys.executable, "-c", "import sys; from relight.cli import main; sys.exit(main())", "video",
                        str(src), "--light", "studio", "--out", str(out)], cwd=REPO, check=True, capture_output=True)
        relit = [read_photo(p)[0] for p in sorted(out.glob("*.png"))]
    return lowpass_flicker(relit, region) / source


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--photos", nargs="+", default=["astronaut", "grace_hopper", "obama_standing"])
    p.add_argument("--height", type=int, default=512)
    p.add_argument("--frames", type=int, default=12)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--revision", default=None, help="relight/clip*.py from this git revision")
    p.add_argument("--parts", nargs="*", default=list(PARTS), help="parts to hold, one at a time (--parts: none)")
    p.add_argument("--cli", action="store_true", help="also through `relight video` on PNG frames")
    args = p.parse_args(argv)
    if args.revision:
        load_revision(args.revision)
    from clip_support import lowpass_flicker, noisy_still, still_region
    from relight.network import quality
    from relight.lighting.light import sh_light
    from relight.network.runtime import Relighter

    relighter = Relighter(quality.model_path("balanced"), threads=1)
    light = sh_light("studio", relighter.sh_order)
    print(f"clip code: {args.revision or 'working tree'}; {args.frames} frames at {args.height} px, noise 2 codes, "
          f"seed {args.seed}; low-pass flicker ratio to the input's (distinct crop boxes)")
    rows = [("each frame alone (stability 0)", set(), 0.0), ("stabilised (0.5)", set(), 0.5)]
    rows += [(f"  {part} held", set(part.split(" + ")), 0.5) for part in args.parts]
    print("| | " + " | ".join(args.photos) + " |\n|---|" + "---|" * len(args.photos))
    table = {name: [] for name, _, _ in rows}
    sources = []
    for name in args.photos:
        photo, matte = EVAL / f"{name}.jpg", EVAL / "reference" / f"{name}.png"
        frames = noisy_still(args.frames, args.height, seed=args.seed, photo=photo)
        region = still_region(args.height, matte, photo)
        source = lowpass_flicker(frames, region)
        sources.append(f"{source:.4f}")
        for label, hold, stability in rows:
            relit, boxes = held_clip(relighter, light, frames, hold, stability)
            table[label].append(f"{lowpass_flicker(relit, region) / source:.2f}x ({boxes})")
        if args.cli:
            table.setdefault("`relight video` on PNG frames", []).append(f"{cli_ratio(frames, region, source):.2f}x")
    print("| input's low-pass flicker | " + " | ".join(sources) + " |")
    for label, cells in table.items():
        print(f"| {label} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
