"""The render passes of the scene files and the channels each writes: the one table that the
farm (which passes it renders, how many channels they make), relight/files/dataset.py (what it
writes, reads and checks) and docs/dataset.md (tests/relight/files/test_scene_passes.py holds
them equal) read.

A pass is rendered, or not, as a whole (`farm --passes`); the geometry pass always. Each of its
channel groups is stored in the scene EXR as `<group>.<suffix>` planes; a group of kind
PER_LIGHT once per light K (`image.L0.R`), SH once per SH coefficient (`transport.00`) and
PER_PERSON once per person K of a group scene (`person.P0.A`). A pass's own groups come
together; its per-light groups need them.
"""

from __future__ import annotations

from dataclasses import dataclass

PLAIN, PER_LIGHT, SH, PER_PERSON = "plain", "per light", "sh", "per person"


@dataclass(frozen=True)
class ChannelGroup:
    name: str
    suffixes: tuple[str, ...]  # an SH group's channels are numbered instead
    kind: str = PLAIN
    optional: bool = False  # may be absent though its pass was rendered (scenes made before it, one-person scenes)


@dataclass(frozen=True)
class RenderPass:
    name: str
    groups: tuple[ChannelGroup, ...]
    what: str  # for `farm --help`
    default: bool = True  # rendered when `--passes` is not given
    always: bool = False  # rendered in every scene, not a choice


PASSES = (
    RenderPass("geometry", (
        ChannelGroup("alpha", ("A",)),
        ChannelGroup("albedo", ("R", "G", "B")),
        ChannelGroup("normal", ("X", "Y", "Z")),
        ChannelGroup("material", ("R", "G", "B")),
        ChannelGroup("depth", ("Z",)),
        ChannelGroup("head", ("A",), optional=True),  # scenes since issue 37
        ChannelGroup("person", ("A",), PER_PERSON, optional=True),  # group scenes (issue 47)
    ), "coverage, albedo, normals, material, depth, head mask: one Cycles render", always=True),
    RenderPass("prt", (
        ChannelGroup("transport", (), SH),
        ChannelGroup("shading", ("R", "G", "B"), PER_LIGHT),
        ChannelGroup("prt", ("R", "G", "B"), PER_LIGHT),
    ), "SH transport baked per vertex, and the shading and PRT image under each light"),
    RenderPass("pt", (ChannelGroup("image", ("R", "G", "B"), PER_LIGHT),), "one path-traced image per light"),
    RenderPass("body", (
        ChannelGroup("body_normal", ("X", "Y", "Z")),
        ChannelGroup("body_alpha", ("A",)),
        ChannelGroup("body_depth", ("Z",)),
    ), "the body under the clothes and hair, ray-cast from the camera (farm/rendering/body_pass.py)"),
    RenderPass("body_back", (ChannelGroup("body_back_depth", ("Z",)),),
               "the far side of the body under the clothes: its depth where the camera's rays leave it "
               "(farm/rendering/body_pass.py)", default=False),
)

BY_NAME = {p.name: p for p in PASSES}
CHOICES = tuple(p.name for p in PASSES if not p.always)  # what `farm --passes` may name
DEFAULT = frozenset(p.name for p in PASSES if p.default and not p.always)
GROUPS = {g.name: g for p in PASSES for g in p.groups}
PASS_OF = {g.name: p for p in PASSES for g in p.groups}


def sh_channel_names(group: str, count: int) -> list[str]:
    """group.00 .. group.(count-1): zero-padded to at least two digits."""
    width = max(2, len(str(count - 1)))
    return [f"{group}.{k:0{width}d}" for k in range(count)]


def channel_count(passes, sh_coeffs: int, lights: int, people: int = 1) -> int:
    """Float32 channels of a scene rendering `passes` (besides the geometry pass) with `sh_coeffs`
    transport coefficients, `lights` lights and `people` people (person masks only above one)."""
    total = 0
    for render_pass in PASSES:
        if not (render_pass.always or render_pass.name in passes):
            continue
        for group in render_pass.groups:
            count = {PLAIN: 1, PER_LIGHT: lights, SH: 0, PER_PERSON: people if people > 1 else 0}[group.kind]
            total += sh_coeffs if group.kind == SH else count * len(group.suffixes)
    return total
