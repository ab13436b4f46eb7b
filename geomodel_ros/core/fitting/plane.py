"""Fitting unit of a plane (desk, wall, a box seen face on): fit, verify, size, orient."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core import obb
from geomodel_ros.core.fitting.cloud import ObjectCloud, ObjectFace
from geomodel_ros.core.fitting.measure import rms
from geomodel_ros.core.fitting.orient import longer_side_first, toward_sensor
from geomodel_ros.core.fitting.result import FitOutcome, FitTask, Fitted
from geomodel_ros.core.fitting.verify import OUTLIER_FACTOR, check_coverage, \
    check_inlier_ratio, check_noise_scatter
from geomodel_ros.core.geometry import frame_with_z
from geomodel_ros.core.primitives import Primitive, PrimitiveType
from geomodel_ros.core.ransac import PlaneModel, refine

__all__ = ["RAY_SHIFT_FACTOR", "plane_from_face", "fit_plane"]

#: Re-projection moves a point along its viewing ray onto a fitted plane by at most this
#: many RANSAC thresholds; a point farther away belongs to another surface and stays.
RAY_SHIFT_FACTOR = 4.0
#: Least-squares rounds of a plane on all of its object's full-resolution points, after
#: those on the working cloud (:func:`~geomodel_ros.core.ransac.refine`'s default).
FULL_REFINE_ROUNDS = 1

PLANE = PrimitiveType.PLANE


def plane_from_face(face: ObjectFace, working: NDArray[np.float64]) -> PlaneModel:
    """Start for a plane fit to a face's working points (m, 3).

    The face's own normal (robust to strays,
    :func:`~geomodel_ros.core.faces.face_plane`) through their median.
    """
    n = face.info.normal
    return PlaneModel(n, -float(np.median(working @ n)))


def _fit(cloud: ObjectCloud, main: int) -> tuple[PlaneModel, float]:
    """Plane refined on every face, started from the main face; its inlier ratio."""
    thr = cloud.params.ransac_threshold
    all_faces = list(range(len(cloud.faces)))
    widx = cloud.face_working(all_faces)
    model = plane_from_face(cloud.faces[main], cloud.wc.points[cloud.faces[main].working])
    model = refine(model, cloud.wc.points[widx], thr)
    model = refine(model, cloud.sample(cloud.face_points(all_faces)), thr,
                   rounds=FULL_REFINE_ROUNDS)
    ratio = float(np.mean(np.abs(model.distance(cloud.wc.points[widx])) <= thr))
    return model, ratio


def _rectangle(cloud: ObjectCloud, frame: NDArray[np.float64], d: float,
               coords: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]
               ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                          float, float]:
    """Minimum-area rectangle of the points on the plane: centre, x, y [m/unit], sizes.

    ``frame`` (3, 3) has the plane's normal (towards the sensor) as its third column,
    ``coords`` the points' (x, y, h) in it, ``d`` the plane's offset.
    """
    params = cloud.params
    x, y, h = coords
    n = frame[:, 2]
    if params.reproject_along_rays:
        # Moving a point along its ray scales all its coordinates alike.
        scale = obb.ray_scale_to_plane(h, np.sqrt(x * x + y * y + h * h), d,
                                       RAY_SHIFT_FACTOR * params.ransac_threshold)
        x *= scale
        y *= scale
    # Rectangle direction from the (re-projected) full-resolution outline.
    direction, _ = obb.min_area_rectangle(np.column_stack([x - x.mean(), y - y.mean()]))
    u = frame[:, :2] @ direction
    v = np.cross(n, u)  # = frame[:, :2] @ (-direction[1], direction[0])
    span_u = obb.interval(x * direction[0] + y * direction[1], cloud.spacing,
                          correct=params.edge_correction)
    span_v = obb.interval(y * direction[0] - x * direction[1], cloud.spacing,
                          correct=params.edge_correction)
    u, v, (lo_u, hi_u), (lo_v, hi_v) = longer_side_first(u, v, span_u, span_v)
    center = u * (lo_u + hi_u) / 2 + v * (lo_v + hi_v) / 2 + n * float(-d)  # n . x = -d
    return center, u, v, hi_u - lo_u, hi_v - lo_v


def fit_plane(task: FitTask) -> FitOutcome:
    """Fit a plane to all faces of ``cloud``, from ``task.main_face``; size its rectangle.

    Returns a plane whose z is the normal towards the sensor and x the longer side, or
    the rejection (too few inliers, too few of the object's points on it, or with a
    measured noise points that scatter about it beyond that noise,
    :func:`~.verify.check_noise_scatter`: a surface that bends within the inlier band,
    such as a torus far from the sensor, is no plane).
    """
    cloud = task.cloud
    model, ratio = _fit(cloud, task.main_face)
    bad = check_inlier_ratio(ratio, cloud.params, PLANE)
    if bad:
        return bad
    n = toward_sensor(model.normal, cloud.center)
    d = -model.d if n @ model.normal < 0 else model.d
    # Sizing uses the points on the model (flying pixels and strays do not stretch it),
    # in the plane's frame (x, y in the plane, h along the normal: one product).
    frame = frame_with_z(n)
    x, y, h = frame.T @ cloud.points.T
    on = np.abs(h + d) <= OUTLIER_FACTOR * cloud.params.ransac_threshold
    bad = check_coverage(on, PLANE) or \
        check_noise_scatter(cloud.points, model.distance, cloud.params, PLANE)
    if bad:
        return bad
    center, u, v, length, width = _rectangle(cloud, frame, d, (x[on], y[on], h[on]))
    rmse = rms(model.distance(cloud.sample(np.arange(len(cloud.points)))))
    prim = Primitive(cloud.oid, PLANE, center, np.column_stack([u, v, n]),
                     {"length": length, "width": width}, len(cloud.points), rmse)
    return Fitted(prim, "plane verified")
