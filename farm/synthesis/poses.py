"""Pose sampler on anny's rig, within joint limits, with a cheap self-intersection test.

anny's 'local-ref' parameterization takes one 4x4 delta per bone, expressed
in world-aligned axes at the rest (A-)pose and carried along by the parent
chain. The rest body faces -Y with its left side at +X, so:
- a rotation about +X by a positive angle moves a downward bone backwards;
- hinge axes (elbow, knee) come from the rest joint positions themselves.
Each joint is an axis-angle rotation; a pose is a dict bone -> (axis, degrees)
list, converted to deltas in `pose_deltas`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

FAMILIES = ("standing", "walking", "arms", "sitting", "crouching")
FAMILY_WEIGHTS = (0.35, 0.2, 0.25, 0.1, 0.1)

X, Y, Z = np.eye(3)


def axis_angle(axis: np.ndarray, degrees: float) -> np.ndarray:
    """3x3 rotation by `degrees` about unit `axis` (Rodrigues)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    t = math.radians(degrees)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(t) * k + (1 - math.cos(t)) * (k @ k)


@dataclass
class Pose:
    family: str
    # bone label -> list of (axis [3], degrees) applied left to right
    rotations: dict[str, list[tuple[list[float], float]]] = field(default_factory=dict)
    attempts: int = 1

    def add(self, bone: str, axis, degrees: float) -> None:
        self.rotations.setdefault(bone, []).append(([float(c) for c in axis], float(degrees)))

    def as_dict(self) -> dict:
        return {
            "family": self.family,
            "attempts": self.attempts,
            "rotations": {
                bone: [{"axis": axis, "degrees": deg} for axis, deg in rots]
                for bone, rots in sorted(self.rotations.items())
            },
        }


def pose_deltas(pose: Pose, bone_labels: list[str]) -> np.ndarray:
    """[B, 4, 4] 'local-ref' deltas for anny (identity for unposed bones)."""
    deltas = np.tile(np.eye(4), (len(bone_labels), 1, 1))
    index = {b: i for i, b in enumerate(bone_labels)}
    for bone, rots in pose.rotations.items():
        if bone not in index:
            raise ValueError(f"pose names unknown bone {bone!r}")
        r = np.eye(3)
        for axis, deg in rots:
            r = axis_angle(np.asarray(axis), deg) @ r
        deltas[index[bone], :3, :3] = r
    return deltas


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


@dataclass(frozen=True)
class RestAxes:
    """Hinge axes from rest joint positions: positive angles close the elbow and
    swing the shin backward (+Y)."""

    elbow: dict[str, np.ndarray]
    knee: dict[str, np.ndarray]

    @staticmethod
    def from_joints(joints: np.ndarray, labels: list[str]) -> RestAxes:
        j = {b: joints[i] for i, b in enumerate(labels)}
        forward = -Y
        elbow, knee = {}, {}
        for s in ("L", "R"):
            upper = _unit(j[f"lowerarm01.{s}"] - j[f"upperarm01.{s}"])
            forearm = _unit(j[f"wrist.{s}"] - j[f"lowerarm01.{s}"])
            # Rotating d about a moves it along a x d. The hinge is the normal of
            # the arm's plane, a = u x d, so that a x d has a -u component
            # (flexion closes the elbow); a straight arm falls back to d x forward.
            hinge = np.cross(upper, forearm)
            if np.linalg.norm(hinge) < 0.2:
                hinge = np.cross(forearm, forward)
            elbow[s] = _unit(hinge)
            shin = _unit(j[f"foot.{s}"] - j[f"lowerleg01.{s}"])
            back = Y - np.dot(Y, shin) * shin
            knee[s] = _unit(np.cross(shin, back))
        return RestAxes(elbow, knee)


def sample_pose(rng: np.random.Generator, axes: RestAxes, family: str | None = None) -> Pose:
    """One pose of a family drawn with FAMILY_WEIGHTS (or the given one)."""
    if family is None:
        family = FAMILIES[int(rng.choice(len(FAMILIES), p=FAMILY_WEIGHTS))]
    if family not in FAMILIES:
        raise ValueError(f"pose family must be one of {FAMILIES}, got {family!r}")
    p = Pose(family)
    u = rng.uniform
    # Torso and head: small everywhere.
    p.add("spine03", X, u(-5, 12))
    p.add("spine03", Y, u(-6, 6))
    p.add("spine02", Z, u(-15, 15))
    p.add("neck01", X, u(-15, 20))
    p.add("head", Z, u(-35, 35))
    p.add("head", Y, u(-10, 10))
    sides = ("L", "R")
    sign = {"L": 1.0, "R": -1.0}  # mirror for rotations about Y and Z

    def arm(s, abduct, flex, elbow_deg, twist):
        # abduct > 0 raises the arm sideways; flex > 0 raises it forwards.
        p.add(f"upperarm01.{s}", Y, -sign[s] * abduct)
        p.add(f"upperarm01.{s}", X, -flex)
        p.add(f"upperarm01.{s}", Z, sign[s] * twist)
        p.add(f"lowerarm01.{s}", axes.elbow[s], elbow_deg)

    def leg(s, flex, knee_deg, abduct=0.0):
        # flex > 0 swings the thigh forwards.
        p.add(f"upperleg01.{s}", X, -flex)
        p.add(f"upperleg01.{s}", Y, -sign[s] * abduct)
        p.add(f"lowerleg01.{s}", axes.knee[s], knee_deg)

    if family == "standing":
        for s in sides:
            arm(s, u(-40, 15), u(-15, 30), u(-40, 30), u(-20, 20))
            leg(s, u(-8, 12), u(0, 15), u(-2, 8))
    elif family == "walking":
        stride = u(12, 30)
        lead = sides[int(rng.integers(2))]
        for s in sides:
            front = 1.0 if s == lead else -1.0
            leg(s, front * stride, u(0, 10) if front > 0 else u(15, 45), u(0, 4))
            arm(s, u(-40, -25), -front * stride * u(0.6, 1.2), u(-30, 20), u(-10, 10))
    elif family == "arms":
        for s in sides:
            arm(s, u(-45, 95), u(-30, 140), u(-45, 100), u(-40, 40))
            leg(s, u(-8, 15), u(0, 20), u(-2, 12))
    elif family == "sitting":
        for s in sides:
            leg(s, u(70, 100), u(70, 105), u(0, 12))
            arm(s, u(-40, 0), u(10, 60), u(-10, 60), u(-20, 20))
    elif family == "crouching":
        p.add("spine04", X, u(10, 30))
        for s in sides:
            leg(s, u(95, 125), u(110, 140), u(5, 20))
            arm(s, u(-35, 10), u(20, 70), u(-20, 60), u(-20, 20))
    return p


# Segments for the intersection test: (name, start bone, end bone, bones whose
# vertices give the radius).
_SEGMENTS = [
    ("torso", "spine05", "neck01", ("spine05", "spine04", "spine03", "spine02", "spine01", "pelvis.L", "pelvis.R")),
    ("head", "neck03", "head", ("head", "neck01", "neck02", "neck03")),
]
for _s in ("L", "R"):
    _SEGMENTS += [
        (f"upperarm.{_s}", f"upperarm01.{_s}", f"lowerarm01.{_s}", (f"upperarm01.{_s}", f"upperarm02.{_s}")),
        (f"forearm.{_s}", f"lowerarm01.{_s}", f"wrist.{_s}", (f"lowerarm01.{_s}", f"lowerarm02.{_s}")),
        (f"thigh.{_s}", f"upperleg01.{_s}", f"lowerleg01.{_s}", (f"upperleg01.{_s}", f"upperleg02.{_s}")),
        (f"shin.{_s}", f"lowerleg01.{_s}", f"foot.{_s}", (f"lowerleg01.{_s}", f"lowerleg02.{_s}")),
    ]
# Pairs that must not interpenetrate (adjacent segments are allowed to touch).
_PAIRS = []
for _s in ("L", "R"):
    _o = "R" if _s == "L" else "L"
    _PAIRS += [
        (f"forearm.{_s}", "torso"),
        (f"forearm.{_s}", "head"),
        (f"forearm.{_s}", f"thigh.{_s}"),
        (f"forearm.{_s}", f"thigh.{_o}"),
        (f"upperarm.{_s}", "head"),
        (f"shin.{_s}", f"shin.{_o}"),
        (f"shin.{_s}", f"thigh.{_o}"),
    ]
_PAIRS += [("forearm.L", "forearm.R")]


def segment_distance(p0, p1, q0, q1) -> float:
    """Shortest distance between segments [p0, p1] and [q0, q1]."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e, f = d1 @ d1, d2 @ d2, d2 @ r
    c, b = d1 @ r, d1 @ d2
    denom = a * e - b * b
    s = np.clip((b * f - c * e) / denom, 0.0, 1.0) if denom > 1e-12 else 0.0
    t = (b * s + f) / e if e > 1e-12 else 0.0
    if t < 0.0:
        t, s = 0.0, np.clip(-c / a, 0.0, 1.0) if a > 1e-12 else 0.0
    elif t > 1.0:
        t, s = 1.0, np.clip((b - c) / a, 0.0, 1.0) if a > 1e-12 else 0.0
    return float(np.linalg.norm((p0 + s * d1) - (q0 + t * d2)))


def worst_penetration(vertices: np.ndarray, joints: np.ndarray, labels: list[str], weights: np.ndarray):
    """(largest capsule overlap as a fraction of the two radii, pair name).

    Each segment's radius is the median distance of its vertices (dominant
    bone in its set) to the segment; 0 means no overlap.
    """
    index = {b: i for i, b in enumerate(labels)}
    dominant = np.argmax(weights, axis=1)
    caps = {}
    for name, a, b, bones in _SEGMENTS:
        p0, p1 = joints[index[a]], joints[index[b]]
        ids = np.isin(dominant, [index[x] for x in bones])
        pts = vertices[ids]
        d = p1 - p0
        t = np.clip(((pts - p0) @ d) / max(d @ d, 1e-12), 0.0, 1.0)
        radius = float(np.median(np.linalg.norm(pts - (p0 + t[:, None] * d), axis=1))) if len(pts) else 0.03
        caps[name] = (p0, p1, radius)
    worst, worst_pair = 0.0, ""
    for n1, n2 in _PAIRS:
        p0, p1, r1 = caps[n1]
        q0, q1, r2 = caps[n2]
        overlap = 1.0 - segment_distance(p0, p1, q0, q1) / (r1 + r2)
        if overlap > worst:
            worst, worst_pair = overlap, f"{n1}/{n2}"
    return worst, worst_pair
