"""Which unit a capped round side goes to first: the side's lean (model_graph.side_tilt)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from geomodel_ros.core.fitting.strategies import graph_decision
from geomodel_ros.core.model_graph import FaceInfo, decide_type, side_tilt
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import PrimitiveType
from suite_helpers import suite_true_labels

TOL = 0.14  # angle tolerance [rad] (the default; 8.0 deg)
COPLANAR = 0.006  # coplanarity tolerance [m]
MIN_HALF = ModelingParams().min_cone_half_angle  # 0.05 rad = 2.86 deg
AXIS = np.array([0.0, -0.6, -0.8])  # unit: 0.36 + 0.64 = 1


def _frame(axis):
    helper = np.array([1.0, 0, 0])
    x = np.cross(helper, axis)
    x /= np.linalg.norm(x)
    return x, np.cross(axis, x)


def side_normals(half_angle, m=400, noise=0.0, seed=0):
    """Return the normals of the seen half of a side about AXIS leaning ``half_angle`` [rad].

    A frustum's side with half-angle a has normals cos(a) radial + sin(a) along its axis
    (towards its top); a cylinder's a = 0. ``noise`` [rad]: independent tilts of each normal
    (Gaussian, along the axis and across it).
    """
    x, y = _frame(AXIS)
    th = np.linspace(0.0, math.pi, m)
    radial = np.cos(th)[:, None] * x + np.sin(th)[:, None] * y
    n = radial * math.cos(half_angle) + AXIS * math.sin(half_angle)
    if noise:
        rng = np.random.default_rng(seed)
        tangent = np.cross(AXIS, radial)
        n = n + rng.normal(0.0, noise, (m, 1)) * AXIS + rng.normal(0.0, noise, (m, 1)) * tangent
        n /= np.linalg.norm(n, axis=1, keepdims=True)
    return n


def faces_of(normals, cap_size=100):
    """Return a curved side with ``normals`` and a planar cap across AXIS (normal along it)."""
    mean = normals.mean(axis=0)
    side = FaceInfo(False, mean / np.linalg.norm(mean), 0.0, len(normals), normals)
    cap_point = np.array([0.0, 0.0, 0.8])
    cap = FaceInfo(True, AXIS, float(-AXIS @ cap_point), cap_size, np.tile(AXIS, (cap_size, 1)),
                   cap_point)
    return [side, cap]


def decide(faces, frustum_tilt):
    return decide_type(faces, ~np.eye(len(faces), dtype=bool), TOL, COPLANAR,
                       frustum_tilt=frustum_tilt)


# ----------------------------------------------------------------------------- side_tilt
@pytest.mark.parametrize("deg", [0.0, 2.0, 5.0, 12.7])
def test_side_tilt_is_the_half_angle_of_a_noise_free_side(deg):
    # Every normal's component along the axis is sin(a): the median too.
    assert side_tilt(side_normals(math.radians(deg)), AXIS) == pytest.approx(math.radians(deg),
                                                                              abs=1e-12)


def test_side_tilt_does_not_depend_on_which_way_the_axis_points():
    n = side_normals(math.radians(7.0))
    assert side_tilt(n, -AXIS) == pytest.approx(math.radians(7.0), abs=1e-12)


def test_independent_noise_leaves_a_cylinder_upright():
    # Normals scattered by 5 deg: their unsigned angles to the perpendicular have a median
    # of about 0.67 * 5 = 3.4 deg (the half-normal's), beyond the least half-angle, but
    # they lean to both sides alike: the signed median stays within about
    # 1.25 * 5 deg / sqrt(400) = 0.3 deg of zero (three such spreads allowed).
    n = side_normals(0.0, noise=math.radians(5.0), seed=3)
    unsigned = np.median(np.arcsin(np.abs(n @ AXIS)))
    assert unsigned > MIN_HALF
    assert side_tilt(n, AXIS) < math.radians(0.9)


def test_no_normals_have_no_tilt():
    assert side_tilt(np.zeros((0, 3)), AXIS) == 0.0


# ------------------------------------------------------------------- the graph's routing
def test_a_side_leaning_by_more_than_the_least_half_angle_goes_to_the_frustum_first():
    # 5 deg < the 8 deg tolerance: the side passes as perpendicular to its cap.
    d = decide(faces_of(side_normals(math.radians(5.0))), MIN_HALF)
    assert d.category == "mixed" and d.main_face == 1
    assert d.candidates == ("frustum", "cylinder", "cone")
    assert d.reason == ("curved normals perpendicular to the plane normal, tilted 5.0 deg to "
                        "one side")


@pytest.mark.parametrize("deg, noise", [(0.0, 0.0), (2.0, 0.0), (0.0, 5.0)])
def test_an_upright_side_keeps_the_cylinder_first(deg, noise):
    # Below the least half-angle (2.86 deg), also with noisy normals: the cylinder first.
    d = decide(faces_of(side_normals(math.radians(deg), noise=math.radians(noise))), MIN_HALF)
    assert d.candidates == ("cylinder", "cone", "frustum")
    assert d.reason == "curved normals perpendicular to the plane normal"


def test_without_a_least_tilt_the_cylinder_stays_first():
    d = decide(faces_of(side_normals(math.radians(5.0))), None)
    assert d.candidates == ("cylinder", "cone", "frustum")


def test_a_side_at_a_clear_angle_still_goes_to_the_cone_first():
    # 20 deg > the tolerance: the constant-angle rule, unchanged.
    d = decide(faces_of(side_normals(math.radians(20.0))), MIN_HALF)
    assert d.candidates == ("cone", "frustum", "cylinder")


@pytest.mark.parametrize("noise_model, first", [("auto", "frustum"), ("fixed", "cylinder")])
def test_the_strategies_route_by_the_lean_only_with_a_measured_noise(noise_model, first):
    faces = faces_of(side_normals(math.radians(5.0)))
    params = dataclasses.replace(ModelingParams(), noise_model=noise_model)
    d = graph_decision(faces, ~np.eye(2, dtype=bool), None, params)
    assert d.candidates[0] == first


# ------------------------------------------------------------------------------- suite
def test_a_suite_frustum_under_correlated_noise_is_a_frustum():
    # set_c at 1.5 m, kinect-real noise, seed 1, from its true labels: the pot (base radius
    # 50, top 32 mm, height 80 mm: half-angle 12.7 deg) had its side pass as perpendicular
    # to its cap and came out a cylinder; its normals lean by about its half-angle.
    objs, gts, _ = suite_true_labels("set_c", 1.5, "kinect-real", seed=1)
    assert gts[1].type == "frustum"
    assert objs[1].type == PrimitiveType.FRUSTUM
    assert "tilted" in objs[1].reason
    assert objs[2].type == PrimitiveType.FRUSTUM


@pytest.mark.parametrize("layout", ["set_a", "set_b"])
def test_suite_cylinders_under_correlated_noise_stay_cylinders(layout):
    # The suite's standing cylinders at 1 m under kinect-real noise (true labels): no
    # cylinder turns into a frustum.
    for seed in (1, 2, 3):
        objs, gts, _ = suite_true_labels(layout, 1.0, "kinect-real", seed=seed)
        for i, g in gts.items():
            if g.type == "cylinder":
                assert objs[i].type == PrimitiveType.CYLINDER, (layout, seed, i)
