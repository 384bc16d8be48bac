"""torch -> ONNX export of RelightNet: one graph, dynamic batch/height/width,
metadata inside, SHA-256 beside it, optional fp16 variant (`python -m export`)."""
