"""Round objects seen from above: cans by their caps' rims, open containers by their walls.

A camera looking down at a table (elevation 70-85 deg) sees a standing can's side only
at grazing incidence, steeper than the 70 deg within which a side's points judge its arc
(:func:`geomodel_ros.core.fitting.measure.steep_arc_span`); its top, seen steeply, is a
disc whose rim is the side's circle (:func:`geomodel_ros.core.fitting.axial.cap_rim_arc`).
An open container shows its inner floor, a cap seen from inside that closes no end: the
container reaches down to the desk it stands on; where region growing joined that floor
to the wall under a real sensor's noise, the points whose normals run along the axis are
left out of the side's profile test. A cylinder that fits a can about as well as a box
does (within the noise) replaces the box when the can's lid is a disc of the cylinder's
circle, all round (:func:`geomodel_ros.core.fitting.strategies.disc_end`); a can seen by
its lid, its side only in grazing slivers, gives no round fit at all, and the circle of
its lid makes the cylinder that meets the box
(:func:`geomodel_ros.core.fitting.strategies.disc_cylinder`). Expected sizes
are the rendered shapes' (:mod:`geomodel_ros.tools.synth.clutter`); the rim-arc and disc
cases are hand-built.
"""

from __future__ import annotations

import dataclasses
import math
import re
from types import SimpleNamespace

import numpy as np
import pytest

from geomodel_ros.core.fitting import strategies
from geomodel_ros.core.fitting.axial import cap_rim_arc
from geomodel_ros.core.fitting.strategies import (_circle_2d, _prefer_disc_cylinder,
                                                  _rectangle_distance, cavity_floor,
                                                  disc_cylinder, disc_end)
from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import Primitive, PrimitiveType
from geomodel_ros.core.ransac import CylinderModel
from geomodel_ros.tools.synth.clutter import (KINECT_NOISE, camera_pose, make_box, make_can,
                                              make_cone, make_container, render_clutter,
                                              render_layout)
from geomodel_ros.tools.synth.scenes import KINECT_REAL_NOISE
from suite_helpers import suite_true_labels

MM = 1e-3
#: A can 70 mm across and 100 mm tall; a bowl 90 mm across at its foot, 160 mm at its rim;
#: a cup 70 mm across at its foot, 90 mm at its rim (walls 4 mm, floors 8 mm thick).
CAN = (0.035, 0.100)
BOWL = (0.045, 0.080, 0.060)
CUP = (0.035, 0.045, 0.080)
WALL = 0.004


def _modeled(item, elevation_deg: float, noise=None, rng: int = 0):
    """Return the object modeled from the most pixels of the one item seen from 0.8 m."""
    scene = render_layout([item], [0], camera_pose(0.8, math.radians(elevation_deg), 0.5),
                          noise=noise, rng=rng)
    return _best(scene, 1)


def _best(scene, gt_id: int):
    """Return the object modeled from the most pixels of ground-truth object ``gt_id``."""
    labels, result = model_scene(scene.organized)
    gt = scene.label_image.ravel()
    mine = labels[(gt == gt_id) & (labels >= 0)]
    assert len(mine), "the item was not segmented at all"
    best = int(np.bincount(mine).argmax())
    return {o.id: o for o in result.objects}[best]


# ------------------------------------------------------------------------ cans from above
@pytest.mark.parametrize("elevation", [70.0, 75.0, 80.0])
@pytest.mark.parametrize("noisy", [False, True])
def test_a_can_seen_from_above_is_a_cylinder_of_its_size(elevation, noisy):
    # From 70-80 deg above the desk the side is seen within 10-20 deg of edge-on: no point
    # of it judges an arc, the top's rim does. Sizes: the radius from the side, the height
    # from the top down to the desk.
    obj = _modeled(make_can(*CAN), elevation, KINECT_NOISE if noisy else None)
    assert obj.type == "cylinder", obj.reason
    tol = 2.0 * MM if noisy else 0.3 * MM
    assert obj.dimensions["radius"] == pytest.approx(CAN[0], abs=tol)
    assert obj.dimensions["height"] == pytest.approx(CAN[1], abs=2 * tol)


def _cap(xy: np.ndarray, z: float = 0.7) -> np.ndarray:
    return np.column_stack([xy, np.full(len(xy), z)])


def _rim_arc(cap_points: np.ndarray, radius: float) -> float:
    """cap_rim_arc of a cap (points at z = 0.7 m) on a vertical cylinder about the z axis."""
    model = CylinderModel(np.zeros(3), np.array([0.0, 0.0, 1.0]), radius)
    params = ModelingParams(ransac_threshold=0.001)
    cloud = SimpleNamespace(points=cap_points, spacing=0.002, params=params)
    side = SimpleNamespace(model=model)
    nearest = np.ones(len(cap_points), dtype=np.int64)
    return cap_rim_arc(cloud, side, nearest, 1, np.zeros(3))


def _grid(half: float, step: float = 0.002) -> np.ndarray:
    g = np.arange(-half, half + 1e-9, step)
    x, y = np.meshgrid(g, g)
    return np.column_stack([x.ravel(), y.ravel()])


def test_a_disc_confirms_its_whole_circle_and_a_half_disc_half_of_it():
    r = 0.035
    g = _grid(r)
    disc = g[np.hypot(g[:, 0], g[:, 1]) <= r]
    assert _rim_arc(_cap(disc), r) > 2 * math.pi - 0.2
    half = disc[disc[:, 0] >= 0]
    assert _rim_arc(_cap(half), r) == pytest.approx(math.pi, abs=0.2)


def test_a_square_top_confirms_no_circle_through_its_sides():
    # A box's top reaches beyond the circle inscribed in it (its corners): not a rim.
    r = 0.035
    assert _rim_arc(_cap(_grid(r)), r) == 0.0


def test_a_cap_well_inside_the_side_confirms_nothing():
    # A lid 20 mm smaller than the side has no points near the side's circle.
    r = 0.035
    g = _grid(r)
    small = g[np.hypot(g[:, 0], g[:, 1]) <= r - 0.020]
    assert _rim_arc(_cap(small), r) == 0.0


# ------------------------------------------------------------------- open containers
@pytest.mark.parametrize("elevation", [45.0, 60.0, 75.0])
def test_a_bowl_seen_from_above_reaches_down_to_the_desk(elevation):
    # Its inner floor (8 mm above the desk) is seen from inside: it is no bottom. The
    # height is rim to desk; the radii those of the wall fitted, the inner one seen more
    # (within a wall's thickness of the outer ones, the foot's extrapolated 8 mm below the
    # inner floor).
    obj = _modeled(make_container(*BOWL, "bowl"), elevation)
    assert obj.type == "frustum", obj.reason
    assert obj.dimensions["height"] == pytest.approx(BOWL[2], abs=2 * MM)
    assert BOWL[1] - WALL - 1.5 * MM <= obj.dimensions["radius"] <= BOWL[1] + 1 * MM
    assert BOWL[0] - WALL - 1.5 * MM <= obj.dimensions["top_radius"] <= BOWL[0] + 1 * MM


@pytest.mark.parametrize("elevation", [60.0, 75.0])
def test_a_cup_seen_from_above_reaches_down_to_the_desk(elevation):
    obj = _modeled(make_container(*CUP, "cup"), elevation)
    assert obj.type == "frustum", obj.reason
    assert obj.dimensions["height"] == pytest.approx(CUP[2], abs=2 * MM)


@pytest.mark.parametrize("elevation", [45.0, 75.0])
def test_closed_solids_seen_from_above_keep_their_tops(elevation):
    # A can's top is seen from outside and closes its end: its height is not stretched.
    # A box has no round side for a rim to confirm.
    can = _modeled(make_can(*CAN), elevation)
    assert can.type == "cylinder"
    assert can.dimensions["height"] == pytest.approx(CAN[1], abs=0.3 * MM)
    box = _modeled(make_box(0.08, 0.06, 0.10), elevation)
    assert box.type == "cuboid"
    assert sorted(box.dimensions.values()) == pytest.approx([0.06, 0.08, 0.10], abs=0.3 * MM)


@pytest.mark.parametrize("rng", [0, 2])
def test_a_bowl_whose_floor_joined_its_wall_is_a_frustum(rng):
    # Kinect-like correlated noise at 0.8 m, 40 deg above the desk: the inner floor is in
    # the side's band, and its points bowed the side's profile by more than the noise.
    obj = _modeled(make_container(*BOWL, "bowl"), 40.0, KINECT_REAL_NOISE, rng)
    assert obj.type == "frustum", obj.reason
    assert obj.dimensions["radius"] > obj.dimensions["top_radius"]


def _disc_case(face_xy: np.ndarray, radius: float, normal=(0.0, 0.0, 1.0)) -> bool:
    """disc_end of one planar face (points at z = 0.7 m) and a cylinder about the z axis."""
    points = _cap(face_xy)
    face = SimpleNamespace(info=SimpleNamespace(planar=True, normal=np.array(normal)),
                           points=np.arange(len(points)))
    cloud = SimpleNamespace(points=points, faces=[face], spacing=0.002,
                            params=ModelingParams(ransac_threshold=0.001))
    cylinder = SimpleNamespace(type=PrimitiveType.CYLINDER, rotation=np.eye(3),
                               center=np.array([0.0, 0.0, 0.65]),
                               dimensions={"radius": radius, "height": 0.1})
    return disc_end(cloud, cylinder)


def test_a_lid_seen_whole_is_a_disc_end_and_a_box_top_or_a_half_lid_is_not():
    r = 0.035
    g = _grid(r)
    disc = g[np.hypot(g[:, 0], g[:, 1]) <= r]
    assert _disc_case(disc, r)
    assert not _disc_case(_grid(r), r)                    # a square: corners outside
    assert not _disc_case(_grid(r), r * math.sqrt(2))     # its circumcircle: rim at corners
    assert not _disc_case(disc[disc[:, 0] >= 0], r)       # half a lid: half a rim
    assert not _disc_case(disc, r, normal=(1.0, 0.0, 0.0))  # a face along the axis


def test_the_circle_through_points_of_a_circle_is_that_circle():
    phi = np.linspace(0.3, 5.0, 9)
    uv = np.column_stack([0.01 + 0.04 * np.cos(phi), -0.02 + 0.04 * np.sin(phi)])
    centre, radius = _circle_2d(uv)
    np.testing.assert_allclose(centre, [0.01, -0.02], atol=1e-12)
    assert radius == pytest.approx(0.04, abs=1e-12)
    assert _circle_2d(uv[:2]) is None


#: A box 70 x 70 mm across and 100 mm deep whose top is at z = 0.7 m, facing the sensor
#: at the origin; it reaches away from the sensor to z = 0.8 m.
LID_BOX = Primitive(0, "cuboid", np.array([0.0, 0.0, 0.75]), np.eye(3),
                    {"length": 0.07, "width": 0.07, "height": 0.1}, 1000, 0.0)


def _disc_cylinder_of(face_xy: np.ndarray, normal=(0.0, 0.0, -1.0), box=LID_BOX):
    """disc_cylinder of one planar face (points at z = 0.7 m) and ``box``."""
    points = _cap(face_xy)
    face = SimpleNamespace(info=SimpleNamespace(planar=True, normal=np.array(normal),
                                                size=len(points)),
                           points=np.arange(len(points)))
    cloud = SimpleNamespace(oid=3, points=points, faces=[face], spacing=0.002,
                            params=ModelingParams(ransac_threshold=0.001))
    return disc_cylinder(cloud, box)


def test_the_cylinder_of_a_disc_face_is_the_lids_circle_as_long_as_the_box():
    r = 0.035
    g = _grid(r)
    cyl = _disc_cylinder_of(g[np.hypot(g[:, 0], g[:, 1]) <= r])
    assert cyl is not None and cyl.type is PrimitiveType.CYLINDER and cyl.id == 3
    # The outline's points lie within one grid step (2 mm) inside the circle.
    assert r - 0.002 < cyl.dimensions["radius"] <= r + 1e-9
    assert cyl.dimensions["height"] == pytest.approx(0.1, abs=1e-12)
    assert cyl.completed == () and 0.0 <= cyl.rmse < 0.002
    # The box's depth completed down to a support: so is the cylinder's height.
    done = _disc_cylinder_of(g[np.hypot(g[:, 0], g[:, 1]) <= r],
                             box=dataclasses.replace(LID_BOX, completed=("height",)))
    assert done.completed == ("height",)
    # Axis along the lid's normal, centre halfway down the box from the lid's centre.
    assert abs(cyl.rotation[2, 2]) == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(cyl.center, [0.0, 0.0, 0.75], atol=1e-4)


def test_a_square_top_a_half_lid_or_a_face_along_no_axis_of_the_box_give_no_cylinder():
    r = 0.035
    g = _grid(r)
    disc = g[np.hypot(g[:, 0], g[:, 1]) <= r]
    assert _disc_cylinder_of(g) is None                         # a box's square top
    assert _disc_cylinder_of(disc[disc[:, 0] >= 0]) is None     # half a lid
    assert _disc_cylinder_of(disc, normal=(0.0, -0.6, -0.8)) is None  # 37 deg off its axes


DISC_FACE, BELOW_LID = "the cylinder of its disc face", "the cylinder below its largest plane"


@pytest.mark.parametrize("seed, gt_id, height_seen", [(13, 16, True), (50, 15, False)])
def test_a_lid_whose_rim_the_noise_frayed_is_the_cans_disc_face(seed, gt_id, height_seen):
    # kinect-real clutter cans of r 31.4 and 34.1 mm at 0.56 and 0.95 m, cuboids while the
    # disc face's rim had to run round the whole circle: the lid's outline follows its
    # circle, and the cylinder of that circle as long as the box costs less than the box.
    # Seed 50's can shows 33 mm of its 69 mm (its lower part hidden, not completed): only
    # its radius is asked.
    scene = render_clutter(seed, KINECT_REAL_NOISE)
    assert scene.kinds[gt_id] == "can"
    obj = _best(scene, gt_id)
    assert obj.type == "cylinder", obj.reason
    assert re.search(DISC_FACE + r" \(cost [0-9.]+\) replaces cuboid", obj.reason)
    truth = scene.objects[gt_id].dimensions
    assert obj.dimensions["radius"] == pytest.approx(truth["radius"], abs=2.0 * MM)
    if height_seen:
        assert obj.dimensions["height"] == pytest.approx(truth["height"], abs=5.0 * MM)
#: The round rival of all faces taken as curved, its first look the cheapest candidate type.
ROUND_RIVAL = "all faces taken as curved"


@pytest.mark.parametrize("noise,seed,gt_id,route", [
    (None, 6, 2, BELOW_LID), (KINECT_REAL_NOISE, 3, 3, BELOW_LID),
    (KINECT_REAL_NOISE, 19, 12, ROUND_RIVAL), (KINECT_REAL_NOISE, 53, 5, ROUND_RIVAL)])
def test_cans_seen_by_their_lids_are_the_cylinders_of_the_lids(noise, seed, gt_id, route):
    # Standing cans whose lid the camera sees whole (noise-free seed 6: 96 % of the can's
    # pixels) and their side only in grazing slivers or facets that pass as planar: no
    # round fit verifies and the box round the lid did (cuboids before); the lid's circle
    # gives the cylinder (radius within 1.6 mm, height the box's, within 2.5 mm). Where
    # the cylinder below the lid, fitted to the side with its axis along the lid's normal,
    # holds the points closer than the box on average, it is taken first (noise-free seed
    # 6: cost 0.000 against 0.010 but t = 2.0 over the blocks; kinect-real seed 3: 0.030
    # against 0.091, t = 1.3). Kinect-real seeds 19 and 53 had the cylinder of the disc
    # face; since the round rival's first look is the cheapest of its candidate types
    # (strategies._cheapest_type), its cylinder holds their points closer than the box
    # beyond the noise first (cost 0.015 against 0.031, t = 2.6; 0.012 against 0.026,
    # t = 3.6).
    scene = render_clutter(seed, noise)
    assert scene.kinds[gt_id] == "can"
    obj = _best(scene, gt_id)
    assert obj.type == "cylinder", obj.reason
    assert route in obj.reason
    truth = scene.objects[gt_id].dimensions
    # The lid's outline gives the radius within 2 mm; the side's fit of the round rival,
    # 1.09 m away under kinect-real noise (seed 19), 2.04 mm.
    radius_tol = 2.5 * MM if route == ROUND_RIVAL else 2.0 * MM
    assert obj.dimensions["radius"] == pytest.approx(truth["radius"], abs=radius_tol)
    assert obj.dimensions["height"] == pytest.approx(truth["height"], abs=3.0 * MM)
    # The rmse of its points about it, not a fit's placeholder: within the noise.
    assert 0.0 < obj.rmse < 3.0 * MM


def test_a_box_whose_top_is_near_a_disc_in_the_noise_stays_a_box():
    # Under kinect-real noise at 0.8 m the rim of this box's 84 x 84 mm top lies within
    # the disc test's band of its circle (before the outline test, the cylinder was
    # tried and lost on cost, 0.147 against 0.033); its outline follows the box's face.
    scene = render_layout([make_box(0.084, 0.084, 0.072, yaw=0.3)], [0],
                          camera_pose(0.8, math.radians(70.0), 0.3), noise=KINECT_REAL_NOISE,
                          rng=3)
    obj = _best(scene, 1)
    assert obj.type == "cuboid", obj.reason
    assert "the cylinder of its disc face" not in obj.reason


def test_a_small_box_in_clutter_whose_box_fit_is_poor_stays_a_box():
    # kinect-real seed 137's box 53 x 42 x 71 mm: its fitted box is off (43 x 72 x 79 mm)
    # and a face of it passed the disc test; compared with the fitted box's face its
    # outline looked round, compared with its own least-area rectangle it does not.
    scene = render_clutter(137, KINECT_REAL_NOISE)
    assert scene.kinds[4] == "box"
    obj = _best(scene, 4)
    assert obj.type == "cuboid", obj.reason


def test_rectangle_distance_is_to_the_least_area_rectangle_round_the_outline():
    # A rectangle 60 x 40 mm turned by 30 deg, its corners and the middles of its sides:
    # every vertex lies on it.
    c, s_ = math.cos(math.radians(30.0)), math.sin(math.radians(30.0))
    local = np.array([[0.03, 0.02], [0.0, 0.02], [-0.03, 0.02], [-0.03, -0.02], [0.0, -0.02],
                      [0.03, -0.02]])
    got = _rectangle_distance(local @ np.array([[c, s_], [-s_, c]]))
    np.testing.assert_allclose(got, 0.0, atol=1e-12)
    # A regular 24-gon of radius 1 with vertices at 7.5 + 15 k deg: its least-area
    # rectangle is the square of half-side cos 7.5 deg; by symmetry eight vertices lie
    # on it and eight each are cos 7.5 - cos 22.5 and cos 7.5 - cos 37.5 deg inside.
    phi = np.radians(7.5 + 15.0 * np.arange(24))
    got = np.sort(_rectangle_distance(np.column_stack([np.cos(phi), np.sin(phi)])))
    a = math.cos(math.radians(7.5))
    want = np.repeat([0.0, a - math.cos(math.radians(22.5)), a - math.cos(math.radians(37.5))], 8)
    np.testing.assert_allclose(got, want, atol=1e-12)


def _lid_and_sides(side_radius):
    """Return a disc lid (r 35 mm at z = 0.7 m) and 100 mm of side below it, round or flat."""
    r = 0.035
    g = _grid(r)
    lid = _cap(g[np.hypot(g[:, 0], g[:, 1]) <= r])
    phi, z = np.meshgrid(np.linspace(-2.0, -1.1, 30), np.linspace(0.702, 0.8, 50))
    if side_radius:
        side = np.column_stack([r * np.cos(phi.ravel()), r * np.sin(phi.ravel()), z.ravel()])
    else:  # the box's side y = -35 mm, as wide as the lid's chord there
        side = np.column_stack([r * np.cos(phi.ravel()), np.full(phi.size, -r), z.ravel()])
    points = np.vstack([lid, side])
    lid_face = SimpleNamespace(info=SimpleNamespace(planar=True, normal=np.array([0, 0, -1.0]),
                                                    size=len(lid)),
                               points=np.arange(len(lid)))
    return SimpleNamespace(oid=3, points=points, faces=[lid_face], spacing=0.002,
                           params=ModelingParams(ransac_threshold=0.001))


@pytest.mark.parametrize(("round_side", "kind"), [(True, "cylinder"), (False, "cuboid")])
def test_the_cylinder_of_a_disc_face_replaces_the_box_only_where_it_costs_less(round_side,
                                                                                kind):
    reasons = []
    got, _ = _prefer_disc_cylinder(_lid_and_sides(round_side), LID_BOX, (), reasons)
    assert got.type == kind
    assert len(reasons) == 1 and reasons[0].startswith("the cylinder of its disc face")


@pytest.mark.parametrize("seed,gt_id", [(12, 5), (12, 7), (27, 7)])
def test_cans_in_clutter_that_a_box_fits_as_well_are_cylinders_of_their_size(seed, gt_id):
    # kinect-real clutter: the cylinder's cost was lower, but not beyond the noise (t
    # 0.6-2.0 over blocks), and the box was kept; then the lid, a disc end of the
    # cylinder, decided (r 26.7, 27.0, 29.2 mm, true 30.5, 29.3, 32.4: the lid, taken as
    # curved, drew the refit's side inwards). With the lid left out of the refit the
    # cylinder wins beyond the noise (t 4.8-5.4) at r 30.4, 28.9, 30.4 mm. (Seed 33's
    # can, the fourth such, wins beyond the noise with its first look: below.)
    scene = render_clutter(seed, KINECT_REAL_NOISE)
    obj = _best(scene, gt_id)
    assert obj.type == "cylinder", obj.reason
    truth = scene.objects[gt_id].dimensions
    assert obj.dimensions["radius"] == pytest.approx(truth["radius"], abs=2.5 * MM)
    assert obj.dimensions["height"] == pytest.approx(truth["height"], abs=5.0 * MM)


@pytest.mark.parametrize("seed,gt_id", [(2, 10), (33, 4), (102, 1), (134, 5), (139, 8)])
def test_cans_whose_round_rivals_refit_goes_astray_are_cylinders_of_their_size(seed, gt_id):
    # kinect-real clutter: the round rival's first look beat the box, its refit on all the
    # points (the lid among them, taken as curved) drew the side inwards and lost (seed 2:
    # cost 0.186 against the box's 0.034; seed 33: r 23.4 mm, a tie decided by the lid,
    # against the first look's 24.9, true 26.8); the first look's model competes instead.
    # The refit leaves the lid out now (seed 134: r 33.1 -> 35.2 mm, true 36.4).
    scene = render_clutter(seed, KINECT_REAL_NOISE)
    obj = _best(scene, gt_id)
    assert obj.type == "cylinder", obj.reason
    true_radius = scene.objects[gt_id].dimensions["radius"]
    assert obj.dimensions["radius"] == pytest.approx(true_radius, abs=2.5 * MM)


@pytest.mark.parametrize("noise,seed,gt_id", [
    (KINECT_REAL_NOISE, 7, 12), (KINECT_REAL_NOISE, 45, 11), (KINECT_REAL_NOISE, 100, 1),
    (KINECT_REAL_NOISE, 137, 10), (KINECT_NOISE, 53, 9),
    # ... and whose first look lost to the box with its ends and wins without them:
    (KINECT_REAL_NOISE, 15, 11), (KINECT_REAL_NOISE, 27, 1), (KINECT_REAL_NOISE, 30, 1),
    (KINECT_REAL_NOISE, 47, 2), (KINECT_REAL_NOISE, 52, 1), (KINECT_REAL_NOISE, 58, 11)])
def test_cans_whose_ends_are_left_out_of_the_round_rival_are_cylinders(noise, seed, gt_id):
    # Cans at 0.7-1.2 m, most of them lying, whose side the box beat while the round
    # rival took their flat ends as curved (cuboids before, r 23-36 mm); with the ends
    # kept planar the rival finds the side (radius within 1.3 mm, length within 6 mm).
    scene = render_clutter(seed, noise)
    assert scene.kinds[gt_id] in ("can", "lying_can")
    obj = _best(scene, gt_id)
    assert obj.type == "cylinder", obj.reason
    truth = scene.objects[gt_id].dimensions
    assert obj.dimensions["radius"] == pytest.approx(truth["radius"], abs=2.0 * MM)
    assert obj.dimensions["height"] == pytest.approx(truth["height"], abs=8.0 * MM)


def test_an_inner_floor_is_the_cavity_and_a_lid_is_not():
    # A round solid about the z axis (centre 0.75 m from the sensor at the origin, either
    # axis sign). A lid at its near end (z = 0.71 m) faces the sensor from outside; a floor
    # at its far end (z = 0.79 m), seen through the opening, faces the sensor from inside.
    # Both normals point towards the sensor (-z).
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.02, 0.02, (50, 2))
    points = np.vstack([np.column_stack([xy, np.full(50, 0.71)]),
                        np.column_stack([xy, np.full(50, 0.79)])])
    towards_sensor = np.array([0.0, 0.0, -1.0])
    faces = [SimpleNamespace(info=SimpleNamespace(planar=True, normal=towards_sensor),
                             points=np.arange(0, 50)),
             SimpleNamespace(info=SimpleNamespace(planar=True, normal=towards_sensor),
                             points=np.arange(50, 100))]
    cloud = SimpleNamespace(points=points, faces=faces, params=ModelingParams())
    for rotation in (np.eye(3), np.diag([1.0, -1.0, -1.0])):
        solid = SimpleNamespace(rotation=rotation, center=np.array([0.0, 0.0, 0.75]))
        floor = cavity_floor(cloud, solid)
        assert not floor[:50].any() and floor[50:].all()


def test_a_cup_reaching_down_to_the_desk_is_not_beaten_by_the_box_of_its_flat_cores():
    # Clutter seed 52, noise-free: the cylinder's cost counted its inner floor, 8 mm inside
    # the solid once the cup reaches the desk, and the box of its flat cores won.
    obj = _best(render_clutter(52, None), 6)
    assert obj.type == "cylinder", obj.reason
    assert "does not replace cylinder" in obj.reason


def test_a_cup_whose_facets_meet_concavely_is_still_round():
    # kinect-real clutter seed 106, cup 6: two planar facets of its walls meet in a concave
    # corner (the inner wall seen through the opening). The model graph's cuboid is no
    # box, but the round model of all its faces replaces it as for any cuboid.
    obj = _best(render_clutter(106, KINECT_REAL_NOISE), 6)
    assert obj.type == "cylinder", obj.reason
    assert "concave corner" in obj.reason


# ------------------------------------------------------ a lid joined to the side as one face
#: A can 56 mm across and 100 mm tall, a cone 70 mm across and 90 mm tall, a cup 60 mm
#: across at its foot and 76 mm at its rim, 90 mm tall.
SMALL_CAN = (0.028, 0.100)


def _seen_from_above(item, distance: float, elevation_deg: float, rng: int):
    scene = render_layout([item], [0], camera_pose(distance, math.radians(elevation_deg), 0.4),
                          noise=KINECT_REAL_NOISE, rng=rng)
    return _best(scene, 1)


@pytest.mark.parametrize("distance,elevation,rng", [
    (0.9, 68.0, 0), (0.9, 74.0, 2), (1.05, 62.0, 0), (1.05, 68.0, 1), (1.05, 74.0, 0)])
def test_a_small_can_whose_lid_joined_its_side_is_the_cylinder_below_the_lid(distance,
                                                                             elevation, rng):
    # Under kinect-real noise at 0.9-1.05 m the lid of a can 56 mm across and the grazing
    # strips of its side are one curved face, and a wide cone through both verified (cones
    # and frustums before). The lid as a planar face, the rest as the side, gives the can.
    obj = _seen_from_above(make_can(*SMALL_CAN), distance, elevation, rng)
    assert obj.type == "cylinder", obj.reason
    assert "the cylinder below its lid" in obj.reason
    assert obj.dimensions["radius"] == pytest.approx(SMALL_CAN[0], abs=2.0 * MM)
    assert obj.dimensions["height"] == pytest.approx(SMALL_CAN[1], abs=5.0 * MM)


@pytest.mark.parametrize("distance,elevation,rng", [(0.9, 68.0, 0), (1.05, 62.0, 0),
                                                    (1.05, 74.0, 0)])
def test_a_cone_or_a_cup_seen_the_same_way_keeps_its_shape(distance, elevation, rng):
    # No plane of theirs is the lid of a cylinder that holds the rest and costs less.
    cone = _seen_from_above(make_cone(0.035, 0.09), distance, elevation, rng)
    assert cone.type == "cone", cone.reason
    assert cone.dimensions["radius"] == pytest.approx(0.035, abs=3.0 * MM)
    cup = _seen_from_above(make_container(0.030, 0.038, 0.090), distance, elevation, rng)
    assert cup.type in ("frustum", "cylinder"), cup.reason
    # Its radius (a cylinder's: the wall's middle) between the foot's and the rim's.
    assert 0.030 - 2.0 * MM <= cup.dimensions["radius"] <= 0.038 + 2.0 * MM
    for obj in (cone, cup):
        assert not re.search(r"the cylinder below its lid \(cost [0-9.]+\) replaces", obj.reason)


@pytest.mark.parametrize("seed,gt_id", [(22, 10), (27, 3), (100, 5), (100, 14)])
def test_cans_in_clutter_seen_as_wide_cones_are_the_cylinders_below_their_lids(seed, gt_id):
    # kinect-real clutter at 0.84-1.0 m: cones of 90, 74, 86 and 98 mm radius before. The
    # lid of held-out seed 100's can 14 (r 34 mm) is no disc end all round under the
    # noise, but its outline follows the cylinder's circle (a cone before section 61).
    _is_the_cans_cylinder(render_clutter(seed, KINECT_REAL_NOISE), gt_id)


def test_a_can_whose_largest_plane_is_its_side_has_the_lid_that_faces_up():
    # Held-out kinect-real seed 107's can 7 (r 29.5 mm at 0.99 m) was a cone of r 58 mm:
    # the largest plane RANSAC finds in it lies through its side (88 deg off its axis),
    # and no cylinder stands below that. The lid sought among the points whose normals
    # face along the support's normal gives the can.
    scene = render_clutter(107, KINECT_REAL_NOISE)
    _is_the_cans_cylinder(scene, 7)
    assert "the cylinder below its lid" in _best(scene, 7).reason


def test_a_tall_can_far_away_has_the_lid_that_faces_up():
    # Held-out seed 114's can 5 (r 28.3 mm, 152 mm tall, at 1.19 m; a cone of r 122 mm
    # before), the same way: the radius within 2.5 mm there (a fit over a side seen 4-5 mm
    # noisy per pixel), the height within 5 mm.
    scene = render_clutter(114, KINECT_REAL_NOISE)
    obj = _best(scene, 5)
    assert obj.type == "cylinder", obj.reason
    truth = scene.objects[5].dimensions
    assert obj.dimensions["radius"] == pytest.approx(truth["radius"], abs=2.5 * MM)
    assert obj.dimensions["height"] == pytest.approx(truth["height"], abs=5.0 * MM)


def test_a_pot_whose_top_faces_up_keeps_its_frustum():
    # The sensor suite's closed pot (r 50 -> 32 mm, 80 mm tall) at 1.5 m under kinect-real
    # noise, modeled from its true labels: its top faces up and the cylinder below it
    # verifies, but holds the points no closer than the frustum (0.034 against 0.018 was
    # measured); a version that let the cheaper of the two lids compete on average made
    # a pot of this suite a cylinder.
    objects, truth, _ = suite_true_labels("set_c", 1.5, "kinect-real", 2)
    pot = objects[1]
    assert pot.type == "frustum", pot.reason
    assert re.search(r"the cylinder below its lid facing up \(cost [0-9.]+\) does not replace "
                     r"frustum", pot.reason)
    assert pot.dimensions["radius"] == pytest.approx(truth[1].dimensions["radius"], abs=5.0 * MM)


def _is_the_cans_cylinder(scene, gt_id: int) -> None:
    """Assert that the can ``gt_id`` is a cylinder of its radius (2 mm) and height (5 mm)."""
    assert scene.kinds[gt_id] == "can"
    obj = _best(scene, gt_id)
    assert obj.type == "cylinder", obj.reason
    truth = scene.objects[gt_id].dimensions
    assert obj.dimensions["radius"] == pytest.approx(truth["radius"], abs=2.0 * MM)
    assert obj.dimensions["height"] == pytest.approx(truth["height"], abs=5.0 * MM)


def _cone_side(radius: float = 0.035) -> np.ndarray:
    """Return the sensor's side of a cone about z: apex at z = 0.7 m, base 100 mm beyond."""
    phi, t = np.meshgrid(np.linspace(-2.0, -1.1, 30), np.linspace(0.05, 1.0, 50))
    r, z = radius * t.ravel(), 0.7 + 0.1 * t.ravel()
    return np.column_stack([r * np.cos(phi.ravel()), r * np.sin(phi.ravel()), z])


#: Round solids about the z axis between z = 0.7 and 0.8 m: a cylinder of r 35 mm and cones
#: of r 35 and 70 mm at their base, their apex at z = 0.7 m (rotation z: base -> apex).
CAN_CYLINDER = Primitive(3, PrimitiveType.CYLINDER, np.array([0.0, 0.0, 0.75]), np.eye(3),
                         {"radius": 0.035, "height": 0.1}, 1, 0.0)
APEX_UP = np.diag([1.0, -1.0, -1.0])


def _cone(radius: float) -> Primitive:
    return Primitive(3, PrimitiveType.CONE, np.array([0.0, 0.0, 0.75]), APEX_UP,
                     {"radius": radius, "height": 0.1}, 1, 0.0)


@pytest.mark.parametrize("points,cone,kind", [
    ("can", 0.070, "cylinder"),    # a can's lid and side: the wide cone costs more
    ("cone", 0.035, "cone")])      # a cone's side: the cylinder costs more
def test_the_cylinder_below_a_lid_replaces_a_cone_only_where_it_costs_less(monkeypatch, points,
                                                                            cone, kind):
    cloud = _lid_and_sides(True) if points == "can" else SimpleNamespace(
        oid=3, points=_cone_side(), params=ModelingParams(ransac_threshold=0.001))
    monkeypatch.setattr(strategies, "_lid_and_side", lambda *_a, **_k: SimpleNamespace())
    monkeypatch.setattr(strategies, "lid_cylinder",
                        lambda *_a, **_k: (CAN_CYLINDER, SimpleNamespace(faces=[])))
    monkeypatch.setattr(strategies, "_lid_facing_up", lambda *_a, **_k: None)
    reasons = []
    got, _ = strategies.prefer_lid_cylinder(SimpleNamespace(cloud=cloud), _cone(cone), (),
                                            reasons)
    assert got.type == kind
    assert len(reasons) == 1 and reasons[0].startswith("the cylinder below its lid")
    # With fixed noise settings nothing is compared.
    cloud.params = ModelingParams(ransac_threshold=0.001, noise_model="fixed")
    got, _ = strategies.prefer_lid_cylinder(SimpleNamespace(cloud=cloud), _cone(cone), (), [])
    assert got.type == "cone"


@pytest.mark.parametrize("noise,seed,gt_id", [
    (KINECT_REAL_NOISE, 20, 9), (KINECT_REAL_NOISE, 104, 12), (KINECT_NOISE, 24, 1)])
def test_cans_close_below_the_camera_whose_side_is_seen_grazing_are_cylinders(noise, seed,
                                                                             gt_id):
    # Cans 0.35-0.45 m from the camera, nearly below it: a few per cent of the side's
    # points are seen within 70 deg of its normal, all on the lid's rounded rim, and they
    # scattered 2.2-3.2 times the noise about a cylinder within 1 mm of the can's (unknown
    # before). The scatter along the rays is not judged from so few points.
    _is_the_cans_cylinder(render_clutter(seed, noise), gt_id)


@pytest.mark.parametrize("noise,seed,gt_id", [
    (KINECT_REAL_NOISE, 8, 4), (KINECT_REAL_NOISE, 55, 6), (KINECT_NOISE, 3, 3)])
def test_cans_no_model_fitted_are_the_cylinders_below_their_lids(noise, seed, gt_id):
    # Cans whose faces fit no rule (facets at no right angles: seeds 8 and 3) or whose
    # round fits all failed (seed 55: axes off its planar face, scatter beyond the noise)
    # were `unknown`; the cylinder below the lid costs less than a sphere of them.
    scene = render_clutter(seed, noise)
    _is_the_cans_cylinder(scene, gt_id)
    assert "the cylinder below its lid" in _best(scene, gt_id).reason


@pytest.mark.parametrize("seed,gt_id", [(58, 9), (120, 8)])
def test_balls_whose_cap_passes_as_a_lid_are_no_cylinders(seed, gt_id):
    # Balls of r 29-30 mm under kinect-real noise: a cap of each passes as a lid and the
    # cylinder below it verifies (r 28.5 mm, 29.5 mm tall), but the sphere of the whole
    # ball costs far less (0.010-0.013 against 0.047-0.072).
    scene = render_clutter(seed, KINECT_REAL_NOISE)
    assert scene.kinds[gt_id] == "sphere"
    obj = _best(scene, gt_id)
    assert obj.type != "cylinder", obj.reason
    assert re.search(r"the cylinder below its lid \(cost [0-9.]+\) not kept", obj.reason)
