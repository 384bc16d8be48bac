"""Subpackage `relight.imaging`: pixels with no person and no light in them (colour transfer, resampling,
the one box type); the lowest layer of the core, imported by every other."""
