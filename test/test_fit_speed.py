"""Shortcuts of the fits against their plain definitions (identical results, less work).

Modules: core.ransac (the least-squares evaluation cache) and core.fitting.strategies
(the box's truncated costs shared by its round rival's first look and verdict).

By hand: the Levenberg-Marquardt minimisation of a model's point distances is a
function of the function and Jacobian values it is given; evaluating both afresh at
every request (the plain definition) must give the same vector, bit for bit, as serving
repeated requests at the same parameter vector from the last evaluation.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import leastsq

from geomodel_ros.core import ransac
from geomodel_ros.core.fitting import strategies
from geomodel_ros.core.primitives import PrimitiveType
from geomodel_ros.core.ransac import ConeModel, CylinderModel, SphereModel

from test_fitting_units import cloud_of, cylinder_points


def plain_least_squares(ref, sub):
    """Return ref's least-squares model on ``sub`` (3, M), every evaluation made afresh."""
    calls = {"f": 0, "j": 0}

    def fun(x):
        calls["f"] += 1
        m = ref.from_vector(x)
        return m.distance_from(m.parts_t(sub))

    def jac(x):
        calls["j"] += 1
        m = ref.from_vector(x)
        return ref.jacobian_from(x, m, m.parts_t(sub))

    tol = ransac._LSQ_TOLERANCE
    x, *_ = leastsq(fun, ref.to_vector(), Dfun=jac, full_output=True, col_deriv=True,
                    ftol=tol, xtol=tol, gtol=tol, maxfev=ransac.MAX_EVALUATIONS)
    return ref.from_vector(x), calls


def noisy_surface(kind, rng):
    """Return (3, M) points within 1 mm of a known surface and a start 5 mm / 3 deg off."""
    n = 600
    if kind == "sphere":
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1)[:, None]
        pts = 0.05 * d + [0.1, 0.0, 1.0]
        start = SphereModel(np.array([0.105, 0.0, 1.0]), 0.047)
    elif kind == "cylinder":
        a, z = rng.uniform(0, 2 * np.pi, n), rng.uniform(-0.06, 0.06, n)
        pts = np.c_[0.04 * np.cos(a), 0.04 * np.sin(a), z] + [0.0, 0.0, 1.0]
        tilt = np.array([np.sin(np.radians(3)), 0.0, np.cos(np.radians(3))])
        start = CylinderModel(np.array([0.005, 0.0, 1.0]), tilt, 0.037)
    else:  # a cone of half-angle 20 deg, apex at z = 1 m, opening towards +z
        a, z = rng.uniform(0, 2 * np.pi, n), rng.uniform(0.05, 0.15, n)
        r = z * np.tan(np.radians(20))
        pts = np.c_[r * np.cos(a), r * np.sin(a), z + 1.0]
        tilt = np.array([np.sin(np.radians(3)), 0.0, np.cos(np.radians(3))])
        start = ConeModel(np.array([0.0, 0.005, 1.0]), tilt, np.radians(22))
    pts = pts + rng.normal(0.0, 0.001, pts.shape)
    return np.ascontiguousarray(pts.T), start


@pytest.mark.parametrize("kind", ["sphere", "cylinder", "cone"])
def test_cached_least_squares_equals_the_plain_minimisation_bit_for_bit(kind):
    sub, start = noisy_surface(kind, np.random.default_rng(3))
    plain, calls = plain_least_squares(start, sub)
    fast = ransac._least_squares(start, sub)
    assert calls["f"] > 2 and calls["j"] > 1  # the minimisation really iterated
    for name in ("center", "point", "apex", "axis", "radius", "half_angle"):
        if hasattr(plain, name):
            assert np.array_equal(np.asarray(getattr(fast, name)),
                                  np.asarray(getattr(plain, name))), name
    # ... and it moved from the start towards the true surface (not a no-op).
    assert np.sqrt(np.mean(fast.distance_t(sub) ** 2)) < \
        0.5 * np.sqrt(np.mean(start.distance_t(sub) ** 2))


def test_the_cache_computes_the_models_parts_once_per_distinct_vector(monkeypatch):
    # MINPACK asks for the Jacobian where it has just evaluated the function (and
    # leastsq evaluates both at x0 twice): the parts are computed once per distinct x.
    sub, start = noisy_surface("cylinder", np.random.default_rng(4))
    seen = []
    original = CylinderModel.parts_t

    def counted(self, pt):
        seen.append((self.point.tobytes(), self.axis.tobytes(), self.radius))
        return original(self, pt)

    monkeypatch.setattr(CylinderModel, "parts_t", counted)
    ransac._least_squares(start, sub)
    cached = len(seen)
    assert cached == len(set(seen))  # never the same model's parts twice
    _, calls = plain_least_squares(start, sub)
    assert len(seen) - cached == calls["f"] + calls["j"]  # the plain run: once per request
    assert cached < calls["f"] + calls["j"]


def test_the_box_costs_are_computed_once_for_the_rivals_first_look_and_verdict(monkeypatch):
    # A cylinder r 40 mm against a stand-in box costing 0.5 per point: the rival's first
    # look beats it on average, so it is refitted and judged; the box is costed once,
    # and the costs returned are exactly those of the plain definition.
    cloud = cloud_of(cylinder_points())
    box = object()
    costed = []
    plain = strategies.truncated_costs

    def costs(prim, c):
        costed.append(prim is box)
        return np.full(len(strategies.every_kth(c.points, strategies.RIVAL_SAMPLE)), 0.5) \
            if prim is box else plain(prim, c)

    monkeypatch.setattr(strategies, "truncated_costs", costs)
    found = strategies.round_rival(cloud, box)
    assert found is not None and found[1].type is PrimitiveType.CYLINDER
    assert costed.count(True) == 1
    assert np.array_equal(found[3], np.full(len(found[2]), 0.5))
    assert len(found[3]) == len(found[2])  # one cost per compared (blocked) point


def _random_axes(rng, b, prior, tol):
    """Return (B, 3) unit axes: a third within ``tol`` of ±prior, a third just beyond, rest any."""
    ang = np.r_[rng.uniform(0, 0.99 * tol, b // 3), rng.uniform(1.01 * tol, 2 * tol, b // 3),
                rng.uniform(0, np.pi, b - 2 * (b // 3))]
    perp = np.cross(prior, [1.0, 0.0, 0.0])
    perp /= np.linalg.norm(perp)
    sign = rng.choice([-1.0, 1.0], b)[:, None]
    return sign * (np.cos(ang)[:, None] * prior + np.sin(ang)[:, None] * perp)


@pytest.mark.parametrize("with_prior", [True, False])
def test_batch_hypothesis_tests_equal_the_per_model_tests_row_by_row(with_prior):
    from geomodel_ros.core.fitting.cone import MAX_CONE_HALF_ANGLE, cone_test
    from geomodel_ros.core.fitting.cylinder import cylinder_test
    from geomodel_ros.core.fitting.sphere import sphere_test
    from geomodel_ros.core.params import ModelingParams
    from geomodel_ros.core.ransac import ConeBatch, CylinderBatch, SphereBatch
    params = ModelingParams()
    rng = np.random.default_rng(5)
    b = 300
    prior = np.array([0.0, 0.6, 0.8]) if with_prior else None
    axes = _random_axes(rng, b, np.array([0.0, 0.6, 0.8]), params.angle_tolerance)
    # Radii and half-angles below, at, inside, at and above their bounds, and NaN.
    radius = np.r_[rng.uniform(0, 2 * params.max_radius, b - 5), params.min_radius,
                   params.max_radius, 0.5 * params.min_radius, np.nan, 3 * params.max_radius]
    half = np.r_[rng.uniform(0, 1.6, b - 4), params.min_cone_half_angle, MAX_CONE_HALF_ANGLE,
                 np.nan, 1.5]
    point = rng.normal(size=(b, 3))
    batches = [(cylinder_test(params, prior), CylinderBatch(point, axes, radius), CylinderModel),
               (cone_test(params, prior), ConeBatch(point, axes, half), ConeModel),
               (sphere_test(params), SphereBatch(point, radius), SphereModel)]
    for test, h, cls in batches:
        rows = test.rows(h)
        one = np.array([test(cls.from_batch(h, i)) for i in range(b)])
        assert rows.dtype == bool and rows.shape == (b,)
        assert np.array_equal(rows, one), cls.__name__
        assert 0 < rows.sum() < b  # both verdicts occur: the comparison is not vacuous
    # The bounds themselves are allowed, NaN never is.
    assert cylinder_test(params, None).rows(CylinderBatch(point[:3], axes[:3], np.array(
        [params.min_radius, params.max_radius, np.nan]))).tolist() == [True, True, False]


def test_ransac_draws_the_same_model_with_the_batch_test_as_with_the_per_model_test():
    from geomodel_ros.core.fitting.cylinder import cylinder_test
    from geomodel_ros.core.params import ModelingParams
    params = ModelingParams()
    sub, _ = noisy_surface("cylinder", np.random.default_rng(6))
    pts = sub.T
    normals = np.c_[pts[:, 0], pts[:, 1], np.zeros(len(pts))]
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    prior = np.array([0.0, 0.0, 1.0])
    test = cylinder_test(params, prior)
    fits = [ransac.ransac(CylinderModel, pts, normals, 0.002, 0.3, 200, 0.99,
                          np.random.default_rng(7), accept=accept)
            for accept in (test, test.one)]
    a, b = fits
    assert a is not None and b is not None
    assert np.array_equal(a.model.point, b.model.point)
    assert np.array_equal(a.model.axis, b.model.axis) and a.model.radius == b.model.radius
    assert np.array_equal(a.inliers, b.inliers)
    assert a.model.radius == pytest.approx(0.04, abs=0.003)  # the surface really was found
