"""Fitting unit of a cone: side by RANSAC, verified up to its apex, sized from the apex."""

from __future__ import annotations

import math
from functools import partial

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.fitting.axial import axial_extent, verified_side
from geomodel_ros.core.fitting.completion import complete_axial
from geomodel_ros.core.fitting.curved import CurvedFit, axis_prior, fit_curved
from geomodel_ros.core.fitting.measure import bulk_reach, side_bulk
from geomodel_ros.core.fitting.result import FitOutcome, FitTask, Fitted, Rejected
from geomodel_ros.core.fitting.verify import (axes_within, axis_within, check_apex,
                                              check_axial_sunk_in_support, check_bulk_length,
                                              check_bulk_reach, check_radius)
from geomodel_ros.core.geometry import frame_with_z
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import Primitive, PrimitiveType
from geomodel_ros.core.ransac import ConeBatch, ConeModel, HypothesisTest

__all__ = ["MAX_CONE_HALF_ANGLE", "CONE_TOO_NARROW", "least_half_angle", "cone_hypothesis_ok",
           "cone_hypotheses_ok", "cone_test", "fit_cone"]

CONE = PrimitiveType.CONE
#: RANSAC takes no cone hypothesis flatter than this half-angle [rad] (80 deg).
MAX_CONE_HALF_ANGLE = 1.4
#: End of the reason of a side rejected as narrower than the least half-angle.
CONE_TOO_NARROW = "too small"


def cone_hypothesis_ok(model: ConeModel, params: ModelingParams,
                       prior: NDArray[np.float64] | None) -> bool:
    """Return True for a RANSAC cone of allowed half-angle whose axis follows ``prior``."""
    return (params.min_cone_half_angle <= model.half_angle <= MAX_CONE_HALF_ANGLE
            and axis_within(model.axis, prior, params.angle_tolerance))


def cone_hypotheses_ok(h: ConeBatch, params: ModelingParams,
                       prior: NDArray[np.float64] | None) -> NDArray[np.bool_]:
    """Return :func:`cone_hypothesis_ok` of each of the B rows of ``h``: (B,) bool."""
    return ((params.min_cone_half_angle <= h.half_angle) & (h.half_angle <= MAX_CONE_HALF_ANGLE)
            & axes_within(h.axis, prior, params.angle_tolerance))


def cone_test(params: ModelingParams, prior: NDArray[np.float64] | None) -> HypothesisTest:
    """Return the RANSAC hypothesis test of a cone (one model, or a batch at once)."""
    return HypothesisTest(partial(cone_hypothesis_ok, params=params, prior=prior),
                          partial(cone_hypotheses_ok, params=params, prior=prior))


def _verified_side(task: FitTask, side: CurvedFit, prior: NDArray[np.float64] | None,
                   kind: PrimitiveType
                   ) -> tuple[list, NDArray[np.int64], NDArray[np.float64],
                              NDArray[np.float64]] | Rejected:
    """Caps, each point's surface, the side's and the profile's points, once the checks pass."""
    checked = verified_side(task, side, prior, kind, side.model.apex)
    if isinstance(checked, Rejected):
        return checked
    if side.model.half_angle < least_half_angle(task.cloud.params, kind):
        return Rejected(kind, f"{kind} half-angle {math.degrees(side.model.half_angle):.1f} deg "
                              f"{CONE_TOO_NARROW}")
    return checked


def least_half_angle(params: ModelingParams, kind: PrimitiveType) -> float:
    """Return the least half-angle [rad] of a side accepted as ``kind`` (cone or frustum).

    ``min_cone_half_angle``, except for a frustum under a measured noise (``noise_model =
    auto``): its taper is then judged against the noise by the frustum unit itself
    (:func:`~.frustum.taper_minimum`), which leaves a side whose taper is within the noise
    to the cylinder and accepts a slightly tapered cup that no cylinder holds.
    """
    if kind is PrimitiveType.FRUSTUM and params.noise_model == "auto":
        return 0.0
    return params.min_cone_half_angle


def fit_cone_side(task: FitTask, kind: PrimitiveType
                  ) -> tuple[CurvedFit, float, float, NDArray[np.float64],
                             NDArray[np.float64]] | FitOutcome:
    """Fit and verify the conical side of ``task.cloud`` for a cone or a frustum (``kind``).

    The axis follows ``task.axis_prior`` or else the main planar face's normal, if any.
    Returns the side's fit, its extent ``lo``, ``hi`` [m] along the axis from the apex
    (caps and supports closing the ends, :func:`~.axial.axial_extent`), the side's
    points (K, 3) [m] and those of them whose normals do not run along the axis (the
    profile's: a flat end's points within the side's band left out), or the rejection.
    """
    cloud = task.cloud
    prior = axis_prior(task)
    side = fit_curved(cloud, kind, ConeModel, cone_test(cloud.params, prior), with_caps=True)
    if not isinstance(side, CurvedFit):
        return side
    checked = _verified_side(task, side, prior, kind)
    if isinstance(checked, Rejected):
        return checked
    caps, nearest, side_points, profile = checked
    lo, hi = axial_extent(cloud, side_points, caps, nearest, side.model.apex, side.model.axis)
    return side, lo, hi, side_points, profile


def _sized(task: FitTask, model: ConeModel, lo: float, hi: float,
           side_points: NDArray[np.float64]) -> float | Rejected:
    """Size the base radius [m] of a cone whose points run from ``lo`` to ``hi`` from its apex.

    ``side_points`` (n, 3): the side's points the extent was taken from.
    """
    cloud = task.cloud
    bad = check_bulk_length(hi - lo, side_bulk(cloud.points, side_points, model.axis), CONE)
    if bad:
        return bad
    height = hi if hi > 0 else 0.0  # apex at t = 0, base at the far end
    bad = check_apex(lo, height)
    if bad:
        return bad
    radius = height * math.tan(model.half_angle)
    bad = check_radius(radius, cloud.params, CONE) or \
        check_bulk_reach(radius, bulk_reach(cloud.points, model.apex, model.axis))
    return bad if bad else radius


def fit_cone(task: FitTask) -> FitOutcome:
    """Fit a cone to the curved faces of ``task.cloud``; a planar face may close its base.

    The axis follows ``task.axis_prior`` or else the main planar face's normal, if any.
    Returns a cone whose z points from the base to the apex, or the rejection (also when
    it would reach into the support its object stands on,
    :func:`~.verify.check_axial_sunk_in_support`).
    """
    fitted = fit_cone_side(task, CONE)
    if not isinstance(fitted, tuple):
        return fitted
    side, lo, hi, side_points, _ = fitted
    model = side.model
    radius = _sized(task, model, lo, hi, side_points)
    if isinstance(radius, Rejected):
        return radius
    completed: tuple[str, ...] = ()
    # After the checks of the points: a completed base lies beyond them. Only the base
    # (the end away from the apex) is completed, with the side's taper.
    slope = math.tan(model.half_angle)
    _, base, end = complete_axial(task.cloud, model.apex, model.axis, 0.0, lo, hi, slope, (1,))
    if end is not None and not check_radius(base * slope, task.cloud.params, CONE):
        hi, radius, completed = base, base * slope, ("radius", "height")
    height = hi if hi > 0 else 0.0
    center = model.apex + model.axis * height / 2
    bad = check_axial_sunk_in_support(center, model.axis, height, (0.0, radius), task.cloud, CONE)
    if bad:
        return bad
    prim = Primitive(task.cloud.oid, CONE, center, frame_with_z(-model.axis),
                     {"radius": float(radius), "height": float(height)},
                     len(task.cloud.points), side.rmse, completed=completed)
    return Fitted(prim, "cone verified")
