"""Thesis task files (YAML): pick, place, pick-and-place, clear the table, empty a box."""
