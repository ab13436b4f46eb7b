"""A box's axes from the modes of an object's point normals, and normals judged against a model.

Under depth noise far from the sensor a small box's segment may split into faces that
each span two of its sides: no face is planar and none has a flat core, so no box is
built from the faces, while a round model explains the points' positions as well as the
box within the wide noise band. The box still shows in the normals: they gather around
the directions of its visible sides, where a round side's normals turn evenly with the
arc. :func:`box_axes` finds those directions (the most populated direction within the
angular tolerance, then the most populated one perpendicular to it), :func:`side_labels`
groups the points by the side they face, and :func:`normal_costs` measures how well a
fitted model's surface normals agree with the measured ones (a truncated cost, like the
residuals' MSAC cost, with the angular tolerance as its band).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.fitting.measure import every_kth

__all__ = ["MODE_CANDIDATES", "MODE_REFINE_ROUNDS", "MIN_SIDE_NORMALS", "box_axes",
           "side_labels", "axis_costs", "normal_costs"]

#: Point normals tried as the centre of a mode (every k-th, about this many): a mode
#: holding a tenth of the normals has about twenty of them among the candidates.
MODE_CANDIDATES = 200
#: Rounds of refining a mode's direction as the mean of the normals within the tolerance
#: of it (sign-aligned); the count of a mode settles after one or two.
MODE_REFINE_ROUNDS = 2
#: Fewest point normals a side of the box needs (each of the two modes, and each face
#: of the box built from them): fewer give no plane to refine, and no box.
MIN_SIDE_NORMALS = 10


def _mode(normals: NDArray[np.float64], candidates: NDArray[np.float64], cos_tol: float,
          across: NDArray[np.float64] | None = None) -> tuple[NDArray[np.float64], int]:
    """Return the direction (3,) within ``cos_tol`` of most of ``normals`` (m, 3), and its count.

    The best of ``candidates`` (c, 3), unit, refined as the mean of its sign-aligned
    normals; kept perpendicular to the unit ``across`` (3,) when given.
    """
    counts = np.count_nonzero(np.abs(candidates @ normals.T) >= cos_tol, axis=1)
    axis = candidates[int(np.argmax(counts))]
    count = int(counts.max())
    for _ in range(MODE_REFINE_ROUNDS):
        dots = normals @ axis
        near = np.abs(dots) >= cos_tol
        if not near.any():
            break
        mean = (normals[near] * np.sign(dots[near])[:, None]).sum(axis=0)
        if across is not None:
            mean = mean - (mean @ across) * across
        norm = float(np.linalg.norm(mean))
        if norm <= 0.0:
            break
        axis = mean / norm
        count = int(np.count_nonzero(np.abs(normals @ axis) >= cos_tol))
    return axis, count


def box_axes(normals: NDArray[np.float64], tol: float) -> NDArray[np.float64] | None:
    """Return box axes (3, 3) (columns, right-handed) from the modes of ``normals`` (m, 3).

    The first axis is the direction within ``tol`` [rad] of most of the (unit) normals,
    the second the one within ``tol`` of most of them among the directions perpendicular
    to it, the third their cross product. None when either mode holds fewer than
    :data:`MIN_SIDE_NORMALS` normals (no two sides of a box are seen).
    """
    if len(normals) < 2 * MIN_SIDE_NORMALS:
        return None
    cos_tol = math.cos(tol)
    cand = every_kth(normals, MODE_CANDIDATES)
    a1, n1 = _mode(normals, cand, cos_tol)
    if n1 < MIN_SIDE_NORMALS:
        return None
    across = cand - np.outer(cand @ a1, a1)
    norm = np.linalg.norm(across, axis=1)
    keep = np.abs(cand @ a1) <= math.sin(tol)
    if not keep.any():
        return None
    a2, n2 = _mode(normals, across[keep] / norm[keep, None], cos_tol, a1)
    if n2 < MIN_SIDE_NORMALS:
        return None
    return np.column_stack([a1, a2, np.cross(a1, a2)])


def side_labels(normals: NDArray[np.float64], axes: NDArray[np.float64], tol: float
                ) -> NDArray[np.int64]:
    """Return the side (m,) each of ``normals`` (m, 3) faces: 2 a + (1 if along +axis a).

    ``axes`` (3, 3) columns; -1 for a normal farther than ``tol`` [rad] from every axis
    (an edge's mixed normals).
    """
    dots = normals @ axes
    a = np.argmax(np.abs(dots), axis=1)
    d = dots[np.arange(len(a)), a]
    labels = 2 * a + (d > 0)
    return np.where(np.abs(d) >= math.cos(tol), labels, -1).astype(np.int64)


def normal_costs(model: NDArray[np.float64], measured: NDArray[np.float64], tol: float
                 ) -> NDArray[np.float64]:
    """Return the truncated angular cost (m,) in [0, 1] of ``model`` normals against ``measured``.

    Both (m, 3), unit. min(angle / ``tol``, 1)^2 with the angle between the two lines
    (sign ignored): a measured normal within the tolerance [rad] costs its squared angle,
    one beyond it (an edge's, a stray's) one band.
    """
    cos = np.clip(np.abs(np.einsum("ij,ij->i", model, measured)), 0.0, 1.0)
    return np.minimum(np.arccos(cos) / tol, 1.0) ** 2


def axis_costs(axes: NDArray[np.float64], measured: NDArray[np.float64], tol: float
               ) -> NDArray[np.float64]:
    """:func:`normal_costs` (m,) of the nearest of ``axes`` (3, 3) to each measured normal.

    No box with these axes has lower normal costs (its face at a point is one of them).
    """
    cos = np.clip(np.abs(measured @ axes).max(axis=1), 0.0, 1.0)
    return np.minimum(np.arccos(cos) / tol, 1.0) ** 2
