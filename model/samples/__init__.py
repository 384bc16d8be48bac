"""Training and evaluation samples from scene files: the two datasets, which scenes and lights may
train, crops, cache and packs, the seeded augmentation draws, the photo-like capture of inputs, and
a tiny analytic dataset for tests and benchmarks.
"""
