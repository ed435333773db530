"""Simulated embodiments: robot registry, SAPIEN world, physics-derived sensors, spherical model, control and planning."""
