"""SO(3)/SE(3) geometry: conventions, conversions, group operations, distances (MATH.md §1–§5)."""
