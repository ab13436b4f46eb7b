"""Fitting unit of a sphere: RANSAC on the curved faces, verified, sized by its radius."""

from __future__ import annotations

from functools import partial

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.fitting.curved import CurvedFit, fit_curved
from geomodel_ros.core.fitting.result import FitOutcome, FitTask, Fitted
from geomodel_ros.core.fitting.verify import (check_noise_scatter, check_radius,
                                              check_seen_through, check_sunk_in_support)
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import Primitive, PrimitiveType
from geomodel_ros.core.ransac import HypothesisTest, SphereBatch, SphereModel

__all__ = ["fit_sphere", "sphere_hypothesis_ok", "sphere_hypotheses_ok", "sphere_test"]

SPHERE = PrimitiveType.SPHERE


def sphere_hypothesis_ok(model: SphereModel, params: ModelingParams) -> bool:
    """Return True when a RANSAC sphere's radius is within [min_radius, max_radius]."""
    return params.min_radius <= model.radius <= params.max_radius


def sphere_hypotheses_ok(h: SphereBatch, params: ModelingParams) -> NDArray[np.bool_]:
    """Return :func:`sphere_hypothesis_ok` of each of the B rows of ``h``: (B,) bool."""
    return (params.min_radius <= h.radius) & (h.radius <= params.max_radius)


def sphere_test(params: ModelingParams) -> HypothesisTest:
    """Return the RANSAC hypothesis test of a sphere (one model, or a batch at once)."""
    return HypothesisTest(partial(sphere_hypothesis_ok, params=params),
                          partial(sphere_hypotheses_ok, params=params))


def fit_sphere(task: FitTask) -> FitOutcome:
    """Fit a sphere to the curved faces of ``task.cloud`` (a sphere has no axis).

    Returns a sphere with identity rotation, or the rejection (also when it would reach
    into the support its object stands on, :func:`~.verify.check_sunk_in_support`, or when
    the sensor saw past its visible cap, :func:`~.verify.check_seen_through`).
    """
    cloud = task.cloud
    side = fit_curved(cloud, SPHERE, SphereModel, sphere_test(cloud.params), with_caps=False)
    if not isinstance(side, CurvedFit):
        return side
    model = side.model
    bad = check_radius(model.radius, cloud.params, SPHERE) or \
        check_noise_scatter(cloud.points, model.distance, cloud.params, SPHERE) or \
        check_sunk_in_support(model.center, float(model.radius), cloud, SPHERE) or \
        check_seen_through(model.center, float(model.radius), cloud, SPHERE)
    if bad:
        return bad
    prim = Primitive(cloud.oid, SPHERE, model.center.copy(), np.eye(3),
                     {"radius": float(model.radius)}, len(cloud.points), side.rmse)
    return Fitted(prim, "sphere verified")
