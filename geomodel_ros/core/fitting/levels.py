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
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import ConvexHull, Delaunay, QhullError

from geomodel_ros.core.fitting.cloud import ObjectFace, Plane
from geomodel_ros.core.geometry import perpendicular_basis
from geomodel_ros.core.params import ModelingParams

__all__ = ["LEVEL_INSIDE_SHARE", "Level", "object_levels", "support_below"]

#: A level face's points within the footprint of what rises beyond it: at most this
#: share for that to stand on the face's body.
LEVEL_INSIDE_SHARE = 0.5
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


def support_below(points: NDArray[np.float64], supports: tuple[Plane, ...] | list[Plane],
                  threshold: float) -> Plane | None:
    """Return the nearest of the ``supports`` that ``points`` (n, 3) [m] stand above, or None.

    Nearest by the points' mean height; above it: all but :data:`BELOW_SHARE` of the
    points on its sensor side or within ``threshold`` [m] of it.
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
                  supports: tuple[Plane, ...] | list[Plane], params: ModelingParams
                  ) -> tuple[Level, ...]:
    """Return the levels of an object's ``points`` (n, 3) [m] (see the module docstring).

    ``faces`` are its faces (:func:`~.cloud.build_faces`), ``supports`` the scene's support
    planes, ``params`` the object's (its ``ransac_threshold`` at its range). Levels within
    a threshold of one found before are left out; lowest first.
    """
    least = params.seg_min_cluster_points
    if not supports or len(points) < 2 * least:
        return ()
    thr = params.ransac_threshold
    cos_tol = math.cos(params.angle_tolerance)
    flats = [f for f in faces if f.info.planar and len(f.points) >= least]
    # Only a support some flat face parallels can be the one below a level.
    below = support_below(points, [(n, d) for n, d in supports if any(
        abs(float(f.info.normal @ n)) >= cos_tol for f in flats)], thr)
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
                any(abs(level - seen) <= thr for seen in levels):
            continue
        if flat is None:
            e1, e2 = perpendicular_basis(normal)
            flat = np.stack([points @ e1, points @ e2], axis=1)
        if _share_within(flat[above], flat[face.points]) <= LEVEL_INSIDE_SHARE:
            levels.append(level)
    return tuple(Level(normal, float(offset), h) for h in sorted(levels))


def _share_within(outline: NDArray[np.float64], points: NDArray[np.float64]) -> float:
    """Share of ``points`` (m, 2) within the convex hull of ``outline`` (k, 2); 1 if flat."""
    try:
        hull = Delaunay(outline[ConvexHull(outline).vertices])
    except QhullError:  # the rising points on a line: no footprint to stand beside
        return 1.0
    return float(np.mean(hull.find_simplex(points) >= 0))
