"""Bundled actuator models built from :mod:`hhra_phys.parts` (one module or package per model)."""
