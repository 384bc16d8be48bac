"""One synthetic scene, end to end, in four steps (Kubric-style):

    sample_scene(index, seed, options)  -> SceneSample   numpy: body, pose, clothes, camera, lights
    bake_scene(sample)                  -> SceneBake     numpy + embree: per-vertex SH transport
    build_blender_scene(scene, ...)                      bpy: meshes, AOVs, materials, camera
    render_buffers(scene, ...)          -> channels, timings   Cycles: geometry pass, one image per light

`render_scene` runs them in a bpy process (the bpy module, or Blender's own
Python), resetting Blender to factory settings first. Every random choice is
drawn from numpy.random.default_rng([seed, index]) in a fixed order (the
bake from [seed, index, 1]); `SceneSample.record()` is the plain-JSON
description the sidecar keeps. Same seed and index -> the same geometry (hash
recorded) and the same sidecar apart from timings; sampling runs without
Blender when no procedural sky is drawn (or a sky renderer is given).
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from farm.synthesis.scene_options import SceneOptions  # part of the job-module interface
from relight.files import dataset, scene_passes
from relight.network import prt
from relight.lighting import sh

# Share of scenes whose materials are all pure Lambert (then "auto" skips the
# view-dependent bake, and the PRT image equals the path-traced one up to
# interreflection and noise).
DIFFUSE_ONLY_SHARE = 0.2
GEOMETRY_SAMPLES = 16
# Streams of their own (default_rng([seed, index, stream])) for what issue 37 added, so that a
# scene's body, clothes and light maps do not depend on --framing or --hard-lights (the bake is 1)
SHOT_STREAM = 2
HARD_LIGHT_STREAM = 3


def _versions() -> dict:
    import bpy

    out = {"bpy": bpy.app.version_string}
    for pkg in ("anny", "numpy", "embreex", "torch"):
        try:
            out[pkg] = importlib.metadata.version(pkg)
        except importlib.metadata.PackageNotFoundError:
            out[pkg] = None
    return out


def geometry_hash(vertices: np.ndarray, faces: np.ndarray) -> str:
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    return h.hexdigest()


def visible_vertices(cam_vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Vertices with at least one adjacent face turned toward the camera (at the origin).

    Only front faces are seen (the body is closed; shells are seen from
    outside), so the other vertices never reach a pixel and need no bake.
    """
    v = cam_vertices
    normal = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    centre = v[faces].mean(axis=1)
    front = np.einsum("ij,ij->i", normal, -centre) > 0.0
    seen = np.zeros(len(v), dtype=bool)
    seen[faces[front].ravel()] = True
    return seen


@dataclass
class SceneSample:
    """What was drawn for one scene, before anything is baked or built in Blender."""

    index: int
    seed: int
    options: SceneOptions
    body: object  # farm.synthesis.bodies.BodyParams
    pose: object  # farm.synthesis.poses.Pose
    yaw_deg: float
    penetration: float
    penetration_pair: object
    parts: list  # farm.synthesis.appearance.Part, in scene order
    look: dict  # the appearance record
    camera: object  # farm.synthesis.camera.Camera
    lights: list  # farm.synthesis.lights.SampledLight
    timings: dict = field(default_factory=dict)
    body_mesh: tuple | None = None  # (vertices [V, 3] world, faces [F, 3]): the posed body without clothes
    head_labels: list | None = None  # per part: float [V], 1 on the head's skin and face details (the head mask)
    people: dict | None = None  # a group's sidecar record (farm.synthesis.people.group_record); None: one person
    part_people: list | None = None  # a group's person index of each part

    @property
    def offsets(self) -> np.ndarray:
        """Start of each part's vertices in the concatenated mesh (len(parts) + 1 entries)."""
        return np.cumsum([0] + [len(p.vertices) for p in self.parts])

    def mesh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(vertices, faces, normals) of all parts concatenated, in world space."""
        return self._world_mesh

    def camera_mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertices, normals) of the concatenated mesh in the camera frame (bake and AOVs)."""
        return self._camera_mesh

    # Computed once: the bake, the Blender build and the record all need them.
    @functools.cached_property
    def _world_mesh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        offsets = self.offsets
        vertices = np.concatenate([p.vertices for p in self.parts])
        faces = np.concatenate([p.faces + offsets[i] for i, p in enumerate(self.parts)])
        normals = np.concatenate([p.normals for p in self.parts])
        return vertices, faces, normals

    @functools.cached_property
    def _camera_mesh(self) -> tuple[np.ndarray, np.ndarray]:
        vertices, _, normals = self._world_mesh
        return self.camera.to_camera(vertices), normals @ self.camera.world_to_camera.T

    def geometry_record(self) -> dict:
        vertices, faces, _ = self.mesh()
        return {
            "hash": geometry_hash(vertices, faces),
            "vertices": len(vertices),
            "faces": len(faces),
            "parts": {p.name: len(p.vertices) for p in self.parts},
        }

    def record(self) -> dict:
        """The plain-JSON description of the scene (what the sidecar keeps)."""
        return {
            "index": int(self.index),
            "seed": int(self.seed),
            "sh_order": self.options.sh_order,
            "options": self.options.to_json(),
            "lights": [light.record() for light in self.lights],
            "camera": self.camera.as_dict(),
            "body": self.body.as_dict(),
            "pose": {**self.pose.as_dict(), "yaw_deg": self.yaw_deg, "penetration": float(self.penetration),
                     "penetration_pair": self.penetration_pair},
            "appearance": self.look,
            "geometry": self.geometry_record(),
            **({"people": self.people} if self.people is not None else {}),
        }


def check_request(index, seed, options: SceneOptions) -> None:
    """The one check of a scene request, made by the public entries (sample_scene,
    render_scene) before any work: index and seed non-negative integers, options in range."""
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or index < 0:
        raise ValueError(f"scene index must be a non-negative integer, got {index!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    options.validate()


def sample_scene(index: int, seed: int, options: SceneOptions, render_sky=None) -> SceneSample:
    """Draw body, pose, clothes, camera and lights of scene `index` (numpy, anny; no bpy).

    `render_sky(params) -> [H, W, 3]` renders a procedural sky when the light
    pool draws one (render_scene passes Cycles' Sky Texture).
    """
    check_request(index, seed, options)
    return draw_scene(index, seed, options, render_sky)


def draw_scene(index: int, seed: int, options: SceneOptions, render_sky=None) -> SceneSample:
    """sample_scene for a request already checked (check_request). A group (options.people,
    farm.synthesis.people) adds its people; one person draws exactly what it drew before."""
    from farm.synthesis import appearance, camera, hard_lights, lights, looks, people

    rng = np.random.default_rng([int(seed), int(index)])
    timings: dict = {}
    plan = people.people_plan(options.people, seed, index)
    if plan.count == 1:
        persons = [people.draw_person(rng, people.one_person_yaw, diffuse_share=DIFFUSE_ONLY_SHARE, timings=timings,
                                      look_rng=looks.look_rng(options.look_pool, seed, index, 0))]
        parts = persons[0].parts
    else:
        persons = people.draw_group(rng, plan, seed, index, DIFFUSE_ONLY_SHARE, timings, options.look_pool)
        parts = [replace(p, name=f"p{k}.{p.name}") for k, person in enumerate(persons) for p in person.parts]
    first = persons[0]

    t0 = time.perf_counter()
    everything = np.concatenate([p.vertices for p in parts])
    cam = camera.frame_person(everything, rng)
    group = [(person.vertices(), person.body) for person in persons] if plan.count > 1 else None
    cam = camera.reframe(cam, everything, first.body, options.framing, [int(seed), int(index), SHOT_STREAM],
                         plan.yaw_deg if group else first.yaw_deg, group=group)
    timings["camera"] = round(time.perf_counter() - t0, 4)

    t0 = time.perf_counter()
    pool = lights.light_pool(options.light_pool)
    scene_lights = [
        lights.sample_light(rng, pool, options.sh_order, cam.world_to_camera, render_sky)
        for _ in range(options.lights)
    ]
    hard_lights.replace_share(scene_lights, options.hard_lights, [int(seed), int(index), HARD_LIGHT_STREAM],
                              options.sh_order, cam.world_to_camera)
    timings["lights"] = round(time.perf_counter() - t0, 4)
    bodies = [person.body for person in persons]
    body_offsets = np.cumsum([0] + [len(b.vertices) for b in bodies])
    return SceneSample(
        index=int(index), seed=int(seed), options=options, body=first.params, pose=first.pose, yaw_deg=first.yaw_deg,
        penetration=first.penetration, penetration_pair=first.penetration_pair, parts=parts, look=first.look,
        camera=cam, lights=scene_lights, timings=timings,
        body_mesh=(np.concatenate([b.vertices for b in bodies]),
                   np.concatenate([b.faces + body_offsets[k] for k, b in enumerate(bodies)])),
        head_labels=[label for person in persons for label in appearance.head_labels(person.parts, person.body)],
        people=people.group_record(persons, plan, cam, options.resolution) if plan.count > 1 else None,
        part_people=[k for k, person in enumerate(persons) for _ in person.parts] if plan.count > 1 else None,
    )


@dataclass
class SceneBake:
    """Per-vertex SH transport in the camera frame (None when the "prt" pass is off)."""

    transport: np.ndarray | None
    record: dict
    seconds: float = 0.0
    ray_seconds: float = 0.0


def bake_scene(sample: SceneSample, threads: int = 0) -> SceneBake:
    """Bake the transport of the vertices that can reach a pixel (rays in the camera frame:
    they are invariant under the rigid change of frame)."""
    from farm.rendering import bake
    from farm.synthesis import material_specs

    options = sample.options
    record = {"directions": options.bake_directions, "specular": "skipped"}
    if "prt" not in options.passes:
        return SceneBake(None, record)
    t0 = time.perf_counter()
    _, faces, _ = sample.mesh()
    cam_vertices, cam_normals = sample.camera_mesh()
    parts = sample.parts
    specular_needed = not all(material_specs.is_diffuse(p.material) for p in parts)
    use_specular = options.specular == "on" or (options.specular == "auto" and specular_needed)
    materials = None
    view_point = None
    if use_specular:
        materials = bake.VertexMaterials(
            roughness=np.concatenate([np.full(len(p.vertices), p.material["roughness"]) for p in parts]),
            metallic=np.concatenate([np.full(len(p.vertices), p.material["metallic"]) for p in parts]),
            specular=np.concatenate([np.full(len(p.vertices), 2.0 * p.material["specular_level"]) for p in parts]),
        )
        view_point = np.zeros(3)  # the camera is the origin of its own frame
    seen = visible_vertices(cam_vertices, faces)
    seen &= ~np.concatenate([p.hidden if p.hidden is not None else np.zeros(len(p.vertices), bool) for p in parts])
    bake_rng = np.random.default_rng([sample.seed, sample.index, 1])
    result = bake.bake_transport(
        cam_vertices, faces, cam_normals, options.sh_order, options.bake_directions,
        view_point=view_point, materials=materials, rng=bake_rng, threads=threads or None, active=seen,
    )
    record.update(
        specular="baked" if result.specular else ("skipped (all diffuse)" if options.specular == "auto" else "off"),
        rays=result.rays,
        baked_vertices=int(seen.sum()),
        alpha_floor=result.alpha_floor,
    )
    return SceneBake(result.transport, record, time.perf_counter() - t0, result.ray_seconds)


def build_blender_scene(scene, sample: SceneSample, baked: SceneBake):
    """Meshes with per-vertex normal, depth and transport attributes routed to AOVs, their
    materials, the camera and the first light's World; returns the AovSpec."""
    from farm.rendering import blender_scene, materials, passes
    from farm.synthesis import camera

    options = sample.options
    cam = sample.camera
    cam_vertices, cam_normals = sample.camera_mesh()
    offsets = sample.offsets
    passes.configure_film(scene, (options.resolution, options.resolution))
    blender_scene.camera_object(cam.location, cam.blender_rotation, cam.focal_mm, camera.SENSOR_MM, scene=scene)
    attribute_names = ["normal", "depth"] + (["head"] if sample.head_labels is not None else [])
    if baked.transport is not None:
        attribute_names += [f"t{i}" for i in range(_transport_blocks(options))]
    attribute_names += [f"people{i}" for i in range(_people_blocks(sample))]
    spec = blender_scene.AovSpec(attribute_aovs=attribute_names, socket_aovs=["albedo", "material"])
    blender_scene.register_aovs(scene.view_layers[0], spec)
    for i, part in enumerate(sample.parts):
        lo, hi = offsets[i], offsets[i + 1]
        attrs = {
            "normal": cam_normals[lo:hi],
            "depth": np.repeat(cam_vertices[lo:hi, 1:2], 3, axis=1),
            "rest": part.rest,
        }
        if sample.head_labels is not None:
            attrs["head"] = np.repeat(sample.head_labels[i][:, None], 3, axis=1)
        if baked.transport is not None:
            for k, block in enumerate(blender_scene.pack_vectors(baked.transport[lo:hi])):
                attrs[f"t{k}"] = block
        if sample.part_people is not None:  # the person's one-hot id: its AOV / alpha is the pixel's share
            one_hot = np.zeros((hi - lo, 3 * _people_blocks(sample)))
            one_hot[:, sample.part_people[i]] = 1.0
            for k, block in enumerate(blender_scene.pack_vectors(one_hot)):
                attrs[f"people{k}"] = block
        obj = blender_scene.mesh_object(part.name, part.vertices, part.faces, part.normals, attrs, scene=scene)
        mat, base_socket, params_socket = materials.build_material(part.name, part.material)
        blender_scene.add_attribute_aovs(mat, attribute_names)
        blender_scene.add_socket_aov(mat, "albedo", base_socket)
        blender_scene.add_socket_aov(mat, "material", params_socket)
        obj.data.materials.append(mat)
    first = sample.lights[0]
    blender_scene.set_environment_world(scene, None, first.rotation_deg, first.scale, pixels=first.pixels, name="light0")
    return spec


def _transport_blocks(options: SceneOptions) -> int:
    return (sh.num_coeffs(options.sh_order) + 2) // 3


def _people_blocks(sample: SceneSample) -> int:
    return 0 if sample.part_people is None else (max(sample.part_people) + 1 + 2) // 3



def render_buffers(scene, sample: SceneSample, spec, baked: SceneBake, work_dir: Path) -> tuple[dict, dict]:
    """Cycles' geometry pass, the PRT images from the baked transport, one path-traced
    image per light; returns the scene's channels (relight.files.dataset names) and the
    seconds of these stages (geometry_pass, path_trace, path_trace_render_calls)."""
    from farm.rendering import blender_scene, passes

    options = sample.options
    timings: dict = {}
    t0 = time.perf_counter()
    geo = passes.render_geometry(scene, spec, work_dir, samples=GEOMETRY_SAMPLES)
    timings["geometry_pass"] = round(time.perf_counter() - t0, 4)

    alpha = geo.alpha
    inside = alpha > 1e-6
    normal = geo.aovs["normal"]
    length = np.linalg.norm(normal, axis=-1, keepdims=True)
    normal = np.where(length > 1e-6, normal / np.maximum(length, 1e-6), 0.0).astype(np.float32)
    channels = {
        "alpha": alpha,
        "albedo": np.where(inside[..., None], geo.aovs["albedo"], 0.0).astype(np.float32),
        "normal": normal,
        "material": np.where(inside[..., None], geo.aovs["material"], 0.0).astype(np.float32),
        "depth": geo.aovs["depth"][..., 0].astype(np.float32),
    }
    if "head" in geo.aovs:  # the head mask: the share of the pixel's person that is head skin or face
        channels["head"] = np.clip(geo.aovs["head"][..., 0], 0.0, 1.0).astype(np.float32)
    if sample.people is not None:
        from farm.synthesis.people import person_masks

        channels.update(person_masks(alpha, [geo.aovs[f"people{i}"] for i in range(_people_blocks(sample))],
                                     sample.people["count"]))
    if baked.transport is not None:
        n_coeffs = sh.num_coeffs(options.sh_order)
        stacked = np.concatenate([geo.aovs[f"t{i}"] for i in range(_transport_blocks(options))], axis=-1)
        t_pix = stacked[..., :n_coeffs].astype(np.float32)
        channels["transport"] = t_pix
        for k, light in enumerate(sample.lights):
            shade = prt.shading(t_pix, light.sh).astype(np.float32)
            channels[f"shading.L{k}"] = shade
            channels[f"prt.L{k}"] = (channels["albedo"] * shade).astype(np.float32)

    path_trace_seconds = []
    if "pt" in options.passes:
        t0 = time.perf_counter()
        for k, light in enumerate(sample.lights):
            if k > 0:
                blender_scene.set_environment_world(
                    scene, None, light.rotation_deg, light.scale, pixels=light.pixels, name=f"light{k}"
                )
            pt = passes.render_path_traced(scene, work_dir, f"light{k}", options.samples, options.denoise,
                                           prefilter=options.denoise_prefilter)
            channels[f"image.L{k}"] = pt.image
            path_trace_seconds.append(round(pt.seconds, 4))
        timings["path_trace"] = round(time.perf_counter() - t0, 4)
    timings["path_trace_render_calls"] = path_trace_seconds
    from farm.rendering.body_pass import RAY_CAST_PASSES

    for name, channels_of in RAY_CAST_PASSES.items():
        if name in options.passes:
            t0 = time.perf_counter()
            channels.update(channels_of(sample))
            timings[f"{name}_pass"] = round(time.perf_counter() - t0, 4)
    return channels, timings


def render_scene(index: int, seed: int, options: SceneOptions, out_dir: Path, *, sample_fn=None) -> Path:
    """Sample, bake, build and render scene `index`; returns the finished JSON path.

    `sample_fn` (same signature as draw_scene, which it defaults to; called with
    the request checked here) draws the scene: farm.clips passes one that poses a
    clip's person for one frame."""
    check_request(index, seed, options)  # before bpy is imported: a bad request needs no Blender
    from farm.rendering import blender_scene, passes
    from farm.synthesis import lights

    threads = passes.thread_count()  # validates $RELIGHT_CYCLES_THREADS before any work
    out_dir = Path(out_dir)
    t_total = time.perf_counter()

    t0 = time.perf_counter()
    scene = blender_scene.reset_scene()
    timings = {"reset": round(time.perf_counter() - t0, 4)}
    work = passes.work_directory(out_dir)
    work_dir = Path(work.name)
    try:
        sample = (sample_fn or draw_scene)(
            index, seed, options,
            render_sky=lambda params: passes.render_sky_equirect(params, lights.SKY_SIZE, work_dir),
        )
        timings.update(sample.timings)
        baked = bake_scene(sample, threads)
        if baked.transport is not None:
            timings["bake_rays"] = round(baked.ray_seconds, 4)
            timings["bake"] = round(baked.seconds, 4)
        t0 = time.perf_counter()
        spec = build_blender_scene(scene, sample, baked)
        timings["scene_build"] = round(time.perf_counter() - t0, 4)
        channels, render_timings = render_buffers(scene, sample, spec, baked, work_dir)
        timings.update(render_timings)
    finally:
        work.cleanup()

    asked = frozenset(options.passes)
    skipped = [name for name in scene_passes.CHOICES if name in scene_passes.DEFAULT and name not in asked]
    record, versions = sample.record(), _versions()
    timings["total_before_write"] = round(time.perf_counter() - t_total, 4)
    meta = {
        **record,
        "bake": baked.record,
        "passes": {"asked": sorted(asked), "skipped": skipped},
        "versions": versions,
        "timings": timings,
    }
    if sample.people is not None:  # each person's visible box and pixels, from its mask
        from farm.synthesis.people import with_boxes

        meta["people"] = with_boxes(sample.people, channels)
    stem = dataset.scene_stem(out_dir, index)
    _, json_path = dataset.write_scene(stem, channels, meta)
    return json_path

