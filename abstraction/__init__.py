"""Embodiment abstraction (thesis ch. 7): ATDs, abstract primitives and events, translator, factories."""
