"""Cans whose lid is partly hidden, typed cuboid: the cylinder below the lid.

A standing can seen from above with part of its lid hidden by a neighbour: taken as curved,
the lid draws the round rival's fits off the side, the lid is no disc all round, and the
box round lid and side strip verified (noise-free clutter seeds 40 and 103: cuboids
before). The object's largest plane taken as the lid and the rest as the side give the
can's cylinder where the lid's outline follows the cylinder's circle; it replaces the box
when it holds the points closer beyond the noise. A box's top under a cylinder through the
box and its neighbour follows a rectangle and makes no lid. Expected sizes are the
rendered shapes' (:mod:`geomodel_ros.tools.synth.clutter`); the outline cases are
hand-built.
"""

from __future__ import annotations

import math
import re
from types import SimpleNamespace

import numpy as np
import pytest

from geomodel_ros.core.fitting import strategies
from geomodel_ros.core.fitting.strategies import _lid_on_circle
from geomodel_ros.core.geometry import frame_with_z
from geomodel_ros.core.primitives import Primitive
from geomodel_ros.tools.synth.clutter import KINECT_NOISE, camera_pose, make_box, \
    render_clutter, render_layout
from geomodel_ros.tools.synth.scenes import KINECT_REAL_NOISE
from suite_helpers import best_object, can_cylinder

MM = 1e-3


@pytest.mark.parametrize("seed, gt_id", [(40, 6), (103, 12)])
def test_a_can_whose_lid_is_partly_hidden_is_the_cylinder_below_it(seed, gt_id):
    # Noise-free: cans r 42.6 and 27.8 mm whose lids' rims show 250 deg and less.
    scene = render_clutter(seed)
    # Noise-free points: the radius and height within 0.3 mm (the suite's noise-free bound).
    obj = can_cylinder(scene, gt_id, 0.3 * MM, 0.3 * MM)
    assert "the cylinder below its largest plane" in obj.reason
    # The axis along the can's.
    assert abs(obj.rotation[:, 2] @ scene.objects[gt_id].rotation[:, 2]) > math.cos(
        math.radians(1.0))


#: Student quantile of paired_cost.lower_beyond_noise over 16 blocks (15 degrees of freedom).
T_16_BLOCKS = 2.131


@pytest.mark.parametrize("noise, seed, gt_id", [(None, 50, 15), (None, 104, 11),
                                                (KINECT_NOISE, 103, 12),
                                                (KINECT_NOISE, 104, 11)])
def test_a_can_whose_side_is_a_narrow_strip_is_the_cylinder_below_its_lid(noise, seed, gt_id):
    # Cans r 34.1, 28.3, 27.8 mm seen from above with part of the lid hidden and a strip of
    # the side below it (noise-free seed 50: 111 of 685 points): the box round them held
    # its own except on the strip, a few of the 16 blocks of the paired test, where no
    # excess is significant (the statistic is 4 sqrt(m / (16 - m)) for an excess alike in
    # m blocks). Cuboids before; the cylinder holds the points closer on average.
    tol = 0.3 * MM if noise is None else 1.0 * MM
    obj = can_cylinder(render_clutter(seed, noise), gt_id, tol, tol)
    found = re.search(r"the cylinder below its largest plane \(cost ([0-9.]+)\) replaces "
                      r"cuboid \(cost ([0-9.]+), t = ([-0-9.]+)\)", obj.reason)
    assert found, obj.reason
    c_cyl, c_box, stat = map(float, found.groups())
    assert c_cyl < c_box
    assert stat < T_16_BLOCKS  # not significant over the blocks: the mean decided


def _noise_free_can_and_its_box():
    """Return the situation of noise-free seed 50's can 15 and the box fitted to it."""
    seen = []
    real = strategies.prefer_round

    def spy(situation, prim, faces, reasons):
        if prim.type == "cuboid":
            seen.append((situation, prim))
        return real(situation, prim, faces, reasons)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(strategies, "prefer_round", spy)
        scene = render_clutter(50)
        obj = best_object(scene, 15)
    assert obj.type == "cylinder", obj.reason
    found = [(s, p) for s, p in seen if s.cloud.oid == obj.id]
    assert len(found) == 1
    return found[0]


def test_the_lid_cylinder_replaces_the_box_only_when_it_costs_less_on_average(monkeypatch):
    situation, box = _noise_free_can_and_its_box()
    cloud = situation.cloud
    real = strategies.truncated_costs
    box_costs = real(box, cloud)
    # The first cylinder costed is the first look on thinned faces (its real costs, so the
    # attempt goes on as it does); the second, the fitted cylinder, is given the box's
    # costs shifted by a thousandth of the band's cost on every point: a difference alike
    # in every block, the paired test's statistic 0 or infinite, the mean alone tells.
    for shift, verdict in ((1e-3, "does not replace"), (0.0, "does not replace"),
                           (-1e-3, "replaces")):
        calls = []

        def costs(prim, c, _s=shift):
            if prim.type != "cylinder":
                return real(prim, c)
            calls.append(prim)
            return real(prim, c) if len(calls) == 1 else box_costs + _s

        monkeypatch.setattr(strategies, "truncated_costs", costs)
        reasons = []
        got = strategies._lid_cylinder_rival(cloud, box, reasons)
        assert len(calls) == 2
        assert (got is not None) == (verdict == "replaces"), (shift, reasons)
        assert got is None or got[0].type == "cylinder"
        assert "the cylinder below its largest plane (cost " in reasons[-1]
        assert f") {verdict} cuboid" in reasons[-1]


def test_a_box_and_a_can_in_one_segment_make_no_lid_of_the_boxs_top():
    # kinect-real seed 10: a box 139 x 52 x 92 mm and a can r 45.8 mm came as one segment,
    # fitted as one box and split into the two. A cylinder r 128 mm below the box's top
    # held the pair closer than that box (t = 2.5) and took the split's place; the top's
    # outline follows a rectangle, not that cylinder's circle.
    scene = render_clutter(10, KINECT_REAL_NOISE)
    box, can = best_object(scene, 1), best_object(scene, 9)
    assert box.id != can.id
    assert box.type == "cuboid", box.reason
    assert can.type == "cylinder", can.reason
    assert can.dimensions["radius"] == pytest.approx(
        scene.objects[9].dimensions["radius"], abs=2.0 * MM)


def _lid(uv: np.ndarray, radius: float, centre=(0.0, 0.0)) -> bool:
    """_lid_on_circle of a planar face (uv at z = 0.7 m) and a vertical cylinder."""
    points = np.column_stack([uv, np.full(len(uv), 0.7)])
    cloud = SimpleNamespace(points=points)
    face = SimpleNamespace(points=np.arange(len(points)))
    cyl = Primitive(0, "cylinder", np.array([*centre, 0.75]), frame_with_z(np.array([0, 0, 1.0])),
                    {"radius": radius, "height": 0.1}, len(points), 0.0)
    return _lid_on_circle(cloud, face, cyl)


def _grid(half: float, step: float = 0.0015, turn_deg: float = 10.0) -> np.ndarray:
    """Return a square lattice of ``step`` [m] over +-``half`` (and beyond), turned ``turn_deg``.

    A lid's pixels seen obliquely: a lattice not aligned with the lid's cut.
    """
    g = np.arange(-1.5 * half, 1.5 * half + 1e-9, step)
    x, y = np.meshgrid(g, g)
    c, s = math.cos(math.radians(turn_deg)), math.sin(math.radians(turn_deg))
    return np.column_stack([x.ravel(), y.ravel()]) @ np.array([[c, s], [-s, c]])


def test_a_lid_whole_or_cut_follows_its_circle_and_a_box_top_does_not():
    # A lid r 35 mm sampled every 1.5 mm (23 samples across its radius); a neighbour
    # hides up to two thirds of it along a straight edge.
    r = 0.035
    g = _grid(r)
    disc = g[np.hypot(g[:, 0], g[:, 1]) <= r]
    assert _lid(disc, r)
    for cut in (-0.4, 0.0, 0.3):
        assert _lid(disc[disc[:, 0] >= cut * r], r), cut
        assert _lid(disc[disc[:, 1] <= -cut * r], r), cut
    # A square top under its circumcircle (corners on it, sides inside): a rectangle.
    square = g[np.all(np.abs(g) <= r, axis=1)]
    assert not _lid(square, r * math.sqrt(2.0))
    # A 140 x 52 mm top under a cylinder r 128 mm whose axis lies 70 mm off its centre
    # (the seed-10 pair above).
    top = _grid(0.07)
    top = top[(np.abs(top[:, 0]) <= 0.07) & (np.abs(top[:, 1]) <= 0.026)]
    assert not _lid(top, 0.128, centre=(0.07, 0.0))
    # The right outline but another circle: a disc r 35 mm under a cylinder r 50 mm.
    assert not _lid(disc, 0.05)
    assert not _lid(disc[:2], r)  # too few points for an outline


def test_a_box_with_rectangular_faces_makes_no_lid_attempt(monkeypatch):
    # A box alone on the desk, Kinect-like noise: its faces are rectangles, so the lid
    # and side split (a RANSAC plane and the faces' features) is never made.
    calls = []
    real = strategies._lid_and_side
    monkeypatch.setattr(strategies, "_lid_and_side",
                        lambda cloud: calls.append(cloud.oid) or real(cloud))
    scene = render_layout([make_box(0.08, 0.06, 0.07, yaw=0.4)], [0],
                          camera_pose(0.8, math.radians(50.0), 0.3), noise=KINECT_REAL_NOISE,
                          rng=2)
    obj = best_object(scene, 1)
    assert obj.type == "cuboid", obj.reason
    assert calls == []


@pytest.mark.parametrize("noise, seed, gt_id", [(None, 24, 8), (KINECT_NOISE, 137, 12)])
def test_a_can_no_rule_fits_is_the_cylinder_below_its_lid_whole_or_partly_hidden(
        noise, seed, gt_id):
    # Noise-free seed 24: a can r 27.6 mm, h 69.6 mm whose side shows 25 mm below its lid
    # and whose lid is partly hidden: its faces fit no rule (`unknown` before; the lid was
    # no disc end all round). Kinect-class seed 137: a can r 34.2 mm, h 94.4 mm whose round
    # fits scatter beyond the noise; its lid, seen whole, is a disc end all round but its
    # noisy outline is not nearer the circle than its rectangle: either test lets it be a
    # lid. The cylinder below the lid costs less than a sphere of the object.
    tol = 0.3 * MM if noise is None else 2.0 * MM
    obj = can_cylinder(render_clutter(seed, noise), gt_id, tol, tol)
    assert "the cylinder below its lid" in obj.reason


def test_a_box_whose_sides_passed_as_curved_is_the_box_of_its_normals():
    # Kinect-class seed 46: a box 109.2 x 52.7 x 42.0 mm whose sides passed as curved
    # faces and whose round fits all failed (`unknown` before); no lid's cylinder either.
    # Its normals gather about its three axes: the box of their modes, each side within
    # 5 mm (its 1365 points lie 1.2 m away, where a pixel spans 2 mm and the noise band
    # several millimetres).
    scene = render_clutter(46, KINECT_NOISE)
    assert scene.kinds[7] == "box"
    obj = best_object(scene, 7)
    assert obj.type == "cuboid", obj.reason
    assert "no strategy fitted; box of the point normals' modes" in obj.reason
    got = sorted(obj.dimensions.values())
    want = sorted(scene.objects[7].dimensions.values())
    np.testing.assert_allclose(got, want, atol=5.0 * MM)
