"""Cycles scenes that tests and benchmarks build to check the conventions against a renderer
(bpy needed): a World whose radiance is one SH basis function."""

from __future__ import annotations

import math

import bpy


def sh_world(scene: bpy.types.Scene, index: int) -> None:
    """World radiance = the real SH basis function Y_k(w) (negative emission allowed).

    Built from the world's direction vector with math nodes, exactly the
    polynomial form of relight.sh for l <= 2, which is what the transport
    check needs.
    """
    world = scene.world or bpy.data.worlds.new("World")
    scene.world = world
    nodes, links = world.node_tree.nodes, world.node_tree.links
    nodes.clear()
    coord = nodes.new("ShaderNodeTexCoord")
    split = nodes.new("ShaderNodeSeparateXYZ")
    links.new(coord.outputs["Generated"], split.inputs["Vector"])
    x, y, z = split.outputs["X"], split.outputs["Y"], split.outputs["Z"]

    def math_node(op, a, b):
        node = nodes.new("ShaderNodeMath")
        node.operation = op
        node.use_clamp = False
        for i, operand in enumerate((a, b)):
            if isinstance(operand, float):
                node.inputs[i].default_value = operand
            else:
                links.new(operand, node.inputs[i])
        return node.outputs[0]

    c0 = 0.5 * math.sqrt(1.0 / math.pi)
    c1 = math.sqrt(3.0 / (4.0 * math.pi))
    c2 = 0.5 * math.sqrt(15.0 / math.pi)
    c20 = 0.25 * math.sqrt(5.0 / math.pi)
    c22 = 0.25 * math.sqrt(15.0 / math.pi)
    if index == 0:
        value = math_node("ADD", math_node("MULTIPLY", x, 0.0), c0)
    elif index == 1:
        value = math_node("MULTIPLY", y, c1)
    elif index == 2:
        value = math_node("MULTIPLY", z, c1)
    elif index == 3:
        value = math_node("MULTIPLY", x, c1)
    elif index == 4:
        value = math_node("MULTIPLY", math_node("MULTIPLY", x, y), c2)
    elif index == 5:
        value = math_node("MULTIPLY", math_node("MULTIPLY", y, z), c2)
    elif index == 6:
        value = math_node("MULTIPLY", math_node("SUBTRACT", math_node("MULTIPLY", math_node("MULTIPLY", z, z), 3.0), 1.0), c20)
    elif index == 7:
        value = math_node("MULTIPLY", math_node("MULTIPLY", x, z), c2)
    elif index == 8:
        value = math_node("MULTIPLY", math_node("SUBTRACT", math_node("MULTIPLY", x, x), math_node("MULTIPLY", y, y)), c22)
    else:
        raise ValueError(f"sh_world supports SH indices 0..8, got {index}")
    combine = nodes.new("ShaderNodeCombineXYZ")
    for axis in ("X", "Y", "Z"):
        links.new(value, combine.inputs[axis])
    background = nodes.new("ShaderNodeBackground")
    background.inputs["Strength"].default_value = 1.0
    output = nodes.new("ShaderNodeOutputWorld")
    links.new(combine.outputs["Vector"], background.inputs["Color"])
    links.new(background.outputs["Background"], output.inputs["Surface"])
