"""SO(3)/SE(3) geometry: conventions, conversions, group operations, distances (docs/method.md §1–§5)."""
