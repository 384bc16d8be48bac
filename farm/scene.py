"""One synthetic scene, end to end: body, pose, clothes, camera, lights, bake, Cycles, files.

`render_scene` runs inside a bpy process (the bpy module, or Blender's own
Python), resets Blender to factory settings itself and draws every random
choice from numpy.random.default_rng([seed, index]); the sidecar records all
of them. Same seed and index -> the same geometry (hash recorded) and the
same sidecar apart from timings.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import math
import time
from pathlib import Path

import numpy as np

from farm.options import SceneOptions  # noqa: F401 (part of the job-module interface)
from relight import dataset, prt, sh

# Share of scenes whose materials are all pure Lambert (then "auto" skips the
# view-dependent bake, and the PRT image equals the path-traced one up to
# interreflection and noise).
DIFFUSE_ONLY_SHARE = 0.2
MAX_POSE_ATTEMPTS = 12
# Capsule overlap (fraction of the two radii) above which a pose is rejected.
MAX_PENETRATION = 0.3
GEOMETRY_SAMPLES = 16


def _versions() -> dict:
    import bpy

    out = {"bpy": bpy.app.version_string}
    for pkg in ("anny", "numpy", "embreex", "torch"):
        try:
            out[pkg] = importlib.metadata.version(pkg)
        except importlib.metadata.PackageNotFoundError:
            out[pkg] = None
    return out


def _yaw(vertices: np.ndarray, degrees: float, centre: np.ndarray) -> np.ndarray:
    t = math.radians(degrees)
    r = np.array([[math.cos(t), -math.sin(t), 0.0], [math.sin(t), math.cos(t), 0.0], [0.0, 0.0, 1.0]])
    return (vertices - centre) @ r.T + centre


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


def render_scene(index: int, seed: int, options: SceneOptions, out_dir: Path) -> Path:
    """Synthesize, bake and render scene `index`; returns the finished JSON path."""
    from farm import appearance, bake, bodies, camera, lights, passes, poses

    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or index < 0:
        raise ValueError(f"scene index must be a non-negative integer, got {index!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    options.validate()
    threads = passes.thread_count()  # validates $RELIGHT_CYCLES_THREADS before any work
    out_dir = Path(out_dir)
    asked = frozenset(options.passes)
    rng = np.random.default_rng([int(seed), int(index)])
    timings: dict = {}
    t_total = time.perf_counter()

    def stage(name, t0):
        timings[name] = round(time.perf_counter() - t0, 4)

    t0 = time.perf_counter()
    scene = passes.reset_scene()
    stage("reset", t0)

    # Body and pose.
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
    yaw = float(rng.uniform(-80.0, 80.0) if rng.random() < 0.85 else rng.uniform(80.0, 280.0))
    pivot = np.array([*body.joints[0, :2], 0.0])
    body.vertices = _yaw(body.vertices, yaw, pivot)
    body.joints = _yaw(body.joints, yaw, pivot)
    stage("pose", t0)

    # Appearance.
    t0 = time.perf_counter()
    diffuse_only = bool(rng.random() < DIFFUSE_ONLY_SHARE)
    parts, look = appearance.dress(
        body, rng, diffuse_only=diffuse_only, skirt_allowed=pose.family in ("standing", "arms", "rest")
    )
    stage("appearance", t0)

    all_vertices = np.concatenate([p.vertices for p in parts])
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts])
    all_faces = np.concatenate([p.faces + offsets[i] for i, p in enumerate(parts)])
    all_normals = np.concatenate([p.normals for p in parts])

    t0 = time.perf_counter()
    cam = camera.frame_person(all_vertices, rng)
    stage("camera", t0)

    # Lights (the sky needs Cycles; everything else is numpy).
    t0 = time.perf_counter()
    pool = lights.light_pool(options.light_pool)
    work = passes.work_directory(out_dir)
    work_dir = Path(work.name)
    try:
        sky_render = lambda params_: passes.render_sky_equirect(params_, lights.SKY_SIZE, work_dir)
        scene_lights = [
            lights.sample_light(rng, pool, options.sh_order, cam.world_to_camera, sky_render)
            for _ in range(options.lights)
        ]
        stage("lights", t0)

        # Transport bake in the camera frame (rays are invariant under the rigid change of frame).
        n_coeffs = sh.num_coeffs(options.sh_order)
        cam_vertices = cam.to_camera(all_vertices)
        cam_normals = all_normals @ cam.world_to_camera.T
        specular_needed = not all(appearance.is_diffuse(p.material) for p in parts)
        use_specular = options.specular == "on" or (options.specular == "auto" and specular_needed)
        passes_record = {"asked": sorted(asked), "skipped": []}
        transport = None
        bake_record = {"directions": options.bake_directions, "specular": "skipped"}
        bake_rng = np.random.default_rng([int(seed), int(index), 1])
        if "prt" in asked:
            t0 = time.perf_counter()
            materials = None
            view_point = None
            if use_specular:
                materials = bake.VertexMaterials(
                    roughness=np.concatenate([np.full(len(p.vertices), p.material["roughness"]) for p in parts]),
                    metallic=np.concatenate([np.full(len(p.vertices), p.material["metallic"]) for p in parts]),
                    specular=np.concatenate([np.full(len(p.vertices), 2.0 * p.material["specular_level"]) for p in parts]),
                )
                view_point = np.zeros(3)  # the camera is the origin of its own frame
            seen = visible_vertices(cam_vertices, all_faces)
            seen &= ~np.concatenate([p.hidden if p.hidden is not None else np.zeros(len(p.vertices), bool) for p in parts])
            result = bake.bake_transport(
                cam_vertices, all_faces, cam_normals, options.sh_order, options.bake_directions,
                view_point=view_point, materials=materials, rng=bake_rng, threads=threads or None, active=seen,
            )
            transport = result.transport
            bake_record.update(
                specular="baked" if result.specular else ("skipped (all diffuse)" if options.specular == "auto" else "off"),
                rays=result.rays,
                baked_vertices=int(seen.sum()),
                alpha_floor=result.alpha_floor,
            )
            timings["bake_rays"] = round(result.ray_seconds, 4)
            stage("bake", t0)
        else:
            passes_record["skipped"].append("prt")
        if "pt" not in asked:
            passes_record["skipped"].append("pt")

        # Blender scene.
        t0 = time.perf_counter()
        passes.configure_film(scene, (options.resolution, options.resolution))
        passes.camera_object(cam.location, cam.blender_rotation, cam.focal_mm, camera.SENSOR_MM, scene=scene)
        attribute_names = ["normal", "depth"]
        if transport is not None:
            attribute_names += [f"t{i}" for i in range((n_coeffs + 2) // 3)]
        spec = passes.AovSpec(attribute_aovs=attribute_names, socket_aovs=["albedo", "material"])
        passes.register_aovs(scene.view_layers[0], spec)
        for i, part in enumerate(parts):
            lo, hi = offsets[i], offsets[i + 1]
            attrs = {
                "normal": cam_normals[lo:hi],
                "depth": np.repeat(cam_vertices[lo:hi, 1:2], 3, axis=1),
                "rest": part.rest,
            }
            if transport is not None:
                for k, block in enumerate(passes.pack_vectors(transport[lo:hi])):
                    attrs[f"t{k}"] = block
            obj = passes.mesh_object(part.name, part.vertices, part.faces, part.normals, attrs, scene=scene)
            mat, base_socket, params_socket = appearance.build_material(part.name, part.material)
            passes.add_attribute_aovs(mat, attribute_names)
            passes.add_socket_aov(mat, "albedo", base_socket)
            passes.add_socket_aov(mat, "material", params_socket)
            obj.data.materials.append(mat)
        first = scene_lights[0]
        passes.set_environment_world(scene, None, first.rotation_deg, first.scale, pixels=first.pixels, name="light0")
        stage("scene_build", t0)

        t0 = time.perf_counter()
        geo = passes.render_geometry(scene, spec, work_dir, samples=GEOMETRY_SAMPLES)
        stage("geometry_pass", t0)

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
        if transport is not None:
            stacked = np.concatenate([geo.aovs[f"t{i}"] for i in range((n_coeffs + 2) // 3)], axis=-1)
            t_pix = stacked[..., :n_coeffs].astype(np.float32)
            channels["transport"] = t_pix
            for k, light in enumerate(scene_lights):
                shade = prt.shading(t_pix, light.sh).astype(np.float32)
                channels[f"shading.L{k}"] = shade
                channels[f"prt.L{k}"] = (channels["albedo"] * shade).astype(np.float32)

        path_trace_seconds = []
        if "pt" in asked:
            t0 = time.perf_counter()
            for k, light in enumerate(scene_lights):
                if k > 0:
                    passes.set_environment_world(
                        scene, None, light.rotation_deg, light.scale, pixels=light.pixels, name=f"light{k}"
                    )
                pt = passes.render_path_traced(scene, work_dir, f"light{k}", options.samples, options.denoise,
                                               prefilter=options.denoise_prefilter)
                channels[f"image.L{k}"] = pt.image
                path_trace_seconds.append(round(pt.seconds, 4))
            stage("path_trace", t0)
        timings["path_trace_render_calls"] = path_trace_seconds
    finally:
        work.cleanup()

    geometry = {
        "hash": geometry_hash(all_vertices, all_faces),
        "vertices": len(all_vertices),
        "faces": len(all_faces),
        "parts": {p.name: len(p.vertices) for p in parts},
    }
    meta = {
        "index": int(index),
        "seed": int(seed),
        "sh_order": options.sh_order,
        "options": options.to_json(),
        "lights": [light.record() for light in scene_lights],
        "camera": cam.as_dict(),
        "body": params.as_dict(),
        "pose": {**pose.as_dict(), "yaw_deg": yaw, "penetration": float(penetration), "penetration_pair": pair},
        "appearance": look,
        "geometry": geometry,
        "bake": bake_record,
        "passes": passes_record,
        "versions": _versions(),
        "timings": timings,
    }
    stem = dataset.scene_stem(out_dir, index)
    timings["total_before_write"] = round(time.perf_counter() - t_total, 4)
    _, json_path = dataset.write_scene(stem, channels, meta)
    return json_path
