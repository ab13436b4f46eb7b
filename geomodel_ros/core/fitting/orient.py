"""Orientation steps shared by the fitting units (the sensor sits at the origin)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["toward_sensor", "axis_toward_sensor", "longer_side_first"]


def toward_sensor(normal: NDArray[np.float64], at: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return ``normal`` (3,) or its opposite, whichever points from ``at`` [m] to the origin."""
    return -normal if normal @ at > 0 else normal


def axis_toward_sensor(axis: NDArray[np.float64], origin: NDArray[np.float64], lo: float,
                       hi: float) -> tuple[NDArray[np.float64], float, float]:
    """Flip an axis so that it points towards the sensor at the segment's midpoint.

    Parameters
    ----------
    axis : (3,) float64, unit
    origin : (3,) float64 [m]
        Point of the axis line from which ``lo`` and ``hi`` are measured.
    lo, hi : float [m]
        The segment ``origin + t * axis``, ``lo <= t <= hi``.

    Returns
    -------
    The axis and the segment's ends along it (negated and swapped when flipped).
    """
    if axis @ (origin + axis * (lo + hi) / 2) > 0:
        return -axis, -hi, -lo
    return axis, lo, hi


def longer_side_first(u: NDArray[np.float64], v: NDArray[np.float64],
                      span_u: tuple[float, float], span_v: tuple[float, float]
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                 tuple[float, float], tuple[float, float]]:
    """Order a rectangle's in-plane axes so that the first runs along its longer side.

    ``u``, ``v`` (3,) are unit axes with ``u x v`` the normal and ``span_u``, ``span_v``
    the rectangle's extents [m] along them; when ``v`` is longer the axes become
    (v, -u), which keeps the frame right-handed.
    """
    (lo_u, hi_u), (lo_v, hi_v) = span_u, span_v
    if hi_v - lo_v > hi_u - lo_u:
        return v, -u, (lo_v, hi_v), (-hi_u, -lo_u)
    return u, v, span_u, span_v
