"""The cone refinement that tries the opposite opening (fitting.curved.refined).

A cone's least squares cannot pass through the cylinder (half-angle 0) to the other
opening: a RANSAC cone that opened the wrong way refines towards a far apex and a
half-angle near 0. Hand-built sides: a frustum's visible half started from the wrong
opening comes back with its own taper; a cylinder's side stays narrow (negative); a cone
that opened the right way is refined as before.
"""

import dataclasses
import math

import numpy as np
import pytest

from geomodel_ros.core.fitting.curved import FULL_REFINE_ROUNDS, WORKING_REFINE_ROUNDS, \
    refined, reversed_cone
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.ransac import ConeModel, refine

AXIS = np.array([0.0, 0.6, 0.8])           # apex -> base, tilted towards the camera
APEX = np.array([0.02, -0.3, 0.55])        # ... the side 300-400 mm beyond the apex


def _frame(axis):
    u = np.cross(axis, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    return u, np.cross(axis, u)


def _side(half_angle, n=1500, sigma=0.002, seed=0, t=(0.30, 0.40), radius=None):
    """Points of the side seen from the origin (the half facing it), with depth noise.

    A cone of ``half_angle`` from APEX along AXIS between ``t`` [m]; with ``radius`` a
    cylinder of that radius about the same axis line instead.
    """
    rng = np.random.default_rng(seed)
    u, v = _frame(AXIS)
    tt = rng.uniform(*t, n)
    phi = rng.uniform(-math.pi, math.pi, n)
    rho = np.full(n, radius) if radius is not None else tt * math.tan(half_angle)
    radial = np.outer(np.cos(phi), u) + np.outer(np.sin(phi), v)
    pts = APEX + np.outer(tt, AXIS) + rho[:, None] * radial
    normal = radial * math.cos(half_angle if radius is None else 0.0) - \
        AXIS * math.sin(half_angle if radius is None else 0.0)
    seen = np.einsum("ij,ij->i", normal, pts) < 0          # facing the camera at the origin
    pts = pts[seen]
    ray = pts / np.linalg.norm(pts, axis=1, keepdims=True)
    return pts + ray * rng.normal(0.0, sigma, (len(pts), 1))


PARAMS = dataclasses.replace(ModelingParams(), ransac_threshold=0.006)


def _angle(a, b):
    return math.degrees(math.acos(min(1.0, abs(float(a @ b)))))


def test_reversed_cone_keeps_the_axis_line_and_the_radius_at_the_points():
    pts = _side(math.radians(7.0))
    cone = ConeModel(APEX, AXIS, math.radians(7.0))
    rev = reversed_cone(cone, pts)
    assert rev.half_angle == cone.half_angle
    np.testing.assert_allclose(rev.axis, -AXIS)
    # The apex stays on the axis line, now beyond the points on the other side.
    off = (rev.apex - APEX) - ((rev.apex - APEX) @ AXIS) * AXIS
    assert np.linalg.norm(off) < 1e-12
    mid = pts.mean(axis=0)
    level = APEX + ((mid - APEX) @ AXIS) * AXIS
    r_cone = np.linalg.norm(level - APEX) * math.tan(cone.half_angle)
    r_rev = np.linalg.norm(level - rev.apex) * math.tan(rev.half_angle)
    assert r_rev == pytest.approx(r_cone, rel=1e-9)
    # The taper runs the other way: the base end is narrower on the reversed cone.
    near, far = APEX + 0.30 * AXIS, APEX + 0.40 * AXIS
    assert np.linalg.norm(far - rev.apex) < np.linalg.norm(near - rev.apex)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_frustum_side_started_from_the_wrong_opening_gets_its_taper_back(seed):
    true = math.radians(7.0)
    pts = _side(true, seed=seed)
    wrong = reversed_cone(ConeModel(APEX, AXIS, true), pts)
    # The plain refinement collapses towards a cylinder, below the least half-angle ...
    plain = refine(refine(wrong, pts, PARAMS.ransac_threshold, rounds=WORKING_REFINE_ROUNDS),
                   pts, PARAMS.ransac_threshold, rounds=FULL_REFINE_ROUNDS)
    assert plain.half_angle < PARAMS.min_cone_half_angle
    # ... the refinement from both openings finds the side's taper.
    got = refined(wrong, pts, pts, PARAMS)
    assert got.half_angle >= PARAMS.min_cone_half_angle
    assert math.degrees(got.half_angle) == pytest.approx(7.0, abs=1.0)
    assert _angle(got.axis, AXIS) < 2.0
    assert got.axis @ AXIS > 0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_cylinder_side_stays_narrow(seed):
    """Negative: a cylinder's side is not given a taper by the reversed opening."""
    pts = _side(0.0, seed=seed, radius=0.035)
    for start in (ConeModel(APEX, AXIS, math.radians(5.0)),):
        for cone in (start, reversed_cone(start, pts)):
            got = refined(cone, pts, pts, PARAMS)
            assert got.half_angle < PARAMS.min_cone_half_angle


def test_a_cone_opened_the_right_way_is_refined_as_before():
    true = math.radians(7.0)
    pts = _side(true, seed=3)
    start = ConeModel(APEX + 0.01 * AXIS, AXIS, math.radians(6.0))
    plain = refine(refine(start, pts, PARAMS.ransac_threshold, rounds=WORKING_REFINE_ROUNDS),
                   pts, PARAMS.ransac_threshold, rounds=FULL_REFINE_ROUNDS)
    got = refined(start, pts, pts, PARAMS)
    np.testing.assert_array_equal(got.apex, plain.apex)
    assert got.half_angle == plain.half_angle


def test_first_look_refines_on_the_working_points_only():
    true = math.radians(7.0)
    pts = _side(true, seed=4)
    wrong = reversed_cone(ConeModel(APEX, AXIS, true), pts)
    got = refined(wrong, pts, None, PARAMS)
    assert math.degrees(got.half_angle) == pytest.approx(7.0, abs=1.5)
