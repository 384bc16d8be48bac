"""Cycles materials from farm.synthesis.appearance's parameter dicts (needs bpy).

`build_material` returns the material and the socket whose value is the
base colour, textures and prints included; farm.scene routes that socket to
the albedo AOV, so the albedo stays exact per pixel.
"""

from __future__ import annotations

import numpy as np

from farm.synthesis.prints import print_image


def _node_math(nodes, links, op, a, b=None):
    m = nodes.new("ShaderNodeMath")
    m.operation = op
    for k, x in enumerate((a, b)):
        if x is None:
            continue
        if isinstance(x, (int, float)):
            m.inputs[k].default_value = float(x)
        else:
            links.new(x, m.inputs[k])
    return m.outputs[0]


def _mix(nodes, links, fac, a, b):
    mix = nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    if isinstance(fac, (int, float)):
        mix.inputs["Factor"].default_value = float(fac)
    else:
        links.new(fac, mix.inputs["Factor"])
    for k, x in ((6, a), (7, b)):
        if isinstance(x, (list, tuple)):
            mix.inputs[k].default_value = (*x, 1.0)
        else:
            links.new(x, mix.inputs[k])
    return mix.outputs[2]


def _rgb(nodes, colour):
    node = nodes.new("ShaderNodeRGB")
    node.outputs[0].default_value = (*colour, 1.0)
    return node.outputs[0]


def _scaled_rest(nodes, links, rest, scale):
    mapping = nodes.new("ShaderNodeMapping")
    mapping.inputs["Scale"].default_value = scale
    links.new(rest, mapping.inputs["Vector"])
    return mapping.outputs["Vector"]


def _noise_fac(nodes, links, vector, scale):
    tex = nodes.new("ShaderNodeTexNoise")
    tex.inputs["Scale"].default_value = scale
    links.new(vector, tex.inputs["Vector"])
    return tex.outputs["Fac"]


def _print_image(name: str, spec: dict):
    import bpy

    rgba = print_image(spec)
    height, width = rgba.shape[:2]
    image = bpy.data.images.new(f"{name}_print", width, height, alpha=True, float_buffer=True)
    image.pixels.foreach_set(rgba[::-1].ravel())  # Blender's rows start at the bottom
    image.pack()
    image.colorspace_settings.name = "Linear Rec.709"
    image.alpha_mode = "STRAIGHT"
    return image


def _add_print(nodes, links, rest, base, name: str, spec: dict):
    """Base colour with the print over it (rest-space planar projection, crisp alpha)."""
    sep = nodes.new("ShaderNodeSeparateXYZ")
    links.new(rest, sep.inputs["Vector"])
    cx, cz = spec["centre"]
    size = spec["size_m"]
    if spec["kind"] == "band":
        # |z - cz| < size / 2 on every side: a jersey's chest band.
        dz = _node_math(nodes, links, "ABSOLUTE", _node_math(nodes, links, "SUBTRACT", sep.outputs["Z"], cz))
        fac = _node_math(nodes, links, "LESS_THAN", dz, size / 2)
        return _mix(nodes, links, fac, base, spec["colours"][0])
    # Seen from the front (-Y) the body's +X is on the viewer's right; from the back, on the left.
    sign = 1.0 if spec["side"] == "front" else -1.0
    u = _node_math(nodes, links, "MULTIPLY_ADD", sep.outputs["X"], sign / size)
    u_node = u.node
    u_node.inputs[2].default_value = 0.5 - sign * cx / size
    v = _node_math(nodes, links, "MULTIPLY_ADD", sep.outputs["Z"], 1.0 / size)
    v.node.inputs[2].default_value = 0.5 - cz / size
    combine = nodes.new("ShaderNodeCombineXYZ")
    links.new(u, combine.inputs["X"])
    links.new(v, combine.inputs["Y"])
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = _print_image(name, spec)
    tex.interpolation = "Closest"
    tex.extension = "CLIP"
    links.new(combine.outputs["Vector"], tex.inputs["Vector"])
    side = _node_math(nodes, links, "LESS_THAN" if spec["side"] == "front" else "GREATER_THAN",
                      sep.outputs["Y"], spec["split_y"])
    fac = _node_math(nodes, links, "MULTIPLY", tex.outputs["Alpha"], side)
    return _mix(nodes, links, fac, base, tex.outputs["Color"])


def build_material(name: str, spec: dict):
    """Principled BSDF material; returns (material, base-colour socket, material-params socket).

    The base-colour socket is the one colour that feeds the BSDF and the
    albedo AOV, so every texture, print and detail below is in the albedo
    exactly.
    """
    import bpy

    mat = bpy.data.materials.new(name)
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes["Principled BSDF"]
    bsdf.inputs["Roughness"].default_value = spec["roughness"]
    bsdf.inputs["Metallic"].default_value = spec["metallic"]
    bsdf.inputs["Transmission Weight"].default_value = spec["transmission"]
    bsdf.inputs["Specular IOR Level"].default_value = spec["specular_level"]
    bsdf.inputs["Diffuse Roughness"].default_value = spec["diffuse_roughness"]
    bsdf.inputs["IOR"].default_value = 1.5
    if spec.get("sheen", 0.0) > 0.0:
        bsdf.inputs["Sheen Weight"].default_value = spec["sheen"]
        bsdf.inputs["Sheen Roughness"].default_value = 0.35

    colour_a = nodes.new("ShaderNodeRGB")
    colour_a.outputs[0].default_value = (*spec["base_color"], 1.0)
    base_socket = colour_a.outputs[0]
    coords = nodes.new("ShaderNodeAttribute")
    coords.attribute_type = "GEOMETRY"
    coords.attribute_name = "relight_rest"
    rest = coords.outputs["Vector"]
    pattern = spec["pattern"]
    if pattern in ("stripes", "checks", "noise"):
        colour_b = nodes.new("ShaderNodeRGB")
        colour_b.outputs[0].default_value = (*spec["second_color"], 1.0)
        scale = spec["pattern_scale"]
        if pattern == "stripes":
            tex = nodes.new("ShaderNodeTexWave")
            tex.wave_type = "BANDS"
            tex.bands_direction = "XYZ"[spec["pattern_axis"]]
            tex.inputs["Scale"].default_value = scale / 4.0
            tex.inputs["Distortion"].default_value = 0.0
            # Wave Fac is in [0, 1]; a threshold makes crisp two-colour stripes.
            fac = _node_math(nodes, links, "GREATER_THAN", tex.outputs["Fac"], 0.5)
        elif pattern == "checks":
            tex = nodes.new("ShaderNodeTexChecker")
            tex.inputs["Scale"].default_value = scale
            fac = tex.outputs["Fac"]
        else:
            tex = nodes.new("ShaderNodeTexNoise")
            tex.inputs["Scale"].default_value = scale
            fac = tex.outputs["Fac"]
        links.new(rest, tex.inputs["Vector"])
        base_socket = _mix(nodes, links, fac, colour_a.outputs[0], colour_b.outputs[0])
    elif pattern in ("dots", "plaid"):  # farm.synthesis.looks' held-out pool only
        scale = spec["pattern_scale"]
        if pattern == "dots":  # a regular grid of dots, a third of the cell across
            tex = nodes.new("ShaderNodeTexVoronoi")
            tex.inputs["Scale"].default_value = scale
            tex.inputs["Randomness"].default_value = 0.0
            links.new(rest, tex.inputs["Vector"])
            fac = _node_math(nodes, links, "LESS_THAN", tex.outputs["Distance"], 0.17)
        else:  # two crossing sets of bands: three tones where they cross
            bands = []
            for direction in ("X", "Z"):
                tex = nodes.new("ShaderNodeTexWave")
                tex.wave_type = "BANDS"
                tex.bands_direction = direction
                tex.inputs["Scale"].default_value = scale
                tex.inputs["Distortion"].default_value = 0.0
                links.new(rest, tex.inputs["Vector"])
                bands.append(_node_math(nodes, links, "GREATER_THAN", tex.outputs["Fac"], 0.65))
            fac = _node_math(nodes, links, "MULTIPLY", _node_math(nodes, links, "ADD", *bands), 0.5)
        base_socket = _mix(nodes, links, fac, spec["base_color"], spec["second_color"])
    elif pattern in ("denim", "knit"):
        # Thread scale: diagonal twill (light weft showing between indigo warps) or vertical ribs.
        tex = nodes.new("ShaderNodeTexWave")
        tex.wave_type = "BANDS"
        tex.bands_direction = "DIAGONAL" if pattern == "denim" else "X"
        tex.inputs["Scale"].default_value = spec["pattern_scale"] / (10.0 if pattern == "denim" else 20.0)
        tex.inputs["Distortion"].default_value = 0.0
        links.new(rest, tex.inputs["Vector"])
        base = np.array(spec["base_color"])
        other = (0.6 * base + 0.4 * np.array([0.8, 0.8, 0.78])) if pattern == "denim" else 0.6 * base
        fac = _node_math(nodes, links, "MULTIPLY", tex.outputs["Fac"], 0.6)
        base_socket = _mix(nodes, links, fac, colour_a.outputs[0], [float(c) for c in other])
    for key in ("mottle", "streaks"):
        if key in spec:
            # Skin mottle (isotropic) or hair streaks (stretched along Z): base x (1 -/+ amount).
            amount, scale = spec[key]["amount"], spec[key]["scale"]
            stretch = (1.0, 1.0, 1.0) if key == "mottle" else (1.0, 1.0, 0.1)
            fac = _noise_fac(nodes, links, _scaled_rest(nodes, links, rest, stretch), scale)
            base = np.array(spec["base_color"])
            lo, hi = np.clip(base * (1 - amount), 0, 1), np.clip(base * (1 + amount), 0, 1)
            base_socket = _mix(nodes, links, fac, [float(c) for c in lo], [float(c) for c in hi])
    if "iris" in spec:
        iris = spec["iris"]
        dist = []
        for c in iris["centres"]:
            vm = nodes.new("ShaderNodeVectorMath")
            vm.operation = "DISTANCE"
            links.new(rest, vm.inputs[0])
            vm.inputs[1].default_value = c
            dist.append(vm.outputs["Value"])
        d = _node_math(nodes, links, "MINIMUM", dist[0], dist[1])
        in_iris = _node_math(nodes, links, "LESS_THAN", d, iris["radius_m"])
        in_pupil = _node_math(nodes, links, "LESS_THAN", d, iris["pupil_m"])
        base_socket = _mix(nodes, links, in_iris, base_socket, iris["colour"])
        base_socket = _mix(nodes, links, in_pupil, base_socket, iris["pupil_colour"])
    if spec.get("print"):
        base_socket = _add_print(nodes, links, rest, base_socket, name, spec["print"])
    links.new(base_socket, bsdf.inputs["Base Color"])
    params = nodes.new("ShaderNodeCombineXYZ")
    params.inputs["X"].default_value = spec["roughness"]
    params.inputs["Y"].default_value = spec["metallic"]
    params.inputs["Z"].default_value = spec["transmission"]
    return mat, base_socket, params.outputs["Vector"]
