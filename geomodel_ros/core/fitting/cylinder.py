"""Fitting unit of a cylinder: side by RANSAC, verified, closed by caps or supports, sized."""

from __future__ import annotations

from functools import partial

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core import obb
from geomodel_ros.core.fitting.axial import axial_extent, verified_side
from geomodel_ros.core.fitting.completion import complete_axial
from geomodel_ros.core.fitting.curved import CurvedFit, axis_prior, fit_curved
from geomodel_ros.core.fitting.measure import side_bulk
from geomodel_ros.core.fitting.orient import axis_toward_sensor
from geomodel_ros.core.fitting.result import FitOutcome, FitTask, Fitted, Rejected
from geomodel_ros.core.fitting.verify import (axes_within, axis_within,
                                              check_axial_sunk_in_support, check_bulk_length,
                                              check_radius)
from geomodel_ros.core.geometry import frame_with_z
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import Primitive, PrimitiveType
from geomodel_ros.core.ransac import CylinderBatch, CylinderModel, HypothesisTest

__all__ = ["CYLINDER_RAY_SHIFT_FACTOR", "cylinder_hypothesis_ok", "cylinder_hypotheses_ok",
           "cylinder_test", "fit_cylinder"]

CYLINDER = PrimitiveType.CYLINDER
#: Re-projection moves a side point along its viewing ray onto the cylinder by at most
#: this many RANSAC thresholds (rays graze the side near its silhouette, where a larger
#: move would take a point across to the far side).
CYLINDER_RAY_SHIFT_FACTOR = 1.0


def cylinder_hypothesis_ok(model: CylinderModel, params: ModelingParams,
                           prior: NDArray[np.float64] | None) -> bool:
    """Return True for a RANSAC cylinder of allowed radius whose axis follows ``prior``."""
    return (params.min_radius <= model.radius <= params.max_radius
            and axis_within(model.axis, prior, params.angle_tolerance))


def cylinder_hypotheses_ok(h: CylinderBatch, params: ModelingParams,
                           prior: NDArray[np.float64] | None) -> NDArray[np.bool_]:
    """Return :func:`cylinder_hypothesis_ok` of each of the B rows of ``h``: (B,) bool."""
    return ((params.min_radius <= h.radius) & (h.radius <= params.max_radius)
            & axes_within(h.axis, prior, params.angle_tolerance))


def cylinder_test(params: ModelingParams, prior: NDArray[np.float64] | None) -> HypothesisTest:
    """Return the RANSAC hypothesis test of a cylinder (one model, or a batch at once)."""
    return HypothesisTest(partial(cylinder_hypothesis_ok, params=params, prior=prior),
                          partial(cylinder_hypotheses_ok, params=params, prior=prior))


def _verified_side(task: FitTask, side: CurvedFit, prior: NDArray[np.float64] | None
                   ) -> tuple[list, NDArray[np.int64], NDArray[np.float64],
                              NDArray[np.float64]] | Rejected:
    """Caps, each point's surface, the side's and the profile's points, once the checks pass."""
    checked = verified_side(task, side, prior, CYLINDER, side.model.point)
    if isinstance(checked, Rejected):
        return checked
    return check_radius(side.model.radius, task.cloud.params, CYLINDER) or checked


def fit_cylinder(task: FitTask) -> FitOutcome:
    """Fit a cylinder to the curved faces of ``task.cloud``; planar faces may close its ends.

    The axis follows ``task.axis_prior`` or else the main planar face's normal, if any.
    Returns a cylinder whose z (its axis) points towards the sensor, or the rejection
    (also when it would reach into the support its object stands on,
    :func:`~.verify.check_axial_sunk_in_support`).
    """
    cloud, params = task.cloud, task.cloud.params
    prior = axis_prior(task)
    side = fit_curved(cloud, CYLINDER, CylinderModel, cylinder_test(params, prior),
                      with_caps=True)
    if not isinstance(side, CurvedFit):
        return side
    checked = _verified_side(task, side, prior)
    if isinstance(checked, Rejected):
        return checked
    caps, nearest, side_points, _ = checked
    model, axis = side.model, side.model.axis
    if params.reproject_along_rays:
        side_points = obb.ray_to_cylinder(side_points, model.point, axis, model.radius,
                                          CYLINDER_RAY_SHIFT_FACTOR * params.ransac_threshold)
    lo, hi = axial_extent(cloud, side_points, caps, nearest, model.point, axis)
    bad = check_bulk_length(hi - lo, side_bulk(cloud.points, side_points, axis), CYLINDER)
    if bad:
        return bad
    if hi - lo <= 0:
        return Rejected(CYLINDER, "cylinder has no height")
    # After the bulk check: a completed height is longer than the points' bulk.
    lo, hi, end = complete_axial(cloud, model.point, axis, model.radius, lo, hi)
    axis, lo, hi = axis_toward_sensor(axis, model.point, lo, hi)
    center = model.point + axis * (lo + hi) / 2
    radius = float(model.radius)
    bad = check_axial_sunk_in_support(center, axis, hi - lo, (radius, radius), cloud, CYLINDER)
    if bad:
        return bad
    prim = Primitive(cloud.oid, CYLINDER, center, frame_with_z(axis),
                     {"radius": float(model.radius), "height": float(hi - lo)},
                     len(cloud.points), side.rmse,
                     completed=("height",) if end is not None else ())
    return Fitted(prim, "cylinder verified")
