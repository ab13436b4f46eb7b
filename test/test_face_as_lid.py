"""Cans typed cuboid under a real sensor's noise: one of the box's faces taken as the lid.

A standing can seen from above and a side under kinect-real noise: its side passes as one
or two planar faces, the box round lid and side verifies, and taken as curved with the side
the lid draws the round rival off the can (a cone of r 48 mm for seed 5's can of r 26 mm).
Each planar face of the box taken as the lid, the rest as the side, gives the can's
cylinder (:func:`~geomodel_ros.core.fitting.strategies._face_as_lid`). The round rival's
first look is the cheapest of its candidate types, not the first its unit accepts
(:func:`~geomodel_ros.core.fitting.strategies._cheapest_type`). Expected sizes are the
rendered shapes' (:mod:`geomodel_ros.tools.synth.clutter`); every case was a cuboid
before.
"""

from __future__ import annotations

import math
import re
from types import SimpleNamespace

import numpy as np
import pytest

from geomodel_ros.core.fitting import strategies
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import Primitive
from geomodel_ros.tools.synth.clutter import camera_pose, make_box, render_clutter, \
    render_layout
from geomodel_ros.tools.synth.scenes import KINECT_REAL_NOISE
from suite_helpers import best_object, can_cylinder

MM = 1e-3
#: Size tolerances under kinect-real noise at 0.5-1.2 m: the range's error there is 2-4 mm
#: per pixel with slow errors across an object; the cylinder's radius and height are fits
#: over hundreds of pixels.
RADIUS_TOL, HEIGHT_TOL = 2.0 * MM, 2.5 * MM
#: The axis within the modeling's default ``angle_tolerance`` (5 deg).
AXIS_TOL_DEG = 5.0


def _axis_error_deg(obj, truth) -> float:
    cos = abs(float(obj.rotation[:, 2] @ truth.rotation[:, 2]))
    return math.degrees(math.acos(min(1.0, cos)))


#: Student quantile of paired_cost.lower_beyond_noise over 16 blocks (15 degrees of freedom).
T_16_BLOCKS = 2.131
#: The comparison _face_as_lid adds to the reasons: the cylinder's and the box's mean
#: truncated costs and the paired statistic.
LID_NOTE = re.compile(r"a face taken as the lid: cylinder \(cost ([0-9.]+)\) (replaces|does not "
                      r"replace) cuboid \(cost ([0-9.]+), t = ([-0-9.]+)\)")


@pytest.mark.parametrize("seed, gt_id", [(5, 2), (45, 16)])
def test_a_can_whose_side_passes_as_planar_faces_is_the_cylinder_below_one_of_them(
        seed, gt_id):
    # Cans r 26.1 and 40.3 mm at 0.67 and 1.19 m, each a cuboid before: the cylinder holds
    # the points closer than the box beyond the noise.
    scene = render_clutter(seed, KINECT_REAL_NOISE)
    obj = can_cylinder(scene, gt_id, RADIUS_TOL, HEIGHT_TOL)
    found = LID_NOTE.search(obj.reason)
    assert found and found.group(2) == "replaces", obj.reason
    assert float(found.group(1)) < float(found.group(3))
    assert float(found.group(4)) >= T_16_BLOCKS
    assert _axis_error_deg(obj, scene.objects[gt_id]) < AXIS_TOL_DEG


def test_a_small_box_far_away_is_no_cylinder_within_the_noise():
    # Held-out seed 137's box 53 x 42 x 71 mm at 1.04 m: a face taken as the lid gives a
    # cylinder that costs less on average (0.087 against 0.101) but not beyond the noise,
    # its top passing as a disc end: the box stays.
    scene = render_clutter(137, KINECT_REAL_NOISE)
    obj = best_object(scene, 4)
    assert obj.type == "cuboid", obj.reason
    found = LID_NOTE.search(obj.reason)
    assert found and found.group(2) == "does not replace", obj.reason
    assert float(found.group(4)) < T_16_BLOCKS


def test_the_round_rival_is_the_cheapest_candidate_type_not_the_first_accepted():
    # Seed 14's can r 42.6 mm at 0.95 m: taken as curved its faces gave a cone first
    # (accepted by the cone unit); the cylinder costs less than the box and replaces it.
    scene = render_clutter(14, KINECT_REAL_NOISE)
    obj = can_cylinder(scene, 1, 3.0 * MM, HEIGHT_TOL)
    assert "all faces taken as curved" in obj.reason
    assert "cylinder (cost" in obj.reason and "replaces cuboid" in obj.reason
    assert _axis_error_deg(obj, scene.objects[1]) < AXIS_TOL_DEG


@pytest.mark.parametrize("dims", [(0.05, 0.05, 0.06), (0.06, 0.04, 0.07), (0.07, 0.07, 0.05)])
@pytest.mark.parametrize("distance, elevation_deg", [(0.6, 35.0), (0.9, 55.0)])
def test_a_can_sized_box_stays_a_box(monkeypatch, dims, distance, elevation_deg):
    # A box as small as a can, alone on the desk under kinect-real noise: the face-as-lid
    # rival is asked and refuses every time (no circle about a face's normal holds a box's
    # sides closer than the box, and a cylinder through its corners costs more).
    tried = []
    real = strategies._face_as_lid

    def spy(cloud, box, reasons):
        got = real(cloud, box, reasons)
        tried.append(got)
        return got

    monkeypatch.setattr(strategies, "_face_as_lid", spy)
    scene = render_layout([make_box(*dims, yaw=0.5)], [0],
                          camera_pose(distance, math.radians(elevation_deg), 0.3),
                          noise=KINECT_REAL_NOISE, rng=7)
    obj = best_object(scene, 1)
    assert obj.type == "cuboid", obj.reason
    assert tried and all(got is None for got in tried)
    assert sorted(obj.dimensions.values()) == pytest.approx(sorted(dims), abs=6.0 * MM)


def test_a_box_that_does_not_explain_its_object_gets_no_lid(monkeypatch):
    # kinect-real seed 10: a box and a can in one segment, fitted as one box with 73 % of
    # the points in its band; the segment's split parts them. A cylinder round both held
    # the points closer than that box and would have kept them in one segment.
    calls = []
    monkeypatch.setattr(strategies, "fit_first",
                        lambda *a, _f=strategies.fit_first, **k: calls.append(1) or _f(*a, **k))
    seen = []
    real = strategies._face_as_lid

    def spy(cloud, box, reasons):
        before = len(calls)
        got = real(cloud, box, reasons)
        share = float(np.mean(strategies.truncated_costs(box, cloud) < 1.0))
        seen.append((share, len(calls) - before, got))
        return got

    monkeypatch.setattr(strategies, "_face_as_lid", spy)
    scene = render_clutter(10, KINECT_REAL_NOISE)
    box, can = best_object(scene, 1), best_object(scene, 9)
    assert box.id != can.id and box.type == "cuboid" and can.type == "cylinder"
    unexplained = [(fits, got) for share, fits, got in seen
                   if share < ModelingParams().min_inlier_ratio]
    assert unexplained, seen
    assert all(fits == 0 and got is None for fits, got in unexplained)


def test_the_geometric_circle_of_a_short_noisy_arc_has_its_radius():
    # A 120 deg arc of r 30 mm, 400 points with 0.5 mm of radial noise: the least-squares
    # circle of the distances recovers the radius within 1 mm, and its residuals are no
    # larger than the algebraic (Kasa) circle's it starts from.
    rng = np.random.default_rng(4)
    phi = rng.uniform(-math.pi / 3, math.pi / 3, 400)
    rho = 0.03 + rng.normal(0.0, 0.0005, 400)
    uv = np.column_stack([rho * np.cos(phi), rho * np.sin(phi)]) + [0.2, -0.1]
    centre, radius, residuals = strategies._geometric_circle(uv)
    assert radius == pytest.approx(0.03, abs=1.0 * MM)
    assert centre == pytest.approx([0.2, -0.1], abs=1.5 * MM)
    kasa_centre, kasa_radius = strategies._circle_2d(uv)
    kasa = np.linalg.norm(uv - kasa_centre, axis=1) - kasa_radius
    assert np.sqrt(np.mean(residuals ** 2)) <= np.sqrt(np.mean(kasa ** 2))
    assert residuals == pytest.approx(np.linalg.norm(uv - centre, axis=1) - radius)
    assert strategies._geometric_circle(uv[:2]) is None  # no circle through two points


def _side_and_lid(points, lid_rows, normal, box, threshold=0.004):
    """_side_round_about of hand-built points: the lid's rows, its normal and the box."""
    cloud = SimpleNamespace(points=points, params=SimpleNamespace(ransac_threshold=threshold))
    lid = SimpleNamespace(points=lid_rows, info=SimpleNamespace(normal=normal))
    return strategies._side_round_about(cloud, box, lid)


def _upright_box(half_x, half_y, height):
    return Primitive(0, "cuboid", np.array([0.0, 0.0, height / 2]), np.eye(3),
                     {"length": 2 * half_x, "width": 2 * half_y, "height": height}, 1, 0.0)


def test_a_cans_side_is_round_about_its_lids_normal_and_a_boxs_sides_are_not():
    rng = np.random.default_rng(5)
    up = np.array([0.0, 0.0, 1.0])
    r, h = 0.03, 0.07
    # A can's lid (a disc at its top) and the half of its side facing the sensor (+x),
    # 1 mm of noise; the box round it (2r x 2r x h, the can's axes).
    disc = rng.uniform(-r, r, (3000, 2))
    disc = disc[np.hypot(disc[:, 0], disc[:, 1]) <= r][:600]
    phi = rng.uniform(-math.pi / 2, math.pi / 2, 900)
    side = np.column_stack([r * np.cos(phi), r * np.sin(phi), rng.uniform(0, h, 900)])
    can = np.vstack([np.column_stack([disc, np.full(len(disc), h)]), side])
    can += rng.normal(0.0, 0.001, can.shape)
    lid_rows = np.arange(len(disc))
    assert _side_and_lid(can, lid_rows, up, _upright_box(r, r, h))
    # A box's top and two of its sides (faces x = +a and y = +b), the same noise: no circle
    # about the top's normal holds the sides closer than the box.
    a, b = 0.04, 0.025
    top = np.column_stack([rng.uniform(-a, a, 600), rng.uniform(-b, b, 600), np.full(600, h)])
    fx = np.column_stack([np.full(450, a), rng.uniform(-b, b, 450), rng.uniform(0, h, 450)])
    fy = np.column_stack([rng.uniform(-a, a, 450), np.full(450, b), rng.uniform(0, h, 450)])
    box_points = np.vstack([top, fx, fy]) + rng.normal(0.0, 0.001, (1500, 3))
    assert not _side_and_lid(box_points, np.arange(600), up, _upright_box(a, b, h))
    # Nor about a side's normal (the box's other faces as that face's "side").
    assert not _side_and_lid(box_points, np.arange(600, 1050), np.array([1.0, 0.0, 0.0]),
                             _upright_box(a, b, h))
