"""Fitting unit of a cuboid (paper 3.2.2): face planes, box axes, extents per axis."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core import obb
from geomodel_ros.core.fastmath import row_norms, take_rows
from geomodel_ros.core.fitting.cloud import ObjectCloud
from geomodel_ros.core.fitting.completion import complete_box
from geomodel_ros.core.fitting.measure import nearest_surface, rms, without_strays
from geomodel_ros.core.fitting.plane import RAY_SHIFT_FACTOR, plane_from_face
from geomodel_ros.core.fitting.result import FitOutcome, FitTask, Fitted
from geomodel_ros.core.fitting.verify import (OUTLIER_FACTOR, check_coverage, check_inlier_ratio,
                                              check_thickness)
from geomodel_ros.core.primitives import DIMENSION_NAMES, Primitive, PrimitiveType
from geomodel_ros.core.ransac import PlaneModel, refine

__all__ = ["fit_cuboid"]

CUBOID = PrimitiveType.CUBOID
#: A point whose depth along its viewing ray differs from its face's plane by more than
#: this many RANSAC thresholds is no noisy sample of that face: a mixed pixel past a
#: silhouette, or a neighbouring surface (a carton's gable) within the sizing band.
#: Moved onto the plane along a slanted ray it would land beyond the face's edge; it
#: takes no part in the sizing. Two bands, not one: a sample's own depth noise (one
#: band) plus the fitted plane's tilt error, which a ray meeting the face obliquely
#: lengthens at the face's far end (at one band, a Kinect box's top seen at a grazing
#: angle under kinect.yaml's fixed threshold lost 6 mm of its height).
RAY_DEPTH_FACTOR = 2.0
#: When more than this share of a face's points fail that test, the rays do not fit the
#: face (the cloud is not seen from the origin): none of its points are left out.
MAX_RAY_OUTLIER_SHARE = 0.5
#: A face's own points decide what is a stray along it (:func:`_kept_values`) when it has
#: at least this many: a plane of fewer (a sliver, a few flying pixels) says nothing.
MIN_SIDE_POINTS = 20


def _face_planes(cloud: ObjectCloud, faces: list[int],
                 normals: NDArray[np.float64] | None = None
                 ) -> tuple[list[PlaneModel], float]:
    """Refine a plane on each of ``faces``; return them and the inlier ratio over all.

    With ``normals`` (len(faces), 3) the planes keep them (a box frame fixed beforehand)
    and only their offsets are refined.
    """
    thr = cloud.params.ransac_threshold
    planes, inlier_ok, inlier_all = [], 0, 0
    for k, i in enumerate(faces):
        f = cloud.faces[i]
        w = cloud.wc.points[f.working]
        if normals is None:
            model = refine(plane_from_face(f, w), w, thr)
            model = refine(model, cloud.sample(f.points), thr)
        else:
            model = _offset_refined(normals[k], w, thr)
            model = _offset_refined(normals[k], cloud.sample(f.points), thr, model)
        inlier_ok += int((np.abs(model.distance(w)) <= thr).sum())
        inlier_all += len(w)
        planes.append(model)
    return planes, inlier_ok / max(inlier_all, 1)


def _offset_refined(normal: NDArray[np.float64], points: NDArray[np.float64], thr: float,
                    start: PlaneModel | None = None) -> PlaneModel:
    """Return the plane of unit ``normal`` (3,) through the mean of ``points`` (n, 3) near it.

    The mean of the points within ``thr`` [m] of ``start`` (of the plane through their
    median without it).
    """
    h = points @ normal
    d = -float(np.median(h)) if start is None else start.d
    near = np.abs(h + d) <= thr
    return PlaneModel(normal, -float(h[near].mean()) if near.any() else d)


def _projections(cloud: ObjectCloud, planes: list[PlaneModel], nearest: NDArray[np.int64],
                 rot: NDArray[np.float64]
                 ) -> tuple[NDArray[np.float64], list[NDArray[np.float64]]]:
    """Box coordinates of the points on the faces, all (n, 3) and per face.

    With ``reproject_along_rays`` each point first moves along its viewing ray onto the
    plane of its ``nearest`` face, and points farther from it along their rays than
    :data:`RAY_DEPTH_FACTOR` RANSAC thresholds are left out (unless most of the face's
    are: :data:`MAX_RAY_OUTLIER_SHARE`).
    """
    params = cloud.params
    thr = params.ransac_threshold
    q = cloud.points.copy()
    used = nearest >= 0
    per_face = []
    for fi, model in enumerate(planes):
        sel = nearest == fi
        if params.reproject_along_rays:
            pts = take_rows(cloud.points, sel)
            # The points' heights over the plane and ranges serve the move and the offset.
            height, dist = pts @ model.normal, row_norms(pts)
            q[sel] = pts * obb.ray_scale_to_plane(height, dist, model.d,
                                                  RAY_SHIFT_FACTOR * thr)[:, None]
            idx = np.flatnonzero(sel)
            off = obb.ray_offset_from(height, dist, model.d) > RAY_DEPTH_FACTOR * thr
            if off.any() and np.mean(off) <= MAX_RAY_OUTLIER_SHARE:  # none off: none to drop
                used[idx[off]] = False
                sel[idx[off]] = False
        per_face.append(take_rows(q, sel) @ rot)
    return take_rows(q, used) @ rot, per_face


def _kept_values(values: NDArray[np.float64], side_values: list[NDArray[np.float64]]
                 ) -> NDArray[np.float64]:
    """``values`` (n,) [m] without strays, judged against the bulk and each face's own.

    Strays are judged on all of the box's projections together
    (:func:`~geomodel_ros.core.fitting.measure.without_strays`) and, separately, on the
    points of each face that runs along the axis (``side_values``, with at least
    MIN_SIDE_POINTS): a value within the range a face's own points keep is no stray. A
    side seen at a grazing angle holds a few per cent of a box's points spread along the
    view, which the bulk of a box seen face on (its front, a few millimetres deep) would
    cut; flying pixels beyond a face's end are strays of that face too.
    """
    vals = without_strays(values)
    lo, hi = float(vals.min()), float(vals.max())
    # Only a face with values beyond the bulk's range can widen it (most lie within).
    beyond = [fv for fv in side_values if len(fv) >= MIN_SIDE_POINTS and
              (float(fv.min()) < lo or float(fv.max()) > hi)]
    ranges = [(float(k.min()), float(k.max())) for k in map(without_strays, beyond)]
    wider = [(a, b) for a, b in ranges if a < lo or b > hi]
    if not wider:
        return vals
    keep = (values >= lo) & (values <= hi)
    for a, b in wider:
        keep |= (values >= a) & (values <= b)
    return values[keep]


def _axis_interval(cloud: ObjectCloud, values: NDArray[np.float64], axis: NDArray[np.float64],
                   face_values: list[NDArray[np.float64]],
                   side_values: list[NDArray[np.float64]]) -> tuple[float, float]:
    """Extent [m] of the box along one ``axis`` (3,) from the points' ``values`` (n,).

    ``face_values`` are the coordinates along it of the points of the faces
    perpendicular to it; their median closes the nearer end (unless they lie beyond the
    bulk: strays). ``side_values`` are those of the faces running along it
    (:func:`_kept_values`). A support plane closes an end no face closes.
    """
    reach = OUTLIER_FACTOR * cloud.params.ransac_threshold
    vals = _kept_values(values, side_values)
    vmin, vmax = float(vals.min()), float(vals.max())
    closed_lo, closed_hi = [], []
    for fv in face_values:
        pos = float(np.median(fv))
        if not vmin - reach <= pos <= vmax + reach:
            continue  # a face of strays beyond the bulk closes nothing
        (closed_hi if vmax - pos < pos - vmin else closed_lo).append(pos)
    s_lo, s_hi = cloud.support_ends(axis, np.zeros(3), vmin, vmax)
    return obb.interval(vals, cloud.spacing,
                        float(np.min(closed_lo)) if closed_lo else s_lo,
                        float(np.max(closed_hi)) if closed_hi else s_hi,
                        correct=cloud.params.edge_correction)


def _box_extent(cloud: ObjectCloud, planes: list[PlaneModel], assign: NDArray[np.int64],
                rot: NDArray[np.float64], nearest: NDArray[np.int64]
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Low and high ends (3,) [m] of the box in its axes ``rot`` (columns)."""
    proj, proj_faces = _projections(cloud, planes, nearest, rot)
    lo, hi = np.empty(3), np.empty(3)
    for a in range(3):
        face_values = [pf[:, a] for fi, pf in enumerate(proj_faces)
                       if assign[fi] == a and len(pf) > 0]
        side_values = [pf[:, a] for fi, pf in enumerate(proj_faces) if assign[fi] != a]
        lo[a], hi[a] = _axis_interval(cloud, np.ascontiguousarray(proj[:, a]), rot[:, a],
                                      face_values, side_values)
    return lo, hi


def fit_cuboid(task: FitTask) -> FitOutcome:
    """Fit a box to the faces of ``task.cloud`` whose axes ``task.axis_of_face`` gives.

    With ``task.axis_prior`` the box's axis 2 is that direction and its axes 0 and 1
    follow the side faces' normals about it (:func:`~geomodel_ros.core.obb.upright_axes`);
    the faces' planes keep the frame's normals. Without it the frame is the one nearest
    to every face's plane (:func:`~geomodel_ros.core.obb.orthonormalize_axes`).

    Sliver faces (axis -1) fit no axis; their points join the nearest real face. Every
    point goes to its nearest face plane (edge points may sit in the wrong face); points
    far from every face (flying pixels, strays) take no part in the sizing. An end hidden
    from the sensor above a support plane is completed down to it
    (:func:`~geomodel_ros.core.fitting.completion.complete_box`).
    """
    cloud, axis_of_face = task.cloud, task.axis_of_face
    keep = [i for i, a in enumerate(axis_of_face) if a >= 0]
    assign = np.asarray([axis_of_face[i] for i in keep], dtype=np.int64)
    weights = np.array([float(len(cloud.faces[i].working)) for i in keep])
    if task.axis_prior is None:
        planes, ratio = _face_planes(cloud, keep)
        rot = obb.orthonormalize_axes(np.array([m.normal for m in planes]), weights, assign)
    else:
        rot = obb.upright_axes(task.axis_prior, np.array([cloud.faces[i].info.normal
                                                          for i in keep]), weights, assign)
        planes, ratio = _face_planes(cloud, keep, rot[:, assign].T)
    bad = check_inlier_ratio(ratio, cloud.params, CUBOID)
    if bad:
        return bad
    nearest, nearest_dist = nearest_surface([np.abs(m.distance(cloud.points)) for m in planes])
    nearest[nearest_dist > OUTLIER_FACTOR * cloud.params.ransac_threshold] = -1
    bad = check_coverage(nearest >= 0, CUBOID)
    if bad:
        return bad
    lo, hi = _box_extent(cloud, planes, assign, rot, nearest)
    bad = check_thickness(hi - lo, cloud.params, CUBOID)
    if bad:
        return bad
    lo, hi, completed = complete_box(cloud, rot, lo, hi)
    ext = hi - lo
    names = DIMENSION_NAMES[CUBOID]
    prim = Primitive(cloud.oid, CUBOID, rot @ ((lo + hi) / 2), rot,
                     {name: float(e) for name, e in zip(names, ext)},
                     len(cloud.points), rms(nearest_dist),
                     completed=tuple(names[a] for a in sorted(completed)))
    return Fitted(prim, "cuboid verified")
