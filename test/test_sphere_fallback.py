"""A surface curved two ways is tried as a sphere; a sphere may not sink into its support.

Modules: core.fitting.strategies (DoublyCurvedAsSphere, the last strategy) and
core.fitting.verify (bowed_profile, standing_on, check_sunk_in_support, used by the
sphere unit).

Geometry by hand: a ball of radius R resting on the plane z = 0 has its centre at z = R;
a sphere of radius R centred at height h above the plane reaches R - h into it. The
suite's ball has R = 40 mm; its torus (major radius 50 mm, tube 18 mm) stands 36 mm tall,
so a sphere through its top ring and outer sides is far larger than 36 mm and centred
below the desk.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from geomodel_ros.core.fitting.result import Rejected
from geomodel_ros.core.fitting.strategies import (STRATEGIES, DoublyCurvedAsSphere,
                                                  support_below)
from geomodel_ros.core.fitting.verify import bowed_profile, check_sunk_in_support, standing_on
from geomodel_ros.core.model_graph import NO_CURVATURE, GraphDecision
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import PrimitiveType
from suite_helpers import suite_true_labels

MM = 1e-3
R = 0.040
SPHERE = PrimitiveType.SPHERE
UP = np.array([0.0, 0.0, 1.0])


def cap(center, radius=R, n=2000, seed=0):
    """Points (n, 3) on the upper half of a sphere (z above its centre) [m]."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[:, 2] = np.abs(d[:, 2])
    return np.asarray(center) + radius * d


def cloud(points, supports, noise_model="auto", threshold=5 * MM):
    """Return the parts of an ObjectCloud the support checks read."""
    params = ModelingParams(noise_model=noise_model, ransac_threshold=threshold)
    return SimpleNamespace(points=points, supports=supports, params=params)


def test_a_ball_resting_on_its_support_is_not_sunk():
    pts = cap([0.1, 0.2, R])
    assert check_sunk_in_support(np.array([0.1, 0.2, R]), R, cloud(pts, ((UP, 0.0),)),
                                 SPHERE) is None


@pytest.mark.parametrize("plane", [(UP, 0.0), (-UP, 0.0), (UP, -0.3)])
def test_a_sphere_centred_near_the_support_is_rejected_by_its_depth_into_it(plane):
    # Points of a 36 mm mound on the plane z = z0; a sphere of radius 50 mm centred 10 mm
    # above the plane reaches 40 mm into it, whichever way the plane's normal points.
    n, d = plane
    z0 = -d * float(n @ UP)
    pts = cap([0.0, 0.0, z0], radius=0.036)
    out = check_sunk_in_support(np.array([0.0, 0.0, z0 + 0.010]), 0.050,
                                cloud(pts, ((n, d),)), SPHERE)
    assert isinstance(out, Rejected) and out.misfit
    assert "reaches 40 mm into" in out.reason


def test_a_sphere_within_the_noise_band_of_its_support_is_kept():
    # 3 mm into the plane with a 5 mm band: within the noise.
    pts = cap([0.0, 0.0, R - 3 * MM])
    assert check_sunk_in_support(np.array([0.0, 0.0, R - 3 * MM]), R,
                                 cloud(pts, ((UP, 0.0),)), SPHERE) is None
    # 8 mm is beyond it.
    assert check_sunk_in_support(np.array([0.0, 0.0, R - 8 * MM]), R,
                                 cloud(cap([0.0, 0.0, R - 8 * MM]), ((UP, 0.0),)),
                                 SPHERE) is not None


def test_a_plane_the_points_lie_on_both_sides_of_is_no_support_to_sink_into():
    # The object's points reach 30 mm below the plane z = 0: it does not rest on that
    # side of it, and the plane says nothing about the sphere.
    pts = cap([0.0, 0.0, -0.030], radius=0.060)
    assert check_sunk_in_support(np.array([0.0, 0.0, -0.030]), 0.060,
                                 cloud(pts, ((UP, 0.0),)), SPHERE) is None


def test_no_sunk_check_with_fixed_noise_or_without_supports():
    pts = cap([0.0, 0.0, 0.0], radius=0.036)
    centre = np.array([0.0, 0.0, 0.010])
    assert check_sunk_in_support(centre, 0.050, cloud(pts, ((UP, 0.0),), "fixed"),
                                 SPHERE) is None
    assert check_sunk_in_support(centre, 0.050, cloud(pts, ()), SPHERE) is None


def test_standing_on_returns_the_plane_as_given_and_support_below_its_normal():
    pts = cap([0.0, 0.0, 0.05])
    plane = (-UP, 0.0)
    c = cloud(pts, (plane,))
    n, d = standing_on(c)
    np.testing.assert_array_equal(n, -UP)
    assert d == 0.0
    np.testing.assert_array_equal(support_below(c), -UP)
    # A plane through the middle of a whole ball: half of it 40 mm below, nothing stands
    # on it (the tolerance, 2 x 4 mm + 5 mm, is 13 mm).
    ball = np.vstack([pts, 2 * np.array([0.0, 0.0, 0.05]) - pts])
    assert standing_on(cloud(ball, ((UP, -0.05),))) is None


def test_bowed_profile_recognises_only_the_profile_checks_rejection():
    assert bowed_profile(Rejected(PrimitiveType.CYLINDER, "cylinder rejected: its profile "
                                  "bows 11.2 mm (beyond 2.6 mm) and turns by 69 deg"))
    assert not bowed_profile(Rejected(PrimitiveType.CYLINDER,
                                      "cylinder fit rejected: 74% inliers < 80%"))


def situation(rejected=(), candidates=("cylinder",), reason="", noise_model="auto"):
    """Return the parts of a strategies.Situation the sphere fallback reads."""
    decision = GraphDecision("curved", candidates, -1, (), reason)
    params = ModelingParams(noise_model=noise_model)
    return SimpleNamespace(cloud=SimpleNamespace(params=params), rejected=list(rejected),
                           fit_decision=decision,
                           no_round_shape=not candidates)


BOWED = Rejected(PrimitiveType.CYLINDER, "cylinder rejected: its profile bows 11.2 mm "
                 "(beyond 2.6 mm) and turns by 69 deg along its axis")


def test_the_sphere_fallback_needs_a_second_bend():
    fallback = DoublyCurvedAsSphere()
    assert fallback.applies(situation([BOWED]))
    assert fallback.applies(situation((), (), "principal curvature ratio 0.41 fits no "
                                      "primitive"))
    # Developable curvatures and plain misfits are no evidence of a second bend.
    misfit = Rejected(PrimitiveType.CYLINDER, "cylinder fit rejected: 74% inliers < 80%",
                      misfit=True)
    assert not fallback.applies(situation([misfit]))
    assert not fallback.applies(situation((), (), NO_CURVATURE))
    # fixed keeps the previous strategies exactly.
    assert not fallback.applies(situation([BOWED], noise_model="fixed"))


def test_the_sphere_fallback_is_tried_last():
    assert isinstance(STRATEGIES[-1], DoublyCurvedAsSphere)


@pytest.mark.parametrize("seed", [2, 3])
def test_the_suite_ball_at_1_5_m_under_correlated_noise_is_a_sphere_of_its_radius(seed):
    # Seed 2: its side is taken for a cylinder whose profile bows; seed 3: its curvature
    # ratio falls between the developable and the spherical bound.
    objs, gts, _ = suite_true_labels("set_a", 1.5, "kinect-real", seed)
    assert gts[3].type == "sphere"
    ball = objs[3]
    assert ball.type == PrimitiveType.SPHERE
    assert "curved two ways" in ball.reason
    assert ball.dimensions["radius"] == pytest.approx(R, abs=2 * MM)


@pytest.mark.parametrize("distance,seed", [(1.0, 2), (1.5, 3)])
def test_the_suite_torus_is_no_sphere_sunk_into_the_desk(distance, seed):
    objs, gts, _ = suite_true_labels("set_b", distance, "kinect-real", seed)
    assert gts[3].type == "torus"
    ring = objs[3]
    assert ring.type == PrimitiveType.UNKNOWN
    assert "into the support beneath it" in ring.reason
