"""Moving points along their viewing rays onto a cylinder (core/obb.ray_to_cylinder).

Expectations are worked out by hand on a cylinder of radius 50 mm whose axis passes through
(0, 0, 0.5) m: the circle of the axis-free coordinates is met by the ray through the surface
point q = (0.03, ., 0.46) (a 3-4-5 triangle) at q itself (front side, s = 1) and at
s = 0.2475 / 0.2125 = 1.16471 (back side; the product of the roots of
0.2125 s^2 - 0.46 s + 0.2475 = 0).
"""

from __future__ import annotations

import numpy as np
import pytest

from geomodel_ros.core.obb import ray_to_cylinder

AXIS_POINT = np.array([0.0, 0.0, 0.5])
RADIUS = 0.05
#: Second root of the ray through the front point, s = c / a (first root s = 1).
BACK_SCALE = 0.2475 / 0.2125


@pytest.mark.parametrize("axis, front", [
    (np.array([0.0, 1.0, 0.0]), np.array([0.03, 0.0, 0.46])),    # upright cylinder
    (np.array([0.0, 1.0, 0.0]), np.array([0.03, 0.02, 0.46])),   # ... higher up its side
    (np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.03, 0.46])),    # lying across the view
    (np.array([1.0, 0.0, 0.0]), np.array([0.015, -0.03, 0.46])),
])
@pytest.mark.parametrize("along", [0.99, 1.01, 1.03])
def test_points_near_the_front_side_move_onto_the_front_side(axis, front, along):
    # With y (or x) along the axis the ray through ``front`` meets the circle at the same
    # scales whatever that coordinate is, because it is projected out.
    p = along * front
    moved = ray_to_cylinder(p[None], AXIS_POINT, axis, RADIUS, max_shift=0.1)[0]
    np.testing.assert_allclose(moved, front, rtol=0, atol=1e-12)
    # not the back side, which is within max_shift too
    assert np.linalg.norm(BACK_SCALE * front - p) < 0.1
    assert np.linalg.norm(moved - BACK_SCALE * front) > 0.07


def test_points_near_the_back_side_move_onto_the_back_side():
    front = np.array([0.03, 0.0, 0.46])
    p = 1.15 * front
    moved = ray_to_cylinder(p[None], AXIS_POINT, np.array([0.0, 1.0, 0.0]), RADIUS, 0.1)[0]
    np.testing.assert_allclose(moved, BACK_SCALE * front, rtol=0, atol=1e-12)


def test_points_stay_when_the_move_is_too_long_or_the_ray_misses():
    axis = np.array([0.0, 1.0, 0.0])
    front = np.array([0.03, 0.0, 0.46])
    far_off = 1.05 * front  # 23 mm behind the surface along its ray
    miss = np.array([0.2, 0.0, 0.5])  # the ray x = 0.4 z passes 0.19 m from the axis
    pts = np.stack([far_off, miss])
    moved = ray_to_cylinder(pts, AXIS_POINT, axis, RADIUS, max_shift=0.01)
    np.testing.assert_array_equal(moved, pts)
    # with a larger allowance the first one does move (onto the front side)
    moved = ray_to_cylinder(pts, AXIS_POINT, axis, RADIUS, max_shift=0.03)
    np.testing.assert_allclose(moved[0], front, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(moved[1], miss)
