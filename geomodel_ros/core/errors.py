"""Errors of the geomodel_ros core."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["InputError", "as_points"]


class InputError(ValueError):
    """Malformed input arrays (wrong shape, dtype or length)."""


def as_points(points, *, allow_organized: bool = False) -> NDArray[np.float64]:
    """``points`` as a contiguous (N, 3) float64 array, or raise :class:`InputError`.

    With ``allow_organized`` an (H, W, 3) array is accepted and flattened row-major.
    """
    arr = np.asarray(points)
    if allow_organized and arr.ndim == 3 and arr.shape[2] == 3:
        arr = arr.reshape(-1, 3)
    if arr.ndim != 2 or arr.shape[1] != 3:
        allowed = "(N, 3) or (H, W, 3)" if allow_organized else "an (N, 3) array"
        raise InputError(f"points must be {allowed}, got shape {np.shape(points)}")
    if not (np.issubdtype(arr.dtype, np.number) or arr.dtype == np.bool_):
        raise InputError(f"points must be numeric, got dtype {arr.dtype}")
    return np.ascontiguousarray(arr, dtype=np.float64)
