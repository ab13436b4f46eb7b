"""Small 3-D helpers shared by the core: unit vectors, cross products, perpendicular bases.

Single 3-vectors are handled in plain floats (numpy's per-call overhead dominates at that
size: these run inside least-squares refinement loops); batches of vectors in numpy.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = ["EPS", "unit3", "cross3", "perpendicular_basis", "perpendicular_bases",
           "frame_with_z"]

#: Norms below this are treated as zero (the vector is returned as it is).
EPS = 1e-12

_X, _Y = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
#: A helper axis is crossed with ``a``; x unless ``a`` is within ~26 deg of x (|a_x| >= 0.9),
#: so the cross product never degenerates.
_HELPER_SWITCH = 0.9


def unit3(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """``v`` (3,) scaled to unit length (unchanged when its norm is below :data:`EPS`)."""
    n = math.sqrt(float(v[0]) ** 2 + float(v[1]) ** 2 + float(v[2]) ** 2)
    return v / n if n > EPS else v


def cross3(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Cross product of two (3,) vectors."""
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def perpendicular_basis(a: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Two unit vectors ``e1, e2`` (3,) with ``(e1, e2, a)`` right-handed and orthonormal.

    ``a`` (3,) must be a unit vector. ``e1 = a x h / |a x h|`` for a fixed helper axis ``h``.
    """
    e1 = unit3(cross3(a, _X if abs(a[0]) < _HELPER_SWITCH else _Y))
    return e1, cross3(a, e1)


def perpendicular_bases(a: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`perpendicular_basis` for every row of ``a`` (M, 3) at once: ``(u, v)`` (M, 3)."""
    helper = np.where(np.abs(a[:, :1]) < _HELPER_SWITCH, _X[None, :], _Y[None, :])
    u = np.cross(a, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(a, u)


def frame_with_z(z: NDArray[np.float64]) -> NDArray[np.float64]:
    """(3, 3) rotation whose columns are x, y, z with the given unit z (3,)."""
    e1, e2 = perpendicular_basis(z)
    return np.column_stack([-e1, -e2, z])
