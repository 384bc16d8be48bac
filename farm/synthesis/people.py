"""The people of a scene (issue 47): one person drawn (body, pose, turn, outfit), and groups of
two to five placed side by side, some apart, some touching, some overlapping (one partly in
front of the other).

    people_plan(text, seed, index)       -> GroupPlan   the count and the layout draws (no anny)
    draw_person(rng, draw_yaw, ...)      -> Person      what farm.scene drew inline before issue 47
    place_people(persons, plan)                          translations along the group's row

A one-person scene (`--people 1`, the default) draws nothing here beyond what farm.scene drew
before: same seed, same bytes. A group draws its count and layout from its own stream
default_rng([seed, index, GROUP_STREAM]) and person k >= 1 from default_rng([seed, index,
GROUP_STREAM, k]); person 0 still draws from the scene's main stream.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace

import numpy as np

MAX_PEOPLE = 5
GROUP_STREAM = 4
MAX_POSE_ATTEMPTS = 12
MAX_PENETRATION = 0.3  # capsule overlap (fraction of the two radii) above which a pose is redrawn
# How a person stands against the one placed before it (its left neighbour in the row)
RELATIONS = ("apart", "touching", "overlap")
RELATION_P = (0.25, 0.4, 0.35)
# Two people's vertices never come closer than this; "touching" stops at the first position
# that would. The slide's step is below twice the clearance, so no vertex passes through a
# vertex band of the other person between two steps unseen.
CLEARANCE_M = 0.012
SLIDE_STEP_M = 0.02
GROUP_YAW_DEG = 25.0  # the row's turn about Z: a group faces the camera, give or take
PERSON_YAW_DEG = 40.0  # each person's own turn within the group
FACING_SCALE = 0.5  # a cut framing's camera walks round a group half as far as round one person


def parse_people(text) -> tuple[int, int]:
    """'3' or '2-5' -> (lowest, highest) count a scene draws from, uniformly; 1..MAX_PEOPLE."""
    m = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", str(text))
    lo, hi = (int(m.group(1)), int(m.group(2) or m.group(1))) if m else (0, 0)
    if not (m and 1 <= lo <= hi <= MAX_PEOPLE):
        raise ValueError(f"people must be a count or a range like 2-5 within 1..{MAX_PEOPLE}, got {text!r}")
    return lo, hi


@dataclass(frozen=True)
class GroupPlan:
    """The draws of a group's layout: its count, the row's turn, and per person k >= 1 how it
    stands against person k - 1 (relation, depth step in metres, the share of its width that
    overlaps, the gap when apart)."""

    count: int
    yaw_deg: float = 0.0
    relations: tuple = ()
    depth_m: tuple = ()
    overlap_share: tuple = ()
    gap_m: tuple = ()


def people_plan(text, seed: int, index: int) -> GroupPlan:
    """The scene's count (drawn uniformly over the range) and layout; a fixed count of one draws
    nothing, so the scenes of before stay the same."""
    lo, hi = parse_people(text)
    if hi == 1:
        return GroupPlan(1)
    rng = np.random.default_rng([int(seed), int(index), GROUP_STREAM])
    count = int(rng.integers(lo, hi + 1)) if hi > lo else lo
    yaw = float(rng.uniform(-GROUP_YAW_DEG, GROUP_YAW_DEG))
    relations, depth, share, gap = [], [], [], []
    for _ in range(count - 1):
        relation = RELATIONS[int(rng.choice(len(RELATIONS), p=RELATION_P))]
        side = float(rng.choice([-1.0, 1.0]))  # in front of its neighbour (nearer the camera) or behind
        step = float(rng.uniform(0.25, 0.6)) if relation == "overlap" else float(rng.uniform(-0.12, 0.12))
        relations.append(relation)
        depth.append(side * step if relation == "overlap" else step)
        share.append(float(rng.uniform(0.2, 0.5)))
        gap.append(float(rng.uniform(0.03, 0.3)))
    return GroupPlan(count, yaw, tuple(relations), tuple(depth), tuple(share), tuple(gap))


def z_rotate(vertices: np.ndarray, degrees: float, centre: np.ndarray) -> np.ndarray:
    t = math.radians(degrees)
    r = np.array([[math.cos(t), -math.sin(t), 0.0], [math.sin(t), math.cos(t), 0.0], [0.0, 0.0, 1.0]])
    return (vertices - centre) @ r.T + centre


def one_person_yaw(rng: np.random.Generator) -> float:
    """A lone person's turn: mostly towards the camera, 15 % from behind."""
    return float(rng.uniform(-80.0, 80.0) if rng.random() < 0.85 else rng.uniform(80.0, 280.0))


@dataclass
class Person:
    """One drawn person, dressed, in the world."""

    params: object  # farm.synthesis.bodies.BodyParams
    pose: object  # farm.synthesis.poses.Pose
    yaw_deg: float
    penetration: float
    penetration_pair: str
    body: object  # farm.synthesis.bodies.Body, posed and turned
    parts: list  # farm.synthesis.appearance.Part
    look: dict
    diffuse_only: bool
    placement: dict = field(default_factory=dict)

    def vertices(self) -> np.ndarray:
        return np.concatenate([p.vertices for p in self.parts])

    def translate(self, offset: np.ndarray) -> None:
        self.body.vertices = self.body.vertices + offset
        self.body.joints = self.body.joints + offset
        self.parts = [replace(p, vertices=p.vertices + offset) for p in self.parts]


def draw_person(rng: np.random.Generator, draw_yaw, diffuse_only: bool | None = None,
                diffuse_share: float = 0.2, timings: dict | None = None,
                look_rng: np.random.Generator | None = None) -> Person:
    """Body, pose (redrawn while limbs interpenetrate), turn, outfit, in this order from `rng`:
    the order farm.scene drew a scene's person in before groups existed. `diffuse_only` given
    (a group's later people share the first one's) is not drawn. With `look_rng`
    (farm.synthesis.looks.look_rng) the person is dressed again from it with the held-out looks;
    `rng` has drawn the train outfit all the same, so what it draws next does not change."""
    import time

    from farm.synthesis import appearance, bodies, poses

    timings = {} if timings is None else timings

    def stage(name, t0):  # summed over a group's people
        timings[name] = round(timings.get(name, 0.0) + time.perf_counter() - t0, 4)

    t0 = time.perf_counter()
    params = bodies.sample_body(rng)
    rest_body = bodies.build_body(params, None)
    axes = poses.RestAxes.from_joints(rest_body.joints, rest_body.bone_labels)
    stage("body", t0)
    t0 = time.perf_counter()
    for attempt in range(1, MAX_POSE_ATTEMPTS + 1):
        pose = poses.sample_pose(rng, axes)
        body = bodies.build_body(params, poses.pose_deltas(pose, rest_body.bone_labels))
        penetration, pair = poses.worst_penetration(body.vertices, body.joints, body.bone_labels, body.bone_weights)
        if penetration <= MAX_PENETRATION:
            break
    else:
        pose = poses.Pose("rest")  # every draw intersected: keep the unposed A-pose
        body = rest_body
        penetration, pair = poses.worst_penetration(body.vertices, body.joints, body.bone_labels, body.bone_weights)
    pose.attempts = attempt
    yaw = float(draw_yaw(rng))
    pivot = np.array([*body.joints[0, :2], 0.0])
    body.vertices = z_rotate(body.vertices, yaw, pivot)
    body.joints = z_rotate(body.joints, yaw, pivot)
    stage("pose", t0)
    t0 = time.perf_counter()
    if diffuse_only is None:
        diffuse_only = bool(rng.random() < diffuse_share)
    skirt_allowed = pose.family in ("standing", "arms", "rest")
    parts, look = appearance.dress(body, rng, diffuse_only=diffuse_only, skirt_allowed=skirt_allowed)
    if look_rng is not None:
        from farm.synthesis import looks

        parts, look = appearance.dress(body, look_rng, diffuse_only, skirt_allowed, looks.HELDOUT)
    stage("appearance", t0)
    return Person(params, pose, yaw, float(penetration), pair, body, parts, look, bool(diffuse_only))


def draw_group(rng: np.random.Generator, plan: GroupPlan, seed: int, index: int, diffuse_share: float,
               timings: dict, look_pool: str = "train") -> list[Person]:
    """The plan's people, person 0 from the scene's stream, the others from their own; placed."""
    from farm.synthesis.looks import look_rng

    persons = []
    for k in range(plan.count):
        stream = rng if k == 0 else np.random.default_rng([int(seed), int(index), GROUP_STREAM, k])
        persons.append(draw_person(stream, lambda r: plan.yaw_deg + float(r.uniform(-PERSON_YAW_DEG, PERSON_YAW_DEG)),
                                   persons[0].diffuse_only if persons else None, diffuse_share, timings,
                                   look_rng(look_pool, seed, index, k)))
    place_people(persons, plan)
    return persons


def _contact(tree, placed_lo, placed_hi, points) -> bool:
    """Whether any of `points` comes within CLEARANCE_M of the placed people's vertices."""
    near = np.all((points >= placed_lo - CLEARANCE_M) & (points <= placed_hi + CLEARANCE_M), axis=1)
    if not near.any():
        return False
    distance, _ = tree.query(points[near], k=1, distance_upper_bound=CLEARANCE_M)
    return bool(np.isfinite(distance).any())


def place_people(persons: list[Person], plan: GroupPlan) -> None:
    """Put the people in a row along the group's right (the X axis turned by plan.yaw_deg), left
    to right: each slides in from the right, at its depth step, until it would come within
    CLEARANCE_M of someone ("touching" stays there; "apart" steps back by its gap) or, for
    "overlap", until its drawn share of its width lies in front of or behind its neighbour (or
    it touches first). Records each person's `placement`."""
    from scipy.spatial import cKDTree

    t = math.radians(plan.yaw_deg)
    right = np.array([math.cos(t), math.sin(t), 0.0])
    away = np.array([-math.sin(t), math.cos(t), 0.0])  # from the camera's side into the scene
    for person in persons:  # each person's root over the origin
        person.translate(np.array([-person.body.joints[0, 0], -person.body.joints[0, 1], 0.0]))
    persons[0].placement = {"relation": "first", "offset_m": [0.0, 0.0, 0.0]}
    placed = persons[0].vertices()
    depth = 0.0
    for k in range(1, len(persons)):
        person, relation = persons[k], plan.relations[k - 1]
        depth += plan.depth_m[k - 1]  # a step from its neighbour's depth
        person.translate(depth * away)
        points = person.vertices()
        along = points @ right
        width = float(np.ptp(along))
        left_edge = float(along.min())
        neighbour = persons[k - 1].vertices() @ right
        tree = cKDTree(placed)
        lo, hi = placed.min(axis=0), placed.max(axis=0)
        start = float((placed @ right).max()) - left_edge + CLEARANCE_M + SLIDE_STEP_M
        floor = float(neighbour.min()) - left_edge  # never past its neighbour's left edge
        if relation == "overlap":  # its left `share` of its width over the neighbour's right edge
            floor = max(floor, float(neighbour.max()) - left_edge - plan.overlap_share[k - 1] * width)
        clear, shift, touched = start, start, False
        while shift > floor:
            shift = max(floor, shift - SLIDE_STEP_M)
            if _contact(tree, lo, hi, points + shift * right):
                touched = True
                break
            clear = shift
        if touched:  # halve the step between the last clear position and the first contact
            hit = shift
            for _ in range(3):
                mid = 0.5 * (clear + hit)
                if _contact(tree, lo, hi, points + mid * right):
                    hit = mid
                else:
                    clear = mid
        if relation == "apart":
            clear += plan.gap_m[k - 1]
        person.translate(clear * right)
        moved = person.vertices()
        distance = float(tree.query(moved, k=1)[0].min())
        person.placement = {
            "relation": relation, "touched": touched,
            "offset_m": [float(v) for v in clear * right + depth * away],
            "depth_step_m": float(plan.depth_m[k - 1]), "nearest_m": round(distance, 5),
            "overlap_m": round(max(0.0, float(neighbour.max()) - float((moved @ right).min())), 5),
        }
        placed = np.concatenate([placed, moved])


def group_record(persons: list[Person], plan: GroupPlan, camera, resolution: int) -> dict:
    """The sidecar's `people` record (before the masks: farm.scene adds each one's `box`)."""
    out = []
    for k, person in enumerate(persons):
        uv = camera.project(person.vertices())
        x = np.clip((uv[:, 0] + 0.5) * resolution, 0.0, resolution)
        y = np.clip((0.5 - uv[:, 1]) * resolution, 0.0, resolution)
        out.append({
            "person": k,
            "body": person.params.as_dict(),
            "pose": {**person.pose.as_dict(), "yaw_deg": person.yaw_deg, "penetration": person.penetration,
                     "penetration_pair": person.penetration_pair},
            "appearance": person.look,
            "placement": person.placement,
            # every vertex projected, hidden ones too, clipped to the frame: [x0, y0, x1, y1] pixels
            "amodal_box": [round(float(v), 3) for v in (x.min(), y.min(), x.max(), y.max())],
        })
    return {"count": plan.count, "yaw_deg": plan.yaw_deg, "channels": [f"person.P{k}.A" for k in range(plan.count)],
            "persons": out}


def person_masks(alpha: np.ndarray, id_blocks: list[np.ndarray], count: int) -> dict:
    """The `person.PK` channels from the geometry pass: each person's one-hot id AOV over alpha
    is its share of the pixel's person (the nearest surface won each sample); the shares,
    renormalised to sum to 1, times alpha, so that a pixel's masks sum to its alpha."""
    share = np.concatenate(id_blocks, axis=-1)[..., :count]
    share = np.clip(share.astype(np.float64), 0.0, None)
    total = share.sum(axis=-1, keepdims=True)
    share = np.where(total > 0.0, share / np.where(total > 0.0, total, 1.0), 0.0)
    return {f"person.P{k}": (share[..., k] * alpha).astype(np.float32) for k in range(count)}


def with_boxes(record: dict, channels: dict) -> dict:
    """The `people` record with each person's visible `box` [x0, y0, x1, y1] (pixels, ends
    exclusive; None when no pixel shows it) and `pixels` (the sum of its mask)."""
    persons = []
    for k, person in enumerate(record["persons"]):
        mask = np.asarray(channels[f"person.P{k}"])
        rows, cols = np.nonzero(mask > 0.0)
        box = None if rows.size == 0 else [int(cols.min()), int(rows.min()), int(cols.max()) + 1, int(rows.max()) + 1]
        persons.append({**person, "box": box, "pixels": round(float(np.sum(mask)), 3)})
    return {**record, "persons": persons}
