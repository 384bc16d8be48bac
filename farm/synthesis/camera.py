"""Photo-like framings: the whole body (frame_person) and the shots that cut it (frame_shot:
three-quarter, waist-up, head-and-shoulders, face; issue 37).

The camera frame is the one of docs/conventions.md: X right, Y forward (the
view axis), Z up. `world_to_camera` has those three unit vectors as rows, so
a world vector v becomes C @ v in the camera frame. Blender's camera object
looks along its local -Z with +Y up: its world rotation has the columns
(right, up, -forward).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

SENSOR_MM = 36.0  # full-frame width: focal lengths are 35 mm equivalents


@dataclass
class Camera:
    location: np.ndarray  # [3] world
    world_to_camera: np.ndarray  # [3, 3] rows: right, forward, up
    focal_mm: float
    pitch_deg: float
    roll_deg: float
    fill: float  # fraction of the frame height the person spans (before the fit check)
    offset: list[float]  # target offset from the person's centre, fractions of the frame
    framing: str = "full-body"  # one of FRAMINGS
    shot: dict | None = field(default=None)  # cut framings: the band kept, the landmarks, the camera's height

    @property
    def blender_rotation(self) -> np.ndarray:
        right, forward, up = self.world_to_camera
        return np.stack([right, up, -forward], axis=1)

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points [N, 3] -> camera frame [N, 3]."""
        return (np.asarray(points) - self.location) @ self.world_to_camera.T

    def project(self, points: np.ndarray) -> np.ndarray:
        """Camera-frame points -> normalized image coords in [-0.5, 0.5] (x right, y up), square film."""
        p = self.to_camera(points)
        scale = self.focal_mm / SENSOR_MM
        return np.stack([p[:, 0] / p[:, 1], p[:, 2] / p[:, 1]], axis=1) * scale

    def as_dict(self) -> dict:
        return {
            "location": self.location.tolist(),
            "world_to_camera": self.world_to_camera.tolist(),
            "focal_mm_35mm_equivalent": self.focal_mm,
            "sensor_width_mm": SENSOR_MM,
            "pitch_deg": self.pitch_deg,
            "roll_deg": self.roll_deg,
            "fill": self.fill,
            "offset": self.offset,
            "framing": self.framing,
            **({"shot": self.shot} if self.shot is not None else {}),
        }


def orientation(pitch_deg: float, roll_deg: float) -> np.ndarray:
    """World-to-camera rows for a camera looking along +Y, pitched up by pitch, rolled by roll."""
    p, r = math.radians(pitch_deg), math.radians(roll_deg)
    forward = np.array([0.0, math.cos(p), math.sin(p)])
    right0 = np.array([1.0, 0.0, 0.0])
    up0 = np.cross(right0, forward)
    right = math.cos(r) * right0 + math.sin(r) * up0
    up = np.cross(right, forward)
    return np.stack([right, forward, up])


def frame_person(vertices: np.ndarray, rng: np.random.Generator) -> Camera:
    """A camera that sees every vertex, with random focal length, tilt and placement."""
    focal = float(rng.uniform(35.0, 85.0))
    pitch = float(rng.uniform(-8.0, 8.0))
    roll = float(rng.uniform(-3.0, 3.0))
    fill = float(rng.uniform(0.72, 0.92))
    rot = orientation(pitch, roll)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    centre = 0.5 * (lo + hi)
    height = float(hi[2] - lo[2])
    # Distance that makes the person `fill` of the frame height: frame height at
    # distance d is d * SENSOR / focal.
    distance = height / fill * focal / SENSOR_MM + 0.5 * float(hi[1] - lo[1])
    slack = max(0.0, 1.0 - fill)
    offset = [float(rng.uniform(-0.5, 0.5) * slack), float(rng.uniform(-0.5, 0.5) * slack * 0.5)]
    frame_size = distance * SENSOR_MM / focal
    right, forward, up = rot
    target = centre - offset[0] * frame_size * right - offset[1] * frame_size * up
    for _ in range(40):
        cam = Camera(target - distance * forward, rot, focal, pitch, roll, fill, offset)
        uv = cam.project(vertices)
        depth = cam.to_camera(vertices)[:, 1]
        if depth.min() > 0.3 and np.abs(uv).max() < 0.48:
            return cam
        distance *= 1.06
    raise ValueError("could not frame the person inside the image")


# ------------------------------------------------------------------ framings (issue 37)

# Shot sizes, widest first. "full-body" is frame_person above (the farm's only framing before
# issue 37, and still the default); the others cut the person at a height measured on the
# posed body's own joints.
FRAMINGS = ("full-body", "three-quarter", "waist-up", "head-and-shoulders", "face")
# 35 mm-equivalent lens ranges per framing: portraits are taken on longer lenses
FOCAL_RANGE = {"three-quarter": (35.0, 85.0), "waist-up": (35.0, 85.0), "head-and-shoulders": (50.0, 105.0),
               "face": (70.0, 135.0)}
# fraction of the frame height the kept band of the body (cut line .. head top) spans
FILL_RANGE = {"three-quarter": (0.8, 0.92), "waist-up": (0.78, 0.92), "head-and-shoulders": (0.74, 0.9),
              "face": (0.8, 0.95)}
MIN_DEPTH_M = 0.15  # every vertex at least this far in front of the camera (clip start is 0.05 m)


def parse_framings(text: str) -> tuple[str, ...]:
    """'all', one framing, or a comma list of them -> the tuple a scene draws from (uniformly)."""
    names = FRAMINGS if str(text).strip() == "all" else tuple(t.strip() for t in str(text).split(",") if t.strip())
    bad = [n for n in names if n not in FRAMINGS]
    if bad or not names:
        raise ValueError(f"framing must be 'all' or a comma list of {', '.join(FRAMINGS)}, got {text!r}")
    return names


@dataclass(frozen=True)
class Landmarks:
    """Heights (world z, metres) on the posed, dressed person the framings cut at, and the head."""

    head_top: float  # highest point of the head, hair included
    chin: float  # about the jaw line: the head bone's root
    shoulders: float  # mean of the two shoulder joints
    hips: float  # mean of the two hip joints
    knees: float  # mean of the two knee joints
    head: np.ndarray  # [3] the head bone's root (neck top)
    eyes_z: float  # eye height (camera height is recorded against it)

    def as_dict(self) -> dict:
        return {"head_top": self.head_top, "chin": self.chin, "shoulders": self.shoulders, "hips": self.hips,
                "knees": self.knees, "eyes": self.eyes_z}


def landmarks(vertices: np.ndarray, joints: np.ndarray, labels: list[str], head_vertices: np.ndarray) -> Landmarks:
    """The cut heights from anny's joints (bone roots) and the head's own vertices.

    `vertices`: every part's vertices (hair, hood); `head_vertices`: the body's vertices whose
    dominant bone is the head. The head top is the highest vertex within 0.25 m (horizontally)
    of the head's vertices' centre and no more than 0.45 m above the head bone: hair counts, a
    hand raised high above the head does not."""
    index = {name: i for i, name in enumerate(labels)}

    def mean_z(*names):
        return float(np.mean([joints[index[n], 2] for n in names]))

    head = np.asarray(joints[index["head"]], dtype=np.float64)
    centre = head_vertices.mean(axis=0)
    near = (np.linalg.norm(vertices[:, :2] - centre[:2], axis=1) < 0.25) & (vertices[:, 2] > head[2]) \
        & (vertices[:, 2] < head[2] + 0.45)
    top = float(max(head_vertices[:, 2].max(), vertices[near, 2].max() if near.any() else -np.inf))
    eyes = [n for n in labels if n.startswith("eye")]
    eyes_z = mean_z(*eyes) if eyes else float(head[2] + 0.45 * (top - head[2]))
    return Landmarks(head_top=top, chin=float(head[2]) - 0.03, shoulders=mean_z("upperarm01.L", "upperarm01.R"),
                     hips=mean_z("upperleg01.L", "upperleg01.R"), knees=mean_z("lowerleg01.L", "lowerleg01.R"),
                     head=head, eyes_z=eyes_z)


def band(framing: str, marks: Landmarks) -> tuple[float, float, float]:
    """(low z, high z, horizontal radius about the head): the part of the body a framing keeps.
    Below `low` the frame cuts the person; outside the radius (metres, in the ground plane) an
    outstretched arm may leave the frame, as in photos, rather than widen the shot."""
    top = marks.head_top
    if framing == "three-quarter":
        return marks.knees - 0.04, top, 0.6
    if framing == "waist-up":
        return marks.hips - 0.04, top, 0.45
    if framing == "head-and-shoulders":
        return marks.shoulders - 0.45 * (top - marks.shoulders), top, 0.32
    if framing == "face":
        return marks.chin - 0.04, top, 0.16
    raise ValueError(f"band: no cut for framing {framing!r}")


def reframe(full_body: Camera, vertices: np.ndarray, body, framing_text: str, stream: list[int],
            body_yaw_deg: float = 0.0, group: list | None = None) -> Camera:
    """The scene's camera for the framings asked (SceneOptions.framing): one drawn uniformly from
    default_rng(stream), its own stream, so that the body, clothes and lights drawn from the
    scene's main stream stay the same whatever the framing; "full-body" keeps `full_body` (the
    camera the main stream drew, which also holds when only "full-body" is asked: nothing drawn).

    `group` (issue 47): (vertices, body) of each person of a group, the first one's landmarks
    recorded; the shot keeps every person's band, aims from their mean eye height and walks
    round the group (turned by body_yaw_deg) half as far as round one person."""
    framings = parse_framings(framing_text)
    if framings == ("full-body",):
        return full_body
    rng = np.random.default_rng(stream)
    framing = str(framings[int(rng.integers(len(framings)))])
    if framing == "full-body":
        return full_body
    if not group:
        marks = _marks(vertices, body)
        return frame_shot(vertices, marks, framing, rng, body_yaw_deg)
    marks = [_marks(v, b) for v, b in group]
    bands = [(*band(framing, m), m.head) for m in marks]
    first = replace(marks[0], eyes_z=float(np.mean([m.eyes_z for m in marks])))
    return frame_shot(vertices, first, framing, rng, body_yaw_deg, bands=bands, facing_scale=GROUP_FACING_SCALE)


GROUP_FACING_SCALE = 0.5  # a group's row seen from 90 degrees hides all but its nearest person


def _marks(vertices: np.ndarray, body) -> Landmarks:
    head = np.argmax(body.bone_weights, axis=1) == body.bone_labels.index("head")
    return landmarks(vertices, body.joints, body.bone_labels, body.vertices[head])


def z_turn(degrees: float) -> np.ndarray:
    """Rotation about world Z by `degrees` (counter-clockwise seen from above)."""
    t = math.radians(degrees)
    return np.array([[math.cos(t), -math.sin(t), 0.0], [math.sin(t), math.cos(t), 0.0], [0.0, 0.0, 1.0]])


def frame_shot(vertices: np.ndarray, marks: Landmarks, framing: str, rng: np.random.Generator,
               body_yaw_deg: float = 0.0, bands: list | None = None, facing_scale: float = 1.0) -> Camera:
    """A camera for one of the cut framings: the band of the body (band()) fills `fill` of the
    frame height with its cut line on the frame's bottom edge and the head room above it; lens,
    camera height (pitch: a high or low camera looks down or up at the head), roll (a
    photographer's tilt, now and then a strong one) and the side it is taken from (about the
    person's facing, `body_yaw_deg`) drawn as photographers vary them. The camera turned about
    world Z by camera_azimuth_deg (recorded) looks along +Y turned by that much. `bands`: a
    group's (low, high, radius, head) per person, kept together (one person: band(marks))."""
    if framing == "full-body":
        return frame_person(vertices, rng)
    bands = bands or [(*band(framing, marks), marks.head)]
    low, high = min(b[0] for b in bands), max(b[1] for b in bands)
    focal = float(rng.uniform(*FOCAL_RANGE[framing]))
    fill = float(rng.uniform(*FILL_RANGE[framing]))
    # the camera's height: seen from the eyes, `elevation` above (or below) them, looking at the
    # frame's centre, as a photographer raises or lowers the camera about eye level
    elevation = float(np.clip(rng.normal(0.0, 8.0), -25.0, 25.0))
    d0 = (high - low) / fill * focal / SENSOR_MM
    centre = low + 0.5 * (high - low) / fill
    pitch = math.degrees(math.atan((centre - marks.eyes_z) / d0 - math.tan(math.radians(elevation))))
    roll = float(np.clip(rng.normal(0.0, 2.5), -6.0, 6.0))
    if rng.random() < 0.1:  # a deliberate tilt
        roll = float(rng.choice([-1.0, 1.0]) * rng.uniform(8.0, 15.0))
    horizontal = float(rng.uniform(-0.5, 0.5))  # fraction of the horizontal slack (rule of thirds and such)
    # a portrait is taken from the front: the camera walks round the person (turned by
    # body_yaw_deg, farm.scene) to within 45 degrees of its facing, one shot in six a profile
    facing = float(rng.uniform(-45.0, 45.0) if rng.random() < 5.0 / 6.0
                   else rng.choice([-1.0, 1.0]) * rng.uniform(45.0, 90.0)) * facing_scale
    rot = orientation(pitch, roll) @ z_turn(body_yaw_deg + facing).T
    right, forward, up = rot
    keep = np.zeros(len(vertices), dtype=bool)
    for lo, hi, radius, head in bands:
        keep |= (vertices[:, 2] >= lo) & (vertices[:, 2] <= hi) \
            & (np.linalg.norm(vertices[:, :2] - head[:2], axis=1) < radius)
    key = vertices[keep]
    if len(key) < 4:
        raise ValueError(f"framing {framing!r}: no body between z = {low:.2f} and {high:.2f}")
    local = (key - key.mean(axis=0)) @ rot.T
    distance = float(np.ptp(local[:, 2])) / fill * focal / SENSOR_MM
    target = key.mean(axis=0)
    want_top = 0.5 - (1.0 - fill)  # the band's top (1 - fill) of the frame below its top edge
    for _ in range(8):
        # measured on the projection: perspective makes the nearer head look larger than the
        # band's mean depth says; the span sets the distance, the top and the centre the aim
        uv = Camera(target - distance * forward, rot, focal, pitch, roll, fill, [0.0, 0.0]).project(key)
        width = float(np.ptp(uv[:, 0]))
        want_u = horizontal * 0.5 * max(0.0, 1.0 - width)
        frame = distance * SENSOR_MM / focal
        target = target + (float(uv[:, 1].max()) - want_top) * frame * up \
            + (0.5 * float(uv[:, 0].max() + uv[:, 0].min()) - want_u) * frame * right
        distance *= float(np.ptp(uv[:, 1])) / fill

    def place(distance: float) -> Camera:
        return Camera(target - distance * forward, rot, focal, pitch, roll, fill, [round(want_u, 6), 0.0])

    for _ in range(60):
        cam = place(distance)
        uv = cam.project(key)
        depth = cam.to_camera(vertices)[:, 1]
        if depth.min() > MIN_DEPTH_M and np.abs(uv[:, 0]).max() < 0.49 and uv[:, 1].max() < 0.49:
            cam.framing = framing
            cam.shot = {"band_z": [float(low), float(high)], "landmarks": marks.as_dict(),
                        "camera_above_eyes_m": float(cam.location[2] - marks.eyes_z),
                        "elevation_from_eyes_deg": elevation, "facing_deg": facing,
                        "camera_azimuth_deg": float(body_yaw_deg + facing)}
            if len(bands) > 1:
                cam.shot["people_band_z"] = [[float(b[0]), float(b[1])] for b in bands]
            return cam
        distance *= 1.05
    raise ValueError(f"could not frame the {framing} shot inside the image")
