"""RANSAC fitters and least-squares refinement (geomodel_ros.core.ransac) on seeded primitives.

Every cloud is sampled on a known primitive with exact normals, disturbed by Gaussian
noise, and 30 % of its points are replaced by uniform outliers at known indices.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from geomodel_ros.core.ransac import (
    MODELS,
    ConeModel,
    CylinderBatch,
    CylinderModel,
    PlaneModel,
    SphereModel,
    fit_plane_svd,
    ransac,
    refine,
)

N = 600
SIGMA = 0.0005  # [m]
THRESHOLD = 0.002  # inlier distance [m]
NORMAL_THRESHOLD = 0.5  # [rad]
#: Known outlier indices: 30 % of the points.
OUTLIERS = np.sort(np.r_[np.arange(0, N, 10), np.arange(3, N, 10), np.arange(7, N, 10)])
SEEDS = (0, 1, 2)


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _frame(z):
    """Return unit x, y perpendicular to the unit z, and z."""
    z = _unit(z)
    helper = np.array([1.0, 0, 0]) if abs(z[0]) < 0.9 else np.array([0, 1.0, 0])
    x = _unit(np.cross(helper, z))
    return x, np.cross(z, x), z


def _angle_deg(a, b, signed=False):
    c = float(np.dot(_unit(a), _unit(b)))
    return math.degrees(math.acos(np.clip(c if signed else abs(c), -1.0, 1.0)))


def _add_noise_and_outliers(p, n, rng, center, half_box):
    p = p + rng.normal(0.0, SIGMA, p.shape)
    n = n.copy()
    p[OUTLIERS] = center + rng.uniform(-half_box, half_box, (len(OUTLIERS), 3))
    n[OUTLIERS] = _unit(rng.normal(size=(len(OUTLIERS), 3)))
    return p, n


def _run(model_cls, p, n, seed, iterations=500):
    fit = ransac(model_cls, p, n, THRESHOLD, NORMAL_THRESHOLD, iterations, 0.995,
                 np.random.default_rng(seed))
    assert fit is not None
    assert isinstance(fit.model, model_cls)
    return fit, refine(fit.model, p, THRESHOLD)


def _check_support(fit):
    """Outliers mostly rejected, the surface's points mostly accepted."""
    inlier_mask = np.ones(N, dtype=bool)
    inlier_mask[OUTLIERS] = False
    assert fit.inliers.shape == (N,)
    assert fit.inliers[OUTLIERS].mean() < 0.1
    assert fit.inliers[inlier_mask].mean() > 0.95
    assert fit.inlier_ratio == pytest.approx(fit.inliers.mean())
    assert 0.0 < fit.rmse < 2 * SIGMA   # Gaussian noise within +-4 sigma: rmse ~ sigma


@pytest.mark.parametrize("seed", SEEDS)
def test_plane_recovered_despite_outliers(seed):
    rng = np.random.default_rng(seed)
    normal = _unit([0.2, -0.5, -1.0])
    x, y, _ = _frame(normal)
    c0 = np.array([0.02, -0.01, 0.6])
    uv = rng.uniform(-0.1, 0.1, (N, 2))
    p = c0 + uv[:, :1] * x + uv[:, 1:] * y
    p, n = _add_noise_and_outliers(p, np.tile(normal, (N, 1)), rng, c0, 0.1)
    fit, model = _run(PlaneModel, p, n, seed)
    _check_support(fit)
    assert _angle_deg(model.normal, normal) < 0.12
    # Signed offset of the true plane n . x + d = 0 in the fitted normal's orientation.
    d_true = -float(np.sign(model.normal @ normal) * (normal @ c0))
    assert model.d == pytest.approx(d_true, abs=0.0005)
    assert np.linalg.norm(model.normal) == pytest.approx(1.0)


@pytest.mark.parametrize("seed", SEEDS)
def test_sphere_recovered_despite_outliers(seed):
    rng = np.random.default_rng(seed)
    c0, r = np.array([0.02, 0.01, 0.55]), 0.03
    d = _unit(rng.normal(size=(N, 3)))
    d[:, 2] = -np.abs(d[:, 2])  # the half facing the sensor at the origin
    p, n = _add_noise_and_outliers(c0 + r * d, d, rng, c0, 0.05)
    fit, model = _run(SphereModel, p, n, seed)
    _check_support(fit)
    assert model.radius == pytest.approx(r, abs=0.0003)
    assert np.linalg.norm(model.center - c0) < 0.0005


@pytest.mark.parametrize("seed", SEEDS)
def test_cylinder_recovered_despite_outliers(seed):
    rng = np.random.default_rng(seed)
    c0, axis, r = np.array([0.1, -0.05, 0.6]), _unit([0.3, 0.2, 1.0]), 0.03
    x, y, z = _frame(axis)
    th = rng.uniform(0, 2 * np.pi, N)
    t = rng.uniform(-0.05, 0.05, N)
    radial = np.cos(th)[:, None] * x + np.sin(th)[:, None] * y
    p, n = _add_noise_and_outliers(c0 + r * radial + t[:, None] * z, radial, rng, c0, 0.08)
    fit, model = _run(CylinderModel, p, n, seed)
    _check_support(fit)
    assert model.radius == pytest.approx(r, abs=0.0002)
    assert _angle_deg(model.axis, axis) < 0.4
    assert np.linalg.norm(model.axis) == pytest.approx(1.0)
    # The fitted axis line passes within 0.15 mm of the true centre.
    v = c0 - model.point
    assert np.linalg.norm(v - (v @ model.axis) * model.axis) < 0.00015


@pytest.mark.parametrize("seed", SEEDS)
def test_cone_recovered_despite_outliers(seed):
    rng = np.random.default_rng(seed)
    apex, axis, half = np.array([0.0, 0.05, 0.5]), _unit([0.1, -0.3, 1.0]), math.radians(25)
    x, y, z = _frame(axis)  # z = apex -> base (ConeModel's convention)
    th = rng.uniform(0, 2 * np.pi, N)
    s = rng.uniform(0.01, 0.06, N)  # distance from the apex along the axis [m]
    radial = np.cos(th)[:, None] * x + np.sin(th)[:, None] * y
    p = apex + s[:, None] * z + (s * math.tan(half))[:, None] * radial
    normal = _unit(radial * math.cos(half) - z * math.sin(half))
    p, n = _add_noise_and_outliers(p, normal, rng, apex + 0.035 * axis, 0.06)
    fit, model = _run(ConeModel, p, n, seed, iterations=1000)
    _check_support(fit)
    assert math.degrees(model.half_angle) == pytest.approx(25.0, abs=0.5)
    # Signed: the axis must point from the apex into the cone.
    assert _angle_deg(model.axis, axis, signed=True) < 0.7
    assert np.linalg.norm(model.apex - apex) < 0.001


@pytest.mark.parametrize("seed", SEEDS)
def test_refined_cylinder_radius_not_biased_by_noise(seed):
    """Noise of 2 mm on r = 20 mm: an algebraic fit drifts towards sqrt(r^2 + sigma^2)."""
    rng = np.random.default_rng(seed)
    r, sigma, m = 0.02, 0.002, 2000
    x, y, z = _frame([0.0, 0.0, 1.0])
    th = rng.uniform(0, 2 * np.pi, m)
    t = rng.uniform(-0.05, 0.05, m)
    radial = np.cos(th)[:, None] * x + np.sin(th)[:, None] * y
    p = np.array([0.0, 0.0, 0.5]) + r * radial + t[:, None] * z + rng.normal(0, sigma, (m, 3))
    fit = ransac(CylinderModel, p, radial, 4 * sigma, 0.8, 500, 0.995, np.random.default_rng(seed))
    assert fit is not None
    model = refine(fit.model, p, 4 * sigma)
    assert model.radius == pytest.approx(r, abs=0.0003)
    assert _angle_deg(model.axis, z) < 0.6


def test_refine_plane_equals_total_least_squares_on_inliers():
    rng = np.random.default_rng(4)
    p = np.c_[rng.uniform(-0.1, 0.1, (200, 2)), 0.5 + rng.normal(0, SIGMA, 200)]
    p[:20, 2] += 0.05  # far outliers
    start = PlaneModel(np.array([0.0, 0.0, 1.0]), -0.5)
    model = refine(start, p, THRESHOLD)
    expected = fit_plane_svd(p[20:])
    sign = np.sign(model.normal @ expected.normal)
    np.testing.assert_allclose(model.normal * sign, expected.normal, atol=1e-12)
    assert model.d * sign == pytest.approx(expected.d, abs=1e-12)


# ---------------------------------------------------------------------------------------
# Degenerate samples and too few points
# ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(MODELS))
def test_collinear_points_with_parallel_normals_give_no_model(name):
    t = np.random.default_rng(0).uniform(0, 0.1, (50, 1))
    p = np.array([0.0, 0.0, 0.5]) + t * np.array([1.0, 2.0, 3.0])
    n = np.tile([0.0, 0.0, 1.0], (50, 1))
    fit = ransac(MODELS[name], p, n, THRESHOLD, NORMAL_THRESHOLD, 200, 0.99,
                 np.random.default_rng(0))
    assert fit is None


@pytest.mark.parametrize("name", ["sphere", "cylinder", "cone"])
def test_parallel_normals_give_no_curved_model(name):
    rng = np.random.default_rng(1)
    p = rng.normal(0, 0.05, (50, 3)) + [0, 0, 0.5]
    n = np.tile([0.0, 0.0, 1.0], (50, 1))
    fit = ransac(MODELS[name], p, n, THRESHOLD, NORMAL_THRESHOLD, 200, 0.99,
                 np.random.default_rng(0))
    assert fit is None


@pytest.mark.parametrize("name", list(MODELS))
def test_duplicate_points_give_no_model(name):
    p = np.tile([0.01, 0.02, 0.5], (40, 1))
    n = np.tile(_unit([0.1, 0.2, -1.0]), (40, 1))
    fit = ransac(MODELS[name], p, n, THRESHOLD, NORMAL_THRESHOLD, 200, 0.99,
                 np.random.default_rng(0))
    assert fit is None


def _collinear_with_random_normals():
    rng = np.random.default_rng(2)
    t = rng.uniform(0, 0.1, (60, 1))
    p = np.array([0.0, 0.0, 0.5]) + t * np.array([1.0, 0.0, 0.0])
    return p, _unit(rng.normal(size=(60, 3)))


@pytest.mark.parametrize("name", ["plane", "cone"])
def test_collinear_points_with_random_normals_give_no_plane_or_cone(name):
    """No plane: no three non-collinear points.

    No cone: the unit directions from any apex to three collinear points lie in one plane
    through the apex, so the axis normal to their tips is perpendicular to all three (a
    90 deg half-angle).
    """
    p, n = _collinear_with_random_normals()
    assert ransac(MODELS[name], p, n, THRESHOLD, NORMAL_THRESHOLD, 200, 0.99,
                  np.random.default_rng(0)) is None


@pytest.mark.parametrize("name", ["sphere", "cylinder"])
def test_collinear_points_with_random_normals_give_a_finite_model(name):
    """Random normals give non-degenerate samples: some (poor) finite model is returned."""
    p, n = _collinear_with_random_normals()
    fit = ransac(MODELS[name], p, n, THRESHOLD, NORMAL_THRESHOLD, 200, 0.99,
                 np.random.default_rng(0))
    assert isinstance(fit.model, MODELS[name])
    assert fit.inliers.shape == (60,)
    assert fit.inlier_ratio == fit.inliers.mean()
    values = [np.ravel(v) for v in vars(fit.model).values()]
    assert np.all(np.isfinite(np.concatenate(values)))
    assert np.all(np.isfinite(fit.model.distance(p)))


@pytest.mark.parametrize("name", list(MODELS))
def test_too_few_points_return_none(name):
    cls = MODELS[name]
    rng = np.random.default_rng(3)
    for m in range(cls.sample_size + 1):  # 0 .. sample_size points
        p = rng.normal(0, 0.05, (m, 3)) + [0, 0, 0.5]
        n = _unit(rng.normal(size=(m, 3))) if m else np.zeros((0, 3))
        assert ransac(cls, p, n, THRESHOLD, NORMAL_THRESHOLD, 100, 0.99,
                      np.random.default_rng(0)) is None


def test_ransac_is_reproducible_with_a_seed():
    rng = np.random.default_rng(5)
    c0, r = np.array([0.0, 0.0, 0.5]), 0.03
    d = _unit(rng.normal(size=(N, 3)))
    p, n = _add_noise_and_outliers(c0 + r * d, d, rng, c0, 0.05)
    a = ransac(SphereModel, p, n, THRESHOLD, NORMAL_THRESHOLD, 300, 0.995, np.random.default_rng(9))
    b = ransac(SphereModel, p, n, THRESHOLD, NORMAL_THRESHOLD, 300, 0.995, np.random.default_rng(9))
    np.testing.assert_array_equal(a.model.center, b.model.center)
    assert a.model.radius == b.model.radius
    np.testing.assert_array_equal(a.inliers, b.inliers)


def test_accept_callback_filters_hypotheses():
    """Radius bounds that exclude the true sphere leave no acceptable hypothesis."""
    rng = np.random.default_rng(6)
    d = _unit(rng.normal(size=(200, 3)))
    p = np.array([0.0, 0.0, 0.5]) + 0.03 * d
    fit = ransac(SphereModel, p, d, THRESHOLD, NORMAL_THRESHOLD, 200, 0.99,
                 np.random.default_rng(0), accept=lambda m: m.radius > 0.1)
    assert fit is None


@pytest.mark.parametrize("model", [
    SphereModel(np.array([0.01, -0.02, 0.5]), 0.03),
    CylinderModel(np.array([0.0, 0.01, 0.45]), _unit([0.2, 0.9, -0.3]), 0.04),
    ConeModel(np.array([0.02, 0.0, 0.4]), _unit([-0.1, 0.3, 0.95]), 0.5),
], ids=["sphere", "cylinder", "cone"])
def test_analytic_jacobian_matches_finite_differences(model):
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(200, 3)) * 0.05 + np.array([0.0, 0.0, 0.45])
    x0 = model.to_vector()
    for x in (x0, x0 + rng.normal(size=len(x0)) * 1e-2):
        jac = model.jacobian(x, pts)
        num = np.empty_like(jac)
        for i in range(len(x)):
            h = np.zeros(len(x))
            h[i] = 1e-7
            num[:, i] = (model.from_vector(x + h).distance(pts)
                         - model.from_vector(x - h).distance(pts)) / 2e-7
        np.testing.assert_allclose(jac, num, atol=1e-6, rtol=1e-5)


# ---------------------------------------------------------------------------------------
# Minimal solvers and residuals on exact samples (no noise): the geometry must be exact.
# Points on a cylinder of radius R about the line C + s A, A not along a coordinate axis.
# ---------------------------------------------------------------------------------------

CYL_C, CYL_A, CYL_R = np.array([0.1, -0.05, 0.6]), _unit([0.3, 0.2, 1.0]), 0.03


def _on_cylinder(theta, s):
    """Points at angles ``theta`` [rad] and axial positions ``s`` [m], with their normals."""
    x, y, z = _frame(CYL_A)
    radial = np.cos(theta)[..., None] * x + np.sin(theta)[..., None] * y
    return CYL_C + CYL_R * radial + np.asarray(s)[..., None] * z, radial


def test_cylinder_hypotheses_from_exact_samples_are_exact():
    """Two points at different heights along the axis give exactly the cylinder.

    The second point's axial offset must be removed before the normal lines are
    intersected: otherwise the radius comes out as sqrt(R^2 + (h/2)^2).
    """
    rng = np.random.default_rng(0)
    th0 = rng.uniform(0, 2 * np.pi, 50)
    theta = np.c_[th0, th0 + rng.uniform(0.3, np.pi - 0.3, 50)]   # normals 17-163 deg apart
    s = np.c_[rng.uniform(-0.1, -0.02, 50), rng.uniform(0.02, 0.1, 50)]   # heights apart
    p, n = _on_cylinder(theta, s)
    h = CylinderModel.hypotheses(p, n)
    assert len(h.radius) == 50   # no sample is degenerate
    np.testing.assert_allclose(h.radius, CYL_R, rtol=1e-11, atol=0)
    np.testing.assert_allclose(np.abs(h.axis @ CYL_A), 1.0, rtol=0, atol=1e-12)
    off = h.point - CYL_C
    off -= (off @ CYL_A)[:, None] * CYL_A
    np.testing.assert_array_less(np.linalg.norm(off, axis=1), 1e-12)   # point on the axis
    model = CylinderModel.from_batch(h, 7)
    assert model.radius == h.radius[7]
    np.testing.assert_array_equal(model.axis, h.axis[7])


def test_cylinder_residuals_use_the_radial_direction():
    """Exact points with exact normals: distance 0 and |cos| 1 far along the axis.

    A normal along the axis (a cap's normal) is perpendicular to the mantle's normal:
    |cos| 0 wherever the point lies along the axis.
    """
    theta = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    s = np.linspace(-0.2, 0.2, 40)   # up to ~7 radii from the axis point
    p, n = _on_cylinder(theta, s)
    batch = CylinderBatch(CYL_C[None], CYL_A[None], np.array([CYL_R]))
    dist, cos = CylinderModel.residuals(batch, np.ascontiguousarray(p.T), np.ascontiguousarray(n.T))
    assert dist.shape == cos.shape == (1, 40)
    np.testing.assert_allclose(dist, 0.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(cos, 1.0, rtol=0, atol=1e-14)
    caps = np.tile(CYL_A, (40, 1))
    _, cos_cap = CylinderModel.residuals(batch, np.ascontiguousarray(p.T),
                                         np.ascontiguousarray(caps.T))
    np.testing.assert_allclose(cos_cap, 0.0, rtol=0, atol=1e-14)


def test_cylinder_ransac_on_exact_points_far_along_the_axis_keeps_them_all():
    """Every exact point is an inlier, however far along the axis it lies."""
    rng = np.random.default_rng(1)
    p, n = _on_cylinder(rng.uniform(0, 2 * np.pi, 300), rng.uniform(-0.3, 0.3, 300))
    fit = ransac(CylinderModel, p, n, THRESHOLD, NORMAL_THRESHOLD, 200, 0.995,
                 np.random.default_rng(0))
    assert fit.inliers.all()
    assert fit.model.radius == pytest.approx(CYL_R, rel=1e-10)
