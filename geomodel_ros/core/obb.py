"""Oriented bounding boxes and extents (paper sections 3.2.2-3.2.3).

Sizes come from projections of *all* of an object's points onto the model's axes. Two
corrections make them sub-millimetre accurate:

* an extent that ends at a sampled edge (not at a face perpendicular to the axis) is
  extended by half the point spacing, the expected gap between the last sample and the
  true edge;
* with ``reproject`` the points are first moved along their viewing rays (sensor at the
  origin) onto the fitted surface, which removes depth noise before taking extremes.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import ConvexHull, QhullError

from geomodel_ros.core.fastmath import row_norms
from geomodel_ros.core.geometry import perpendicular_basis

__all__ = ["ray_to_plane", "ray_scale_to_plane", "ray_offset_to_plane", "ray_offset_from",
           "ray_to_cylinder", "hull_candidates",
           "min_area_rectangle", "orthonormalize_axes", "upright_axes", "interval", "edge_gap"]

#: A ray that meets a plane at a cosine below this (more obliquely than about 78 deg)
#: moves a point ill-conditioned (a small depth error becomes a large shift): such points
#: stay where they are.
MIN_RAY_COS = 0.2
#: The sampling gap at an edge is judged from the projections within this many point
#: spacings of the extreme (a few sampling rows).
EDGE_BAND = 4.0
#: The expected gap between the last sample and the true edge: this share of the
#: largest step between samples near the edge (uniform position within one step).
EDGE_GAP_SHARE = 0.5
#: Clouds of fewer points go to qhull whole: the Akl-Toussaint filter would save nothing.
HULL_FILTER_MIN_POINTS = 64
#: Extreme directions of the Akl-Toussaint filter (an octagon inside the hull).
HULL_DIRECTIONS = 8
#: The filter's projections are taken over this many points at a time: the (8, n)
#: products of a desk's 10^5 points (several MB each, fresh pages every frame) become
#: blocks of 512 KB that stay in the cache; every value and decision is the same.
HULL_CHUNK = 8192


def _shift_ok(s: NDArray[np.float64], dist: NDArray[np.float64], max_shift: float
              ) -> NDArray[np.bool_]:
    return np.isfinite(s) & (np.abs(s - 1.0) * dist <= max_shift)


def ray_to_plane(points: NDArray[np.float64], normal: NDArray[np.float64], d: float,
                 max_shift: float, min_cos: float = MIN_RAY_COS) -> NDArray[np.float64]:
    """Move points along their rays from the origin onto the plane n . x + d = 0.

    Points that would move by more than ``max_shift`` [m] (points of another surface) or
    whose ray meets the plane more obliquely than ``arccos(min_cos)`` (ill-conditioned)
    are left where they are.
    """
    scale = ray_scale_to_plane(points @ normal, row_norms(points), d, max_shift, min_cos)
    return points * scale[:, None]


def ray_scale_to_plane(height: NDArray[np.float64], dist: NDArray[np.float64], d: float,
                       max_shift: float, min_cos: float = MIN_RAY_COS) -> NDArray[np.float64]:
    """Return factors that move points onto the plane n . x + d = 0 along their rays.

    As :func:`ray_to_plane`, from the points' ``height`` n . x (n,) and distance |x|
    (n,) [m] from the origin; 1 where a point stays.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -d / height
    ok = _shift_ok(s, dist, max_shift) & (np.abs(height) >= min_cos * dist)
    return np.where(ok, s, 1.0)


def ray_offset_to_plane(points: NDArray[np.float64], normal: NDArray[np.float64], d: float,
                        min_cos: float = MIN_RAY_COS) -> NDArray[np.float64]:
    """Distance [m] (n,) along each point's ray from the origin to the plane n . x + d = 0.

    The depth error a point of that plane would have. 0 where the ray meets the plane
    more obliquely than ``arccos(min_cos)`` (ill-conditioned: judged as on the plane), inf
    where it never meets it.
    """
    return ray_offset_from(points @ normal, row_norms(points), d, min_cos)


def ray_offset_from(height: NDArray[np.float64], dist: NDArray[np.float64], d: float,
                    min_cos: float = MIN_RAY_COS) -> NDArray[np.float64]:
    """Return :func:`ray_offset_to_plane` from the points' ``height`` n . x and range |x| (n,)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -d / height
    off = np.where(np.isfinite(s) & (s > 0), np.abs(s - 1.0) * dist, np.inf)
    return np.where(np.abs(height) >= min_cos * dist, off, 0.0)


def ray_to_cylinder(points: NDArray[np.float64], point: NDArray[np.float64],
                    axis: NDArray[np.float64], radius: float, max_shift: float
                    ) -> NDArray[np.float64]:
    """Move points (n, 3) along their rays from the origin onto a cylinder.

    Of the two crossings of a ray with the cylinder the one nearest the point is taken
    (scale closest to 1); points that would move more than ``max_shift`` [m], or whose
    ray misses the cylinder, stay.
    """
    pp = points - (points @ axis)[:, None] * axis
    p0 = point - (point @ axis) * axis
    a = np.einsum("ij,ij->i", pp, pp)
    b = -2.0 * (pp @ p0)
    c = p0 @ p0 - radius * radius
    disc = b * b - 4 * a * c
    ok = (disc >= 0) & (a > 0)
    sq = np.sqrt(np.where(ok, disc, 0.0))
    a_safe = np.where(a > 0, a, 1.0)
    s1, s2 = (-b - sq) / (2 * a_safe), (-b + sq) / (2 * a_safe)
    s = np.where(np.abs(s1 - 1) < np.abs(s2 - 1), s1, s2)
    ok &= _shift_ok(s, row_norms(points), max_shift)
    return points * np.where(ok, s, 1.0)[:, None]


def edge_gap(values: NDArray[np.float64], spacing: float) -> float:
    """Return the expected distance [m] from the largest of ``values`` to the edge beyond it.

    Near a sampled edge the projections of the last samples are either spread almost
    continuously (edge oblique to the sampling grid: the extreme sample sits nearly on
    the edge) or fall into discrete rows (edge parallel to the grid: the gap is uniform
    over one row step). Half (EDGE_GAP_SHARE) the largest step between consecutive
    projections within EDGE_BAND spacings of the extreme covers both cases.
    """
    if values.size < 2 or spacing <= 0:
        return 0.0
    return _gap(values, float(values.max()), spacing, below=False)


def _gap(values: NDArray[np.float64], extreme: float, spacing: float, below: bool) -> float:
    """Return :func:`edge_gap` of ``values`` (n >= 2) whose largest is ``extreme`` [m].

    With ``below`` the gap below the smallest, ``extreme``: ``edge_gap(-values)``
    without the negated copy (the same band and steps: negation is exact).
    """
    reach = EDGE_BAND * spacing
    near = values <= extreme + reach if below else values >= extreme - reach
    band = np.sort(values[near])
    if band.size < 2:
        return EDGE_GAP_SHARE * spacing
    return EDGE_GAP_SHARE * float(np.max(np.diff(band)))


def interval(values: NDArray[np.float64], spacing: float, closed_low: float | None = None,
             closed_high: float | None = None, correct: bool = True) -> tuple[float, float]:
    """Extent of projected values along one axis.

    Parameters
    ----------
    values : (n,) float64 array [m]
        Projections of the object's points on the axis.
    spacing : float [m]
        Median point spacing; with ``correct`` open ends move outwards by the expected
        sampling gap (:func:`edge_gap`).
    closed_low, closed_high : float or None [m]
        Position of a fitted face perpendicular to the axis at that end; used as the end
        itself (no sampling gap there).
    """
    lo = float(values.min()) if closed_low is None else float(closed_low)
    hi = float(values.max()) if closed_high is None else float(closed_high)
    measured = correct and values.size >= 2 and spacing > 0
    if measured and closed_low is None:
        lo -= _gap(values, lo, spacing, below=True)
    if measured and closed_high is None:
        hi += _gap(values, hi, spacing, below=False)
    return lo, hi


def hull_candidates(xy: NDArray[np.float64], directions: int = HULL_DIRECTIONS
                    ) -> NDArray[np.float64]:
    """Points of ``xy`` (n, 2) that may be convex-hull vertices (Akl-Toussaint filter).

    The extreme points in ``directions`` evenly spaced directions span a convex polygon
    inside the hull; points strictly inside it cannot be hull vertices and are dropped,
    which leaves qhull a small fraction of a dense cloud.
    """
    if len(xy) < HULL_FILTER_MIN_POINTS:
        return xy
    ang = np.arange(directions) * (2.0 * np.pi / directions)
    dirs = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    xt = np.ascontiguousarray(xy.T)  # (2, n): products and reductions along long rows
    poly = xy[_extremes(dirs, xt)]  # counter-clockwise by construction
    keep_vertex = np.r_[True, np.any(np.diff(poly, axis=0) != 0, axis=1)]
    poly = poly[keep_vertex]
    if len(poly) > 1 and np.all(poly[-1] == poly[0]):
        poly = poly[:-1]
    if len(poly) < 3:
        return xy
    edges = np.roll(poly, -1, axis=0) - poly
    inward = np.stack([-edges[:, 1], edges[:, 0]], axis=1)
    inward /= np.linalg.norm(inward, axis=1, keepdims=True)
    # Strictly left of every edge = strictly inside; a small margin keeps round-off safe.
    margin = 1e-9 * float(np.max(np.abs(xy[0]))) + 1e-12
    offset = np.einsum("ij,ij->i", inward, poly) + margin
    keep = np.empty(len(xy), dtype=bool)
    for start in range(0, len(xy), HULL_CHUNK):
        proj = inward @ xt[:, start:start + HULL_CHUNK]  # (edges, chunk)
        proj -= offset[:, None]
        keep[start:start + HULL_CHUNK] = ~(proj.min(axis=0) > 0)
    return np.compress(keep, xy, axis=0)  # several times faster than xy[keep]


def _extremes(dirs: NDArray[np.float64], xt: NDArray[np.float64]) -> NDArray[np.int64]:
    """Index of the point of ``xt`` (2, n) farthest along each of ``dirs`` (d, 2).

    The first of equal ones, as ``np.argmax(dirs @ xt, axis=1)``, in blocks of HULL_CHUNK
    points.
    """
    best = np.full(len(dirs), -np.inf)
    index = np.zeros(len(dirs), dtype=np.int64)
    rows = np.arange(len(dirs))
    for start in range(0, xt.shape[1], HULL_CHUNK):
        proj = dirs @ xt[:, start:start + HULL_CHUNK]
        j = np.argmax(proj, axis=1)
        value = proj[rows, j]
        better = value > best  # a later block wins only when strictly farther
        best[better] = value[better]
        index[better] = start + j[better]
    return index


def min_area_rectangle(xy: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
    """Direction (2,) of the first side of the minimum-area enclosing rectangle of ``xy``.

    Rotating calipers over the convex hull edges, vectorised. Returns the unit direction
    and the rectangle's area [m^2].
    """
    try:
        cand = hull_candidates(xy)
        hull = cand[ConvexHull(cand).vertices]
    except (QhullError, ValueError):
        return np.array([1.0, 0.0]), 0.0
    edges = np.roll(hull, -1, axis=0) - hull
    lengths = np.linalg.norm(edges, axis=1)
    dirs = edges[lengths > 0] / lengths[lengths > 0, None]
    normals = np.stack([-dirs[:, 1], dirs[:, 0]], axis=1)
    pu = dirs @ hull.T
    pv = normals @ hull.T
    areas = (pu.max(1) - pu.min(1)) * (pv.max(1) - pv.min(1))
    i = int(np.argmin(areas))
    return dirs[i], float(areas[i])


def orthonormalize_axes(normals: NDArray[np.float64], weights: NDArray[np.float64],
                        assignment: NDArray[np.int64]) -> NDArray[np.float64]:
    """Closest rotation whose axes match the given face normals (orthogonal Procrustes).

    Parameters
    ----------
    normals : (F, 3) float64, unit face normals
    weights : (F,) float64, e.g. face sizes
    assignment : (F,) int64 in {0, 1, 2}
        Which axis each normal belongs to (sign is absorbed).

    Returns
    -------
    (3, 3) rotation, columns = axes, det = +1.
    """
    # Orthogonal Procrustes: R = argmin sum w |R e_a - s n|^2 with the sign s of each
    # normal chosen to agree with the heaviest normal of its axis.
    m = np.zeros((3, 3))
    for a in range(3):
        sel = np.flatnonzero(assignment == a)
        if sel.size == 0:
            continue
        ref = normals[sel[np.argmax(weights[sel])]]
        signed = normals[sel] * np.sign(normals[sel] @ ref)[:, None]
        m[:, a] = (weights[sel, None] * signed).sum(axis=0)
    # Axis signs are free: make the target triple right-handed before solving.
    if np.linalg.det(m) < 0:
        m[:, 2] *= -1
    u, _, vt = np.linalg.svd(m)
    r = u @ vt
    if np.linalg.det(r) < 0:
        u[:, -1] *= -1
        r = u @ vt
    return r


def upright_axes(up: NDArray[np.float64], normals: NDArray[np.float64],
                 weights: NDArray[np.float64], assignment: NDArray[np.int64]
                 ) -> NDArray[np.float64]:
    """Rotation (3, 3) whose axis 2 is ``up`` (3,) and axes 0, 1 follow the side faces.

    Only the ``normals`` (F, 3) of the faces on axes 0 and 1 count (``assignment`` (F,)),
    by their components across ``up``, weighted by ``weights`` (F,) and by how far they
    lie across it: the angle of axis 0 about ``up`` is the weighted circular mean of the
    faces' directions modulo 180 deg (a normal's sign is free), those on axis 1 taken a
    quarter turn back. Faces on axis 2 and those of no axis (-1) do not turn it.
    Columns are the axes, det = +1; axis 0 is an arbitrary direction across ``up`` when
    no side face is given.
    """
    z = up / np.linalg.norm(up)
    e1, e2 = perpendicular_basis(z)
    side = (assignment == 0) | (assignment == 1)
    theta = 0.0
    if side.any():
        u, v = normals[side] @ e1, normals[side] @ e2
        angle = np.arctan2(v, u) - np.where(assignment[side] == 1, np.pi / 2, 0.0)
        w = weights[side] * np.hypot(u, v)
        theta = float(np.angle(np.sum(w * np.exp(2j * angle)))) / 2.0
    x = np.cos(theta) * e1 + np.sin(theta) * e2
    return np.column_stack([x, np.cross(z, x), z])
