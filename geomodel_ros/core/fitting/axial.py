"""Steps shared by the cylinder and cone units: caps, surface assignment, axial extent."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core import obb
from geomodel_ros.core.fastmath import centroid, take_rows
from geomodel_ros.core.fitting.cloud import ObjectCloud, ObjectFace, Plane
from geomodel_ros.core.fitting.curved import INNER_CAP_CONE_MARGIN, CurvedFit
from geomodel_ros.core.fitting.measure import (arc_span, nearest_surface, scatter_incidence,
                                               steep_arc_span)
from geomodel_ros.core.fitting.orient import toward_sensor
from geomodel_ros.core.fitting.plane import RAY_SHIFT_FACTOR
from geomodel_ros.core.fitting.result import FitTask, Rejected
from geomodel_ros.core.fitting.verify import (OUTLIER_FACTOR, check_arc, check_axis,
                                              check_coverage, check_noise_scatter,
                                              check_profile_bow)
from geomodel_ros.core.primitives import PrimitiveType
from geomodel_ros.core.ransac import ConeModel

__all__ = ["across_axis", "cap_facing", "seen_from_outside", "end_caps", "assign_to_surfaces",
           "axial_extent", "verified_side", "cap_rim_arc", "rim_arc", "RIM_SPACINGS",
           "CAP_OUTSIDE_SHARE"]

#: A cap's rim points lie within this many point spacings inside the side's surface (the
#: outermost samples of a steeply seen cap are within about one spacing of its edge) ...
RIM_SPACINGS = 2.0
#: ... and a cap confirms the side's circle only when at most this share of its points lie
#: outside the side by more than OUTLIER_FACTOR RANSAC thresholds (a box's top beside a
#: round sliver reaches beyond any circle through that sliver; a can's top does not).
CAP_OUTSIDE_SHARE = 0.05


def across_axis(cloud: ObjectCloud, axis: NDArray[np.float64]) -> list[ObjectFace]:
    """Return the object's planar faces perpendicular to ``axis`` (3,) (``angle_tolerance``)."""
    cos_tol = math.cos(cloud.params.angle_tolerance)
    return [f for f in cloud.faces if f.info.planar and abs(float(f.info.normal @ axis)) >= cos_tol]


def end_caps(cloud: ObjectCloud, side: CurvedFit) -> list[Plane]:
    """Planes that may close the side's ends.

    The object's planar faces perpendicular to the axis (within ``angle_tolerance``),
    then the side's inner caps.
    """
    return [(f.info.normal, f.info.offset) for f in across_axis(cloud, side.model.axis)] + \
        list(side.inner_caps)


def assign_to_surfaces(cloud: ObjectCloud, side: CurvedFit, caps: list[Plane],
                       kind: PrimitiveType) -> NDArray[np.int64] | Rejected:
    """Surface of each of the object's points (N,): 0 the side, i the i-th cap, -1 none.

    Each point goes to its nearest surface; points farther than OUTLIER_FACTOR RANSAC
    thresholds from all are outliers. Rejected when too few points lie on the surfaces.
    """
    dists = [np.abs(side.model.distance(cloud.points))] + \
        [np.abs(cloud.points @ normal + offset) for normal, offset in caps]
    nearest, nearest_dist = nearest_surface(dists)
    nearest[nearest_dist > OUTLIER_FACTOR * cloud.params.ransac_threshold] = -1
    bad = check_coverage(nearest >= 0, kind)
    return bad if bad else nearest


def _cap_positions(cloud: ObjectCloud, caps: list[Plane], nearest: NDArray[np.int64],
                   origin: NDArray[np.float64], axis: NDArray[np.float64]
                   ) -> tuple[list[NDArray[np.float64]], list[tuple[float, float]]]:
    """Axial coordinates of the caps' points; each cap's median position [m] and facing.

    The facing is the sign of the cap's normal towards the sensor along ``axis`` (3,).
    """
    parts, closed = [], []
    for ci, (normal, offset) in enumerate(caps, start=1):
        q = take_rows(cloud.points, nearest == ci)
        if len(q) == 0:
            continue
        if cloud.params.reproject_along_rays:
            q = obb.ray_to_plane(q, normal, offset,
                                 RAY_SHIFT_FACTOR * cloud.params.ransac_threshold)
        t_cap = (q - origin) @ axis
        parts.append(t_cap)
        closed.append((float(np.median(t_cap)), cap_facing(q, normal, axis)))
    return parts, closed


def cap_facing(q: NDArray[np.float64], normal: NDArray[np.float64],
               axis: NDArray[np.float64]) -> float:
    """Component along ``axis`` (3,) of a cap's normal towards the sensor (its points q)."""
    return float(toward_sensor(np.asarray(normal, dtype=np.float64), centroid(q)) @ axis)


def seen_from_outside(facing: float, high_end: bool) -> bool:
    """Whether a cap at the high (else low) end along the axis faces out of the solid.

    ``facing``: :func:`cap_facing`. A cap seen from inside (an open container's inner
    floor, through its opening) faces into the solid at its end and closes nothing.
    """
    return facing > 0 if high_end else facing < 0


def axial_extent(cloud: ObjectCloud, side_points: NDArray[np.float64], caps: list[Plane],
                 nearest: NDArray[np.int64], origin: NDArray[np.float64],
                 axis: NDArray[np.float64]) -> tuple[float, float]:
    """Extent [lo, hi] [m] of the object along ``axis`` (3,) from ``origin`` (3,).

    From the side's points (n, 3) and those of its caps (re-projected onto them along
    their rays); a cap seen from outside closes the end it is nearer to (one seen from
    inside, a cup's or bowl's inner floor, closes nothing), a support plane an end no cap
    closes, and open ends get the edge correction.
    """
    parts, closed = _cap_positions(cloud, caps, nearest, origin, axis)
    t_all = np.concatenate([(side_points - origin) @ axis] + parts)
    tmin, tmax = float(t_all.min()), float(t_all.max())
    # A cap closes the end it is nearer to only when it is seen from outside the solid
    # (its normal towards the sensor points out of that end): one seen from inside is an
    # open container's inner floor, above its hidden bottom.
    closed_lo = [c for c, facing in closed
                 if c - tmin < tmax - c and seen_from_outside(facing, high_end=False)]
    closed_hi = [c for c, facing in closed
                 if c - tmin >= tmax - c and seen_from_outside(facing, high_end=True)]
    s_lo, s_hi = cloud.support_ends(axis, origin, tmin, tmax)
    return obb.interval(t_all, cloud.spacing, min(closed_lo) if closed_lo else s_lo,
                        max(closed_hi) if closed_hi else s_hi,
                        correct=cloud.params.edge_correction)


def rim_arc(caps: list[NDArray[np.float64]], distance, axis: NDArray[np.float64],
            origin: NDArray[np.float64], spacing: float, threshold: float) -> float:
    """Angle [rad] round an axis that the rims of flat end caps confirm for a round side.

    ``caps``: each cap's points (k, 3) [m]; ``distance``: the side's signed distance
    (positive outside); the axis (3,) through ``origin`` (3,); the object's point
    ``spacing`` and the RANSAC ``threshold`` [m]. A cap's points lie inside the side's
    circle, and its rim points (within RIM_SPACINGS point spacings plus ``threshold``
    inside the surface) span the arc round the axis that the cap's edge confirms. A cap
    with more than CAP_OUTSIDE_SHARE of its points outside the side (by more than
    OUTLIER_FACTOR thresholds) has another outline and confirms nothing. The largest arc
    of the caps; 0 without one.
    """
    inner = RIM_SPACINGS * spacing + threshold
    outer = OUTLIER_FACTOR * threshold
    best = 0.0
    for q in caps:
        if len(q) == 0:
            continue
        d = distance(q)
        if np.count_nonzero(d > outer) > CAP_OUTSIDE_SHARE * len(q):
            continue
        best = max(best, arc_span(q[(d >= -inner) & (d <= outer)], origin, axis))
    return best


def cap_rim_arc(cloud: ObjectCloud, side: CurvedFit, nearest: NDArray[np.int64],
                n_caps: int, origin: NDArray[np.float64]) -> float:
    """Angle [rad] round the axis that the rims of the side's planar end caps confirm.

    A round side seen only at grazing incidence (a can from above: its side within 20 deg
    of edge-on) shows no arc steep enough to judge (:func:`~.measure.steep_arc_span`); its
    cap, seen steeply, does (:func:`rim_arc`). Only the object's own planar faces count
    (``n_caps`` of the caps, numbered 1.. in ``nearest``), not the side's inner caps.
    """
    caps = [take_rows(cloud.points, nearest == ci) for ci in range(1, n_caps + 1)]
    return rim_arc(caps, side.model.distance, side.model.axis, origin, cloud.spacing,
                   cloud.params.ransac_threshold)


def verified_side(task: FitTask, side: CurvedFit, prior: NDArray[np.float64] | None,
                  kind: PrimitiveType, origin: NDArray[np.float64]
                  ) -> tuple[list, NDArray[np.int64], NDArray[np.float64],
                             NDArray[np.float64]] | Rejected:
    """Check a round side's axis, cover its points by side and caps, check its arc.

    Parameters
    ----------
    task : FitTask
    side : CurvedFit
        The fitted side (cylinder or cone) with an ``axis``.
    prior : (3,) float64 array or None
        Axis the side must follow (within ``angle_tolerance``), if any.
    kind : PrimitiveType
        ``CYLINDER`` or ``CONE`` (named in the rejection reasons).
    origin : (3,) float64 array [m]
        A point on the axis (cylinder point, cone apex) for the arc span.

    Returns
    -------
    (caps, nearest, side_points, profile) -- the end caps, each point's surface (0 =
    side), the side's points (K, 3) [m] and those of them whose normals do not run along
    the axis (the profile's, :func:`_without_cap_normals`) -- or the first rejection.
    """
    cloud, model = task.cloud, side.model
    bad = check_axis(model.axis, prior, cloud.params, kind)
    if bad:
        return bad
    caps = end_caps(cloud, side)
    nearest = assign_to_surfaces(cloud, side, caps, kind)
    if isinstance(nearest, Rejected):
        return nearest
    side_points = take_rows(cloud.points, nearest == 0)
    # With the measured noise, only the points seen steeply enough count for the arc
    # (:func:`~.measure.steep_arc_span`); ``fixed`` keeps every point's arc.
    steep = cloud.params.noise_model == "auto"
    # The arc and the scatter test judge the same sample's incidences: computed once.
    cos = scatter_incidence(model.distance, side_points) if steep else None
    arc = steep_arc_span(side_points, origin, model.axis, model.distance, cos) if steep else \
        arc_span(side_points, origin, model.axis)
    if steep and arc < cloud.params.min_arc:
        own_caps = len(caps) - len(side.inner_caps)
        arc = max(arc, cap_rim_arc(cloud, side, nearest, own_caps, origin))
    bad = check_arc(arc, cloud.params, kind, steep) or \
        check_noise_scatter(side_points, model.distance, cloud.params, kind, cos)
    if bad:
        return bad
    profile = _without_cap_normals(cloud, nearest == 0, model)
    return check_profile_bow(profile, model, cloud, kind) or \
        (caps, nearest, side_points, profile)


def _without_cap_normals(cloud: ObjectCloud, side: NDArray[np.bool_], model
                         ) -> NDArray[np.float64]:
    """Return the ``side`` points of ``cloud`` (mask (N,)) whose normals do not run along the axis.

    Within the inlier band of a side lie points of a flat end it meets (an open
    container's inner floor where region growing joined it to the wall, under a real
    sensor's noise): their working points' normals lie within ``angle_tolerance`` of the
    axis, a side's do not (unless the side itself is a cone within twice the tolerance of
    flat, as for inner caps; then every side point is kept). A thinned first-look cloud
    keeps every point (its points are not the working cloud's).
    """
    params = cloud.params
    flat_side = isinstance(model, ConeModel) and \
        model.half_angle > math.pi / 2 - INNER_CAP_CONE_MARGIN * params.angle_tolerance
    if flat_side or len(cloud.wc.point_to_working) != len(cloud.points):
        return take_rows(cloud.points, side)
    rows = np.flatnonzero(side)
    normals = take_rows(cloud.wc.normals, cloud.wc.point_to_working[rows])
    along = np.abs(normals @ model.axis) >= math.cos(params.angle_tolerance)
    return take_rows(cloud.points, rows[~along])
