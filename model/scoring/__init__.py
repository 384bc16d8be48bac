"""Measuring a model: metrics over the person's pixels, one prediction's metrics on an evaluation pair,
a checkpoint or ONNX file run on inputs, geometry diagnostics, the face region, and the evaluation
commands' shared ending.
"""
