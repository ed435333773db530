"""LOC object features (thesis §8.4.3): sorted dimensions, SOS/AOS activations (eq. 8.1-8.2), weight."""

from __future__ import annotations

import numpy as np

HAND_OPENING = 150.0  # mm, comfortable hand opening H
FEATURES = ("SOS", "AOS", "D1", "D2", "D3", "W")
FEATURE_SETS: dict[str, tuple[str, ...]] = {
    "SOS, AOS": ("SOS", "AOS"),
    "D1, D2, D3": ("D1", "D2", "D3"),
    "SOS, AOS, D1": ("SOS", "AOS", "D1"),
    "SOS, AOS, W": ("SOS", "AOS", "W"),
    "SOS, AOS, D1, D2, D3, W": FEATURES,
}
"""The feature subsets of Tables 8.2 and 8.3."""


def _sorted_dims(d1, d2, d3):
    d = np.sort(np.stack(np.broadcast_arrays(np.asarray(d1, float), np.asarray(d2, float), np.asarray(d3, float))), axis=0)
    return d[2], d[1], d[0]


def sos_activation(d1, d2, d3, hand: float = HAND_OPENING):
    """Surface-orientation-selective activation, eq. 8.1 (dimensions in mm, any order)."""
    d1, d2, d3 = _sorted_dims(d1, d2, d3)
    return (1.0 - ((d1 - d2) / (d1 + d2)) ** 2 - 0.03 * d3 / (d1 + d2)
            - 0.5 / (1.0 + np.exp(-0.04 * (d3 - hand))))


def aos_activation(d1, d2, d3, hand: float = HAND_OPENING):
    """Axis-orientation-selective activation, eq. 8.2 as printed (dimensions in mm, any order)."""
    d1, d2, d3 = _sorted_dims(d1, d2, d3)
    return (1.0 - (d1 - d2) / (d1 + d2) - 0.37 * d1 / np.maximum(d3, 1e-6)
            - 0.5 / (1.0 + np.exp(-0.04 * (d1 - hand))))


def object_features(dims_m: np.ndarray, weight: float = float("nan"), names: tuple[str, ...] = FEATURES) -> np.ndarray:
    """Feature vector (in ``names`` order) from box dimensions (m) and weight (N).

    Dimensions are converted to millimetres and sorted D1 >= D2 >= D3; a non-positive or
    non-finite dimension gives NaN features rather than an error.
    """
    d = np.asarray(dims_m, float).reshape(-1)
    if d.shape != (3,):
        raise ValueError(f"object_features.dims_m: expected 3 dimensions, got {d.shape}")
    if not np.all(np.isfinite(d)) or np.any(d <= 0):
        return np.full(len(names), np.nan)
    d1, d2, d3 = np.sort(d * 1000.0)[::-1]
    values = {"SOS": float(sos_activation(d1, d2, d3)), "AOS": float(aos_activation(d1, d2, d3)),
              "D1": d1, "D2": d2, "D3": d3, "W": float(weight)}
    unknown = [n for n in names if n not in values]
    if unknown:
        raise ValueError(f"object_features.names: unknown features {unknown} (known: {FEATURES})")
    return np.array([values[n] for n in names])


def select(X: np.ndarray, subset: tuple[str, ...], names: tuple[str, ...] = FEATURES) -> np.ndarray:
    """Columns of ``X`` (named ``names``) for one feature subset."""
    return np.asarray(X)[:, [names.index(n) for n in subset]]
