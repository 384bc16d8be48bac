"""Synthetic training data: scene synthesis, transport bake, Cycles ground truth, executors."""
