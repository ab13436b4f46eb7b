"""A cylinder, cone or frustum is a solid: it cannot reach through the support it rests on.

Module: core.fitting.verify (check_axial_sunk_in_support, used by the cylinder, cone and
frustum units).

Geometry by hand, the support the plane z = 0 (normal UP), the solid the convex hull of
its two end circles. A circle of radius r centred at height h, tilted by theta (its
axis's angle to UP), reaches down to h - r sin(theta); the fitted axis is known to within
the angle tolerance TOL, so the check takes the tilt TOL smaller: h - r sin(theta - TOL)
(h for theta <= TOL). Hence:

- a cone standing on its base (axis vertical) reaches its base plane and no lower;
- a cone of half-angle alpha (tan alpha = R / H) lying on its side touches the floor
  along a generator: its axis rises by alpha from the apex (theta = 90 deg - alpha), the
  base centre stands at R cos(alpha), the apex is at 0 and the base rim's lowest point at
  R cos(alpha) - R cos(alpha + TOL) > 0;
- a cylinder of radius r lying with its axis level at height r reaches r - r cos(TOL) > 0;
- a wide cone with its axis level at 150 mm (base radius 300 mm, 200 mm long: the cone
  that explained the office scene's bottle pack, a bump on a box-like pack with its axis
  running along the floor) reaches 300 cos(TOL) - 150 = 147 mm into the floor.

The band is the RANSAC threshold (5 mm here), as for a sphere
(:func:`~geomodel_ros.core.fitting.verify.check_sunk_in_support`).
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from geomodel_ros.core.fitting.result import Rejected
from geomodel_ros.core.fitting.verify import check_axial_sunk_in_support
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import PrimitiveType

MM = 1e-3
UP = np.array([0.0, 0.0, 1.0])
LEVEL = np.array([1.0, 0.0, 0.0])
CONE, CYLINDER, FRUSTUM = PrimitiveType.CONE, PrimitiveType.CYLINDER, PrimitiveType.FRUSTUM
TOL = math.radians(8.0)


def cloud(points, supports=((UP, 0.0),), noise_model="auto", threshold=5 * MM):
    """Return the parts of an ObjectCloud the support checks read."""
    params = ModelingParams(noise_model=noise_model, ransac_threshold=threshold,
                            angle_tolerance=TOL)
    return SimpleNamespace(points=np.asarray(points, dtype=np.float64), supports=supports,
                           params=params)


def patch(z_lo, z_hi, n=500, seed=0):
    """Points (n, 3) [m] spread over a 200 mm square between heights z_lo and z_hi."""
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-0.1, 0.1, n), rng.uniform(-0.1, 0.1, n),
                            rng.uniform(z_lo, z_hi, n)])


def test_a_cone_standing_on_its_base_is_not_sunk():
    r, h = 0.08, 0.20
    # base (radius r) at z = 0, apex (radius 0) at z = h: axis UP, ends in that order
    assert check_axial_sunk_in_support(np.array([0.0, 0.0, h / 2]), UP, h, (r, 0.0),
                                       cloud(patch(0.0, h)), CONE) is None


def test_a_cone_lying_on_its_side_touches_the_floor_along_a_generator():
    r, h = 0.08, 0.20
    alpha = math.atan(r / h)
    axis = np.array([math.cos(alpha), 0.0, math.sin(alpha)])  # apex -> base, rising
    base = np.array([0.0, 0.0, r * math.cos(alpha)])
    center = base - axis * h / 2
    assert center[2] - h / 2 * axis[2] == pytest.approx(0.0, abs=1e-12)  # the apex is down
    assert check_axial_sunk_in_support(center, axis, h, (0.0, r), cloud(patch(0.0, 0.15)),
                                       CONE) is None
    # The same cone 8 mm lower: its apex reaches 8 mm into the floor, beyond the 5 mm band
    # (the base rim's lowest point, R cos(alpha) - R cos(alpha + TOL) = 4.9 mm above the
    # floor before, is 3.1 mm into it).
    out = check_axial_sunk_in_support(center - 8 * MM * UP, axis, h, (0.0, r),
                                      cloud(patch(0.0, 0.15)), CONE)
    assert isinstance(out, Rejected) and out.misfit
    assert "reaches 8 mm into" in out.reason


@pytest.mark.parametrize("plane", [(UP, 0.0), (-UP, 0.0), (UP, -0.3)])
def test_a_wide_cone_along_the_floor_is_rejected_by_its_depth_into_it(plane):
    # A bump of points 50-300 mm above the floor; the cone through it has its axis level
    # at 150 mm and a 300 mm base: its base rim reaches 300 cos(TOL) - 150 = 147 mm below
    # the floor, whichever way the plane's normal points.
    n, d = plane
    z0 = -d * float(n @ UP)
    out = check_axial_sunk_in_support(np.array([0.0, 0.0, z0 + 0.150]), LEVEL, 0.20,
                                      (0.0, 0.30), cloud(patch(z0 + 0.05, z0 + 0.30),
                                                         ((n, d),)), CONE)
    assert isinstance(out, Rejected) and out.misfit and out.type is CONE
    assert "reaches 147 mm into" in out.reason


def test_a_cylinder_lying_on_the_floor_is_kept_within_the_band_and_not_beyond():
    r = 0.04  # level: its lowest line 0.4 mm above the axis's height less r
    pts = patch(0.0, 2 * r)
    assert check_axial_sunk_in_support(np.array([0.0, 0.0, r]), LEVEL, 0.2, (r, r),
                                       cloud(pts), CYLINDER) is None
    assert check_axial_sunk_in_support(np.array([0.0, 0.0, r - 3 * MM]), LEVEL, 0.2, (r, r),
                                       cloud(pts), CYLINDER) is None
    out = check_axial_sunk_in_support(np.array([0.0, 0.0, r - 9 * MM]), LEVEL, 0.2, (r, r),
                                      cloud(pts), CYLINDER)
    depth = 9 * MM - r * (1.0 - math.cos(TOL))
    assert isinstance(out, Rejected) and f"reaches {depth * 1000:.0f} mm into" in out.reason


def test_a_standing_cylinder_tilted_within_the_angle_tolerance_is_not_sunk():
    # Its bottom circle centred on the floor. A wide can (92 mm) fitted 3.5 deg off its
    # table's normal dips 92 mm x sin 3.5 deg = 5.6 mm, beyond a 5 mm band; its axis is
    # known only to within TOL, so no dip counts. Tilted 20 deg, 12 deg beyond TOL, the
    # rim reaches 92 mm x sin 12 deg = 19 mm into the floor.
    r, h = 0.092, 0.10
    for tilt_deg, kept in ((3.5, True), (20.0, False)):
        t = math.radians(tilt_deg)
        axis = np.array([math.sin(t), 0.0, math.cos(t)])
        out = check_axial_sunk_in_support(axis * h / 2, axis, h, (r, r), cloud(patch(0.0, h)),
                                          CYLINDER)
        assert (out is None) is kept, out
        if not kept:
            assert "reaches 19 mm into" in out.reason


def test_a_cup_standing_on_its_small_end_is_not_sunk_whichever_way_its_axis_runs():
    small, large, h = 0.032, 0.045, 0.10
    c = np.array([0.0, 0.0, h / 2])
    assert check_axial_sunk_in_support(c, UP, h, (small, large), cloud(patch(0.0, h)),
                                       FRUSTUM) is None
    assert check_axial_sunk_in_support(c, -UP, h, (large, small), cloud(patch(0.0, h)),
                                       FRUSTUM) is None
    # The radii swapped (the large circle on the floor) still rest on it.
    assert check_axial_sunk_in_support(c, UP, h, (large, small), cloud(patch(0.0, h)),
                                       FRUSTUM) is None


def test_a_plane_the_points_lie_on_both_sides_of_is_no_support_to_sink_into():
    # The points reach 100 mm below z = 0: the object does not rest on that side of it.
    pts = patch(-0.10, 0.20)
    assert check_axial_sunk_in_support(np.array([0.0, 0.0, 0.05]), LEVEL, 0.2, (0.0, 0.3),
                                       cloud(pts), CONE) is None


def test_no_check_with_fixed_noise_or_without_supports():
    args = (np.array([0.0, 0.0, 0.150]), LEVEL, 0.20, (0.0, 0.30))
    pts = patch(0.05, 0.30)
    assert check_axial_sunk_in_support(*args, cloud(pts, noise_model="fixed"), CONE) is None
    assert check_axial_sunk_in_support(*args, cloud(pts, supports=()), CONE) is None
    assert isinstance(check_axial_sunk_in_support(*args, cloud(pts), CONE), Rejected)
