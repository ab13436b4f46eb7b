"""Levels of a segment: a box's top with part of the segment rising beyond it.

A body standing on a box (a box, a can, a cup) meets the box's top along a concave crease,
which the segmentation cuts. Where a side of the upper body is flush with a side of the
box below, or a real sensor's noise rounds the crease over, the two come as one segment,
and one model may explain both within the noise (the box that holds them). The lower box's
top, seen round the upper body, still says where the two meet: a planar face parallel to
the support below, with points of the segment rising beyond it.

A level is the height above the support (its points' median) of such a face of at least
``seg_min_cluster_points`` points (the seen part of a body), farther above it than
``ransac_threshold`` (a piece of the support itself is none). At least
``seg_min_cluster_points`` of the object's points rise more than ``ransac_threshold``
beyond it and as many do not, and no more than :data:`LEVEL_INSIDE_SHARE` of the face's
points lie within the footprint (the convex hull on the support plane) of the points
rising beyond: a container's inner floor lies within its wall's footprint, a box's top
under a can shows round the can (the part under it hidden by it). The segment is then
modeled as the two parts on either side of the level
(:func:`geomodel_ros.core.compounds.split_compounds`), which keeps the split only when
they are two bodies. (The tops of faces perpendicular to the support, a box's sides below
a narrower body, were measured too and are no levels: a box's own side seen at a grazing
angle may end below its top.)

A body standing on a box whose top it hides (a can on a box seen from the side) leaves no
such face, but its silhouette steps: the object's width across the view keeps one value
below the box's top and another above it (:func:`silhouette_step`). An object in front
that hides part of one body's width makes a step too; the sensor must then see past the
narrower part where the wider one would reach (the background beside a can on a box, not
an occluder in front).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import ConvexHull, Delaunay, QhullError

from geomodel_ros.core.fitting.cloud import ObjectFace, Plane
from geomodel_ros.core.fitting.completion import CELL_SPACINGS
from geomodel_ros.core.geometry import perpendicular_basis
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.view import SceneView

__all__ = ["LEVEL_INSIDE_SHARE", "Level", "nearest_support_below", "object_levels",
           "silhouette_step"]

#: A level face's points within the footprint of what rises beyond it: at most this
#: share for that to stand on the face's body.
LEVEL_INSIDE_SHARE = 0.5
#: A slice's width spans its points across the view between this percentile and its
#: complement.
WIDTH_PERCENTILE = 3.0
#: Slices with fewer points have no width.
MIN_SLICE_POINTS = 20
#: Slices are at least this many point spacings thick (a few rows of the image).
SLICE_SPACINGS = 3.0
#: The points stand above a support when at most this share of them lie more than a
#: RANSAC threshold below its plane.
BELOW_SHARE = 0.1


@dataclass(frozen=True)
class Level:
    """A height above a support plane where one body of a segment stands on another.

    Attributes
    ----------
    normal : (3,) float64 array
        The support plane's unit normal, towards the sensor.
    offset : float
        Its offset d [m] (n . x + d = 0).
    height : float
        The level's height [m] above it.
    """

    normal: NDArray[np.float64]
    offset: float
    height: float

    def above(self, points: NDArray[np.float64], margin: float) -> NDArray[np.bool_]:
        """Tell which ``points`` (n, 3) [m] rise more than ``margin`` [m] beyond the level."""
        return points @ self.normal + self.offset > self.height + margin


def nearest_support_below(points: NDArray[np.float64], supports: tuple[Plane, ...] | list[Plane],
                  threshold: float) -> Plane | None:
    """Return the nearest of the ``supports`` that ``points`` (n, 3) [m] stand above, or None.

    Nearest by the points' mean height; above it: all but :data:`BELOW_SHARE` of the
    points on its sensor side or within ``threshold`` [m] of it. (Not the first plane the
    object lies on one side of, :func:`~.verify.standing_on`: a level's height is taken
    above the support right below it, a table's top rather than the floor under it.)
    """
    best: tuple[float, Plane] | None = None
    for normal, offset in supports:
        height = points @ normal + offset
        if np.mean(height < -threshold) > BELOW_SHARE:
            continue
        low = float(np.mean(height))
        if best is None or low < best[0]:
            best = (low, (normal, offset))
    return None if best is None else best[1]


def object_levels(points: NDArray[np.float64], faces: list[ObjectFace],
                  supports: tuple[Plane, ...] | list[Plane], params: ModelingParams,
                  seen: tuple[SceneView, int, float] | None = None) -> tuple[Level, ...]:
    """Return the levels of an object's ``points`` (n, 3) [m] (see the module docstring).

    ``faces`` are its faces (:func:`~.cloud.build_faces`), ``supports`` the scene's support
    planes, ``params`` the object's (its ``ransac_threshold`` at its range). With
    ``seen`` (the scene's view, the sensor at the origin, the object's label in it and
    its points' median spacing [m]) the step of the object's width across the view adds
    one (:func:`silhouette_step`). Levels within a threshold of one found before are left
    out; lowest first.
    """
    least = params.seg_min_cluster_points
    if not supports or len(points) < 2 * least:
        return ()
    thr = params.ransac_threshold
    cos_tol = math.cos(params.angle_tolerance)
    flats = [f for f in faces if f.info.planar and len(f.points) >= least]
    below = nearest_support_below(points, supports, thr)
    if below is None:
        return ()
    normal, offset = below
    height = points @ normal + offset
    flat: NDArray[np.float64] | None = None
    levels: list[float] = []
    for face in flats:
        if abs(float(face.info.normal @ normal)) < cos_tol:
            continue
        level = float(np.median(height[face.points]))
        above = height > level + thr
        rising = int(np.count_nonzero(above))
        if level <= thr or rising < least or len(points) - rising < least or \
                any(abs(level - h) <= thr for h in levels):
            continue
        if flat is None:
            e1, e2 = perpendicular_basis(normal)
            flat = np.stack([points @ e1, points @ e2], axis=1)
        if _share_within(flat[above], flat[face.points]) <= LEVEL_INSIDE_SHARE:
            levels.append(level)
    if seen is not None:
        view, oid, spacing = seen
        step = silhouette_step(points, height, (normal, offset),
                               max(thr, SLICE_SPACINGS * spacing), least,
                               (view, oid, CELL_SPACINGS * spacing))
        if step is not None and all(abs(step - h) > thr for h in levels):
            levels.append(step)
    return tuple(Level(normal, float(offset), h) for h in sorted(levels))


def silhouette_step(points: NDArray[np.float64], height: NDArray[np.float64],
                    support: Plane, tol: float, least: int,
                    seen: tuple[SceneView, int, float] | None = None) -> float | None:
    """Return the height [m] where the object's width across the view steps, or None.

    ``points`` (n, 3) [m] seen from the origin, ``height`` (n,) [m] theirs above the
    ``support`` plane (unit normal, offset). The points are cut into slices ``tol`` [m] thick; a
    slice's width is the extent of its points across the ray to the object (horizontal,
    between the :data:`WIDTH_PERCENTILE` and its complement). A body standing on another
    of another width shows two runs of slices each of one width within ``tol`` / 2, their
    mean widths ``tol`` apart or more, at least two slices and ``least`` points each (a
    taper changes the width within the runs); between them one or two slices (the lower
    body's top and the upper body's foot), and above them the top slice (a lid, a top
    face) are not compared. The level is the bottom of the slices between; of several
    such steps the largest. A box, a can, a lying can keep one width; a cone's, a cup's,
    a sphere's, a bowl's change from slice to slice. With ``seen`` (the scene's view, the
    object's label in it and an angular cell [m at 1 m]) the sensor must see past the
    narrower run where the wider one would reach (:func:`_seen_past`): an object in front
    that hides part of a body's width makes a step too.
    """
    normal, offset = support
    across = np.cross(normal, points.mean(axis=0))
    norm = float(np.linalg.norm(across))
    if norm == 0.0:
        return None
    x = points @ (across / norm)
    k = np.floor(height / tol).astype(np.int64)
    keep = np.flatnonzero(k >= 0)
    if len(keep) == 0:
        return None
    # One sort by slice, then across (the extent of x is below 1 + its span).
    xk = x[keep]
    order = np.argsort(k[keep] * (float(np.ptp(xk)) + 1.0) + (xk - xk.min()))
    ks, xs = k[keep][order], xk[order]
    ids, start, count = np.unique(ks, return_index=True, return_counts=True)
    full = count >= MIN_SLICE_POINTS
    ids, start, count = ids[full], start[full], count[full]
    m = len(ids)
    if m < 6:  # two slices below, one between, two above and the top slice
        return None
    lo = xs[start + np.floor((count - 1) * WIDTH_PERCENTILE / 100).astype(np.int64)]
    hi = xs[start + np.ceil((count - 1) * (1 - WIDTH_PERCENTILE / 100)).astype(np.int64)]
    width = hi - lo
    # Every split at once: the run below ends before slice e, the one above starts at j and
    # ends before the top slice; prefix sums and running extremes give their means and spans.
    sum_w, sum_n = np.r_[0.0, np.cumsum(width)], np.r_[0, np.cumsum(count)]
    low_max, low_min = np.maximum.accumulate(width), np.minimum.accumulate(width)
    body = width[:-1][::-1]
    up_max = np.maximum.accumulate(body)[::-1]
    up_min = np.minimum.accumulate(body)[::-1]
    splits = [(j - gap, j) for gap in (1, 2) for j in range(2 + gap, m - 2)]
    e, j = (np.array(v, dtype=np.int64) for v in zip(*splits))
    jump = np.abs(sum_w[e] / e - (sum_w[m - 1] - sum_w[j]) / (m - 1 - j))
    spread = np.maximum(low_max[e - 1] - low_min[e - 1], up_max[j] - up_min[j])
    ok = (ids[j] - ids[e] == j - e) & (sum_n[e] >= least) & (sum_n[m] - sum_n[j] >= least) \
        & (jump >= tol) & (spread <= 0.5 * tol)
    if not np.any(ok):
        return None
    best = int(np.flatnonzero(ok)[np.argmax(jump[ok])])  # the largest jump, the first of ties
    end, up = int(e[best]), int(j[best])
    if seen is not None:
        # The narrower run's slices, and the wider run's extent across the view.
        wide_lo, wide_hi = lo[:end].min(), hi[:end].max()
        narrow = slice(up, m - 1)
        if width[:end].mean() < width[up:-1].mean():
            wide_lo, wide_hi = lo[up:-1].min(), hi[up:-1].max()
            narrow = slice(0, end)
        rows_in = np.isin(k, ids[narrow])
        if not _seen_past(points[rows_in], (normal, offset), across / norm,
                          (float(lo[narrow].max()), float(hi[narrow].min())),
                          (float(wide_lo), float(wide_hi)), tol, seen):
            return None
    return float(ids[end]) * tol


def _seen_past(run: NDArray[np.float64], support: Plane, across: NDArray[np.float64],
               narrow: tuple[float, float], wide: tuple[float, float], tol: float,
               seen: tuple[SceneView, int, float]) -> bool:
    """Tell whether the sensor sees past a narrower run of slices where a wider would reach.

    ``run`` (m, 3) [m] are the narrower run's points; probes at their median height and
    depth along ``across`` (3,) (unit, horizontal) between its extent ``narrow`` and the
    wider run's ``wide`` [m], more than ``tol`` [m] beyond the narrower one's. Seen past
    when more probes see a return behind them (or none, inside the image) than one in
    front of them from another object: a body standing on a wider one shows the
    background beside it; an object in front hiding part of a body, itself.
    """
    view, oid, cell = seen
    normal, offset = support
    ahead = np.cross(across, normal)
    lift = float(np.median(run @ normal))
    depth = float(np.median(run @ ahead))
    xs = np.concatenate([np.arange(wide[0], narrow[0] - tol, 0.5 * tol),
                         np.arange(narrow[1] + tol, wide[1], 0.5 * tol)])
    if len(xs) == 0:
        return False
    probes = np.outer(xs, across) + depth * ahead + lift * normal
    r_t = np.linalg.norm(probes, axis=1)
    got = view.returns(probes, cell / max(float(np.median(r_t)), np.finfo(float).tiny))
    band = tol + cell
    in_front = (got.nearest < got.ranges - band) & (got.nearest_label != oid)
    past = ~np.isfinite(got.nearest) & ~view.beyond_image(probes) | \
        (got.nearest > got.ranges + band)
    return int(np.count_nonzero(past)) > int(np.count_nonzero(in_front))


def _share_within(outline: NDArray[np.float64], points: NDArray[np.float64]) -> float:
    """Share of ``points`` (m, 2) within the convex hull of ``outline`` (k, 2); 1 if flat."""
    try:
        hull = Delaunay(outline[ConvexHull(outline).vertices])
    except QhullError:  # the rising points on a line: no footprint to stand beside
        return 1.0
    return float(np.mean(hull.find_simplex(points) >= 0))
