"""Perceptual primitives exposing detection and recognition to tasks (thesis §3, §8.6)."""
