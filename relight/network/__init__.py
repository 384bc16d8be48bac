"""The relighting network at run time: the checked ONNX session, the runtime that finds the person,
crops and runs the network (`Relighter.decompose`), the decomposition and its relighting formula,
what changes the photo's light (test-time augmentation, the level prior, refinement), the quality
presets, the PRT render formula, resizing, and the relit person composited over the full-resolution
photo; the face's own mesh and its relighting.
"""
