"""Surface type of a face (paper eqs. 1-6) and principal curvatures (core.surface_type)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from geomodel_ros.core.faces import estimate_normals
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.surface_type import covariance_features, face_feature, principal_curvatures

SPACING = 0.001  # sample spacing of the synthetic faces [m]
OFFSET = np.array([0.01, -0.02, 0.5])  # in front of the sensor


# ---------------------------------------------------------------------------------------
# Synthetic faces (regular samplings, then shifted in front of the sensor)
# ---------------------------------------------------------------------------------------


def rectangle(a, b, sp=SPACING):
    u = np.arange(-a / 2, a / 2 + 1e-9, sp)
    v = np.arange(-b / 2, b / 2 + 1e-9, sp)
    uu, vv = np.meshgrid(u, v)
    return np.c_[uu.ravel(), vv.ravel(), np.zeros(uu.size)] + OFFSET


def cylinder_patch(r, arc, height=0.06, sp=SPACING):
    """Patch of a cylinder of radius r (axis = y) spanning ``arc`` [rad] around the axis."""
    th = np.arange(-arc / 2, arc / 2, sp / r)
    y = np.arange(-height / 2, height / 2, sp)
    tt, yy = np.meshgrid(th, y)
    return np.c_[r * np.sin(tt.ravel()), yy.ravel(), r * np.cos(tt.ravel())] + OFFSET


def sphere_cap(r, polar, sp=SPACING):
    """Cap of a sphere of radius r up to the polar angle ``polar`` [rad]."""
    rings = []
    for phi in np.arange(0.0, polar, sp / r):
        k = max(1, int(2 * np.pi * r * np.sin(phi) / sp))
        th = np.arange(k) * 2 * np.pi / k
        rings.append(np.c_[r * np.sin(phi) * np.cos(th), r * np.sin(phi) * np.sin(th),
                           np.full(k, r * np.cos(phi))])
    return np.vstack(rings) + OFFSET


# ---------------------------------------------------------------------------------------
# Eqs. 1-4 on exact configurations
# ---------------------------------------------------------------------------------------


def test_flat_disc_is_planar():
    """Rings of 8 i points: l1 = l2 exactly, l3 = 0 -> P = 1, C = 0, cf = 1."""
    rings = [np.zeros((1, 3))]
    for i in range(1, 26):
        th = np.arange(8 * i) * 2 * np.pi / (8 * i)
        rings.append(0.001 * i * np.c_[np.cos(th), np.sin(th), np.zeros_like(th)])
    planarity, curvature, cf = covariance_features(np.vstack(rings) + OFFSET)
    assert planarity == pytest.approx(1.0, abs=1e-6)
    assert curvature == pytest.approx(0.0, abs=1e-6)
    assert cf == pytest.approx(1.0, abs=1e-6)
    assert cf == pytest.approx(planarity * (1 - curvature) ** 2)


def test_line_has_no_planarity():
    pts = OFFSET + np.linspace(0, 0.1, 50)[:, None] * np.array([1.0, 2.0, 3.0])
    planarity, curvature, cf = covariance_features(pts)
    assert planarity == pytest.approx(0.0, abs=1e-6)
    assert curvature == pytest.approx(0.0, abs=1e-6)
    assert cf == pytest.approx(0.0, abs=1e-6)


def test_rectangle_corners_give_side_ratio():
    """Four corners of an a x b rectangle: sqrt(l1) : sqrt(l2) = a : b, l3 = 0 -> P = b / a."""
    a, b = 0.08, 0.02
    pts = OFFSET + np.array([[a, b, 0], [-a, b, 0], [a, -b, 0], [-a, -b, 0]]) / 2
    planarity, curvature, cf = covariance_features(pts)
    assert planarity == pytest.approx(b / a, rel=1e-9)
    assert curvature == pytest.approx(0.0, abs=1e-9)
    assert cf == pytest.approx(b / a, rel=1e-9)


def test_cube_corners_are_isotropic():
    """Eight cube corners: l1 = l2 = l3 -> P = 0, C = 1/3, cf = 0."""
    pts = OFFSET + 0.01 * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    planarity, curvature, cf = covariance_features(pts)
    assert planarity == pytest.approx(0.0, abs=1e-9)
    assert curvature == pytest.approx(1.0 / 3.0, rel=1e-9)
    assert cf == pytest.approx(0.0, abs=1e-9)


def test_identical_points_give_zeros():
    assert covariance_features(np.tile(OFFSET, (10, 1))) == (0.0, 0.0, 0.0)


# ---------------------------------------------------------------------------------------
# Eq. 6 weights
# ---------------------------------------------------------------------------------------


def test_cf_weights_noise_free():
    assert ModelingParams(noise_amplitude=0.0).cf_weights == (1.0, 0.0, 0.0)


def test_cf_weights_at_one_millimetre():
    e = math.exp(-1.0)
    w = ModelingParams(noise_amplitude=0.001).cf_weights
    assert w == pytest.approx((e, 1 - e, 2 * (1 - e)), rel=1e-12)


def test_cf_weights_default_noise_amplitude():
    """Default t = 0.5 mm -> w = (e^-0.5, 1 - e^-0.5, 2 (1 - e^-0.5))."""
    e = math.exp(-0.5)
    assert ModelingParams().cf_weights == pytest.approx((e, 1 - e, 2 * (1 - e)), rel=1e-12)


# ---------------------------------------------------------------------------------------
# face_feature: planar vs curved, noise levels 0 and 0.3 mm, default CF_th
# ---------------------------------------------------------------------------------------

PLANAR = {
    "square40": lambda: rectangle(0.04, 0.04),
    "square60": lambda: rectangle(0.06, 0.06),
    "square100": lambda: rectangle(0.10, 0.10),
    "rect120x50": lambda: rectangle(0.12, 0.05),
    "rect200x80": lambda: rectangle(0.20, 0.08),
}
CURVED = {
    "cyl20_half": lambda: cylinder_patch(0.020, math.pi),
    "cyl35_half": lambda: cylinder_patch(0.035, math.pi),
    "cyl50_half": lambda: cylinder_patch(0.050, math.pi),
    "cyl20_quarter": lambda: cylinder_patch(0.020, math.pi / 2),
    "cap25": lambda: sphere_cap(0.025, math.pi / 3),
    "cap35": lambda: sphere_cap(0.035, math.pi / 3),
    "cap50": lambda: sphere_cap(0.050, math.pi / 3),
}
NOISE = (0.0, 0.0003)

# At t = 0, eq. 6 gives w = (1, 0, 0): only the smallest radius (1/6 of the face's width)
# counts, where a curved face is still nearly flat (CF ~ 1 - rho / (2 r) ~ 0.84-0.9).
T0_LIMITATION = ("paper eq. 6: with noise amplitude t = 0 the weights are (1, 0, 0), so CF is "
                 "the smallest-radius cf alone and curved faces score 0.84-0.91 > CF_th 0.82; "
                 "the pipeline's plane-fit verification of each face corrects these")


def _feature(pts, sigma, seed):
    params = ModelingParams(noise_amplitude=sigma)
    if sigma > 0:
        pts = pts + np.random.default_rng(seed).normal(0, sigma, pts.shape)
    return face_feature(pts, params.cf_weights, params.cf_threshold, params.cf_radius_fraction)


@pytest.mark.parametrize("sigma", NOISE)
@pytest.mark.parametrize("name", list(PLANAR))
def test_planar_faces_are_planar(name, sigma):
    feat = _feature(PLANAR[name](), sigma, seed=11)
    assert feat.planar is True
    assert ModelingParams().cf_threshold < feat.cf_total <= 1.0


def _curved_cases():
    for sigma in NOISE:
        for name in CURVED:
            marks = [pytest.mark.xfail(strict=True, reason=T0_LIMITATION)] if sigma == 0 else []
            yield pytest.param(name, sigma, id=f"{name}-{sigma}", marks=marks)


@pytest.mark.parametrize(("name", "sigma"), list(_curved_cases()))
def test_curved_faces_are_curved(name, sigma):
    feat = _feature(CURVED[name](), sigma, seed=12)
    assert feat.planar is False
    assert 0.0 <= feat.cf_total <= ModelingParams().cf_threshold


def test_face_feature_geometry_of_a_rectangle():
    """Centre = face point nearest the centroid; min width = short side; radii (1, 2, 3)/3."""
    pts = rectangle(0.12, 0.05)
    feat = face_feature(pts, (1.0, 0.0, 0.0), 0.82, 0.5)
    np.testing.assert_allclose(feat.center, OFFSET, atol=1e-12)
    assert feat.min_width == pytest.approx(0.05, abs=1e-9)
    np.testing.assert_allclose(feat.radii, 0.05 * 0.5 * np.array([1, 2, 3]) / 3, rtol=1e-9)
    np.testing.assert_allclose(feat.cf, 1.0, atol=1.5e-3)   # a 1 mm grid: 1e-3 measured
    assert feat.cf_total == pytest.approx(feat.cf[0])


def test_face_feature_normalises_by_the_weight_sum():
    pts = cylinder_patch(0.03, math.pi)
    w = (0.2, 0.3, 0.5)
    feat = face_feature(pts, w, 0.82, 0.5)
    assert np.all(np.isfinite(feat.cf))
    expected = float(np.dot(w, feat.cf) / sum(w))
    assert feat.cf_total == pytest.approx(expected, rel=1e-12)
    # Scaling all weights does not change the normalised CF.
    scaled = face_feature(pts, tuple(10 * x for x in w), 0.82, 0.5)
    assert scaled.cf_total == pytest.approx(feat.cf_total, rel=1e-12)


def test_face_feature_too_few_points_per_radius_gives_zero():
    """Fewer than 5 points in every neighbourhood: cf NaN, CF = 0, curved."""
    pts = OFFSET + np.array([[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0.01, 0.01, 0.0]])
    feat = face_feature(pts, (1.0, 0.0, 0.0), 0.82, 0.5)
    assert np.all(np.isnan(feat.cf))
    assert feat.cf_total == 0.0
    assert feat.planar is False



def test_face_feature_of_a_single_point_has_no_width():
    """One point (a millimetre object far away can leave one per face): width 0, curved."""
    feat = face_feature(OFFSET + np.zeros((1, 3)), (1.0, 0.0, 0.0), 0.82, 0.5)
    assert feat.min_width == 0.0 and np.all(feat.radii == 0.0)
    assert np.all(np.isnan(feat.cf)) and feat.cf_total == 0.0 and feat.planar is False
    assert np.array_equal(feat.center, OFFSET + np.zeros(3))

# ---------------------------------------------------------------------------------------
# Principal curvatures
# ---------------------------------------------------------------------------------------


def _curvatures(pts, k=16):
    normals, _, neighbors = estimate_normals(pts, k)
    return principal_curvatures(pts, normals, neighbors)


@pytest.mark.parametrize("r", [0.02, 0.03, 0.05])
def test_sphere_curvatures_are_both_one_over_r(r):
    k_max, k_min = _curvatures(sphere_cap(r, math.pi / 2))
    # Quadric fits on a 1 mm grid: within 0.4 % of 1/r at r = 20 mm (measured), less above.
    for k in (k_max, k_min):
        assert np.median(np.abs(k)) == pytest.approx(1.0 / r, rel=0.005)
        assert np.percentile(np.abs(k), 5) > 0.995 / r
        assert np.percentile(np.abs(k), 95) < 1.005 / r
    assert np.all(np.abs(k_max) >= np.abs(k_min))


@pytest.mark.parametrize("r", [0.02, 0.03, 0.05])
def test_cylinder_curvatures_are_one_over_r_and_zero(r):
    k_max, k_min = _curvatures(cylinder_patch(r, math.pi))
    assert np.median(np.abs(k_max)) == pytest.approx(1.0 / r, rel=0.005)
    assert np.percentile(np.abs(k_max), 5) > 0.995 / r
    assert np.percentile(np.abs(k_min), 95) < 0.001 / r   # 3e-4 / r measured at r = 20 mm
    assert np.all(np.abs(k_max) >= np.abs(k_min))


def test_curvatures_at_chosen_rows_are_those_points_own():
    # A cylinder r 30 mm: curvatures of every 7th point only, each its own quadric fit,
    # exactly as with all the points; 1/r and 0 there as everywhere.
    r = 0.03
    pts = cylinder_patch(r, math.pi)
    normals, _, neighbors = estimate_normals(pts, 16)
    rows = np.arange(3, len(pts), 7)
    k_max, k_min = principal_curvatures(pts, normals, neighbors, rows)
    all_max, all_min = principal_curvatures(pts, normals, neighbors)
    assert k_max.shape == k_min.shape == rows.shape
    assert np.array_equal(k_max, all_max[rows]) and np.array_equal(k_min, all_min[rows])
    assert np.median(np.abs(k_max)) == pytest.approx(1.0 / r, rel=0.005)
    assert np.percentile(np.abs(k_min), 95) < 0.001 / r
    # No rows: nothing computed, no error.
    empty = principal_curvatures(pts, normals, neighbors, np.zeros(0, dtype=np.int64))
    assert empty[0].shape == empty[1].shape == (0,)


def test_plane_curvatures_are_zero():
    k_max, k_min = _curvatures(rectangle(0.05, 0.04))
    assert np.abs(k_max).max() < 1e-9
    assert np.abs(k_min).max() < 1e-9


def _ring_cross_and_corners():
    """Build a flat face whose smallest CF neighbourhood is empty but the others not.

    In the face's plane (z = 0, shifted by OFFSET): the centre c = (0, 0); a ring of 8
    points at radius 15 mm (every 45 deg); two points (+-25 mm, 0); four corners
    (+-60 mm, +-30 mm). Everything is symmetric about c, so the centroid is c, the first
    principal axis is x and the minimum width is the y extent, 60 mm. With the radius
    fraction 0.5 the radii are 10, 20 and 30 mm:

    * r1 = 10 mm holds c only (1 point < 5): cf1 = NaN;
    * r2 = 20 mm holds c and the ring (9 points): sum x^2 = sum y^2 = 4 rho^2, so
      l1 = l2, l3 = 0: P = 1, C = 0, cf2 = 1;
    * r3 = 30 mm adds the two points on x: sum x^2 = 4 rho^2 + 2 a^2, sum y^2 = 4 rho^2,
      l3 = 0: cf3 = P = sqrt(4 rho^2 / (4 rho^2 + 2 a^2)); the corners (67 mm) stay out.
    """
    rho, a = 0.015, 0.025
    th = np.arange(8) * np.pi / 4
    plane = np.vstack([[[0.0, 0.0]], rho * np.c_[np.cos(th), np.sin(th)], [[a, 0], [-a, 0]],
                       [[0.06, 0.03], [-0.06, 0.03], [0.06, -0.03], [-0.06, -0.03]]])
    cf3 = math.sqrt(4 * rho ** 2 / (4 * rho ** 2 + 2 * a ** 2))
    return np.c_[plane, np.zeros(len(plane))] + OFFSET, cf3


def test_cf_is_normalised_by_the_weights_of_valid_radii_only():
    pts, cf3 = _ring_cross_and_corners()
    w = ModelingParams().cf_weights   # (e^-0.5, 1 - e^-0.5, 2 (1 - e^-0.5))
    feat = face_feature(pts, w, 0.7, 0.5)
    np.testing.assert_allclose(feat.radii, [0.01, 0.02, 0.03], rtol=1e-12)
    assert np.isnan(feat.cf[0])
    np.testing.assert_allclose(feat.cf[1:], [1.0, cf3], rtol=1e-12)
    # w1 drops out with its NaN radius: (w2 * 1 + w3 * cf3) / (w2 + w3) = (1 + 2 cf3) / 3.
    assert feat.cf_total == pytest.approx((1 + 2 * cf3) / 3, rel=1e-12)   # 0.7647
    assert feat.planar is True   # above CF_th = 0.7 (dividing by all weights gives 0.505)
    # The same face with all weight on the empty radius has no valid neighbourhood.
    empty = face_feature(pts, (1.0, 0.0, 0.0), 0.7, 0.5)
    assert empty.cf_total == 0.0 and empty.planar is False
