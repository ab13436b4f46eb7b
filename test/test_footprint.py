"""Two boxes side by side in one segment, parted by their footprints.

Two boxes standing against each other at different headings, their tops at one height,
come as one segment that one cuboid holds; the sensor then sees through that cuboid where
the rectangle round both footprints is empty (:func:`~geomodel_ros.core.footprint.
seen_through`), and the line parting the footprint into two rectangles of least joint
area parts the boxes (:func:`~geomodel_ros.core.footprint.footprint_split`). Expected
counts, lines and sizes are worked out from the geometry given or rendered
(:mod:`geomodel_ros.tools.synth.clutter`), never from the code's output.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from geomodel_ros.core.compounds import _parts_of_one_box, _SeenThrough
from geomodel_ros.core.footprint import Returns, footprint_split, seen_through
from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import Primitive, PrimitiveType
from geomodel_ros.tools.bench_clutter import OPTIONAL_NOISE
from geomodel_ros.tools.synth.clutter import (KINECT_CAMERA, KINECT_NOISE, CAMERA_ELEVATION,
                                              camera_pose, footprints_overlap, make_box,
                                              render_clutter, render_layout)
from suite_helpers import best_object_and_labels, box_sizes, scene_iou

MM = 1e-3
#: Noise-free sizes: an edge is known to about a pixel, 1.6 mm at 0.9 m on the 640 x 480
#: Kinect grid (focal length ~580 px).
EDGE_TOL = 1.6 * MM
#: The two boxes (length, width, height; their heights 2 mm apart, as kinect-real clutter
#: seed 75's), the second turned TURN from the first.
FIRST = (0.12, 0.095, 0.14)
SECOND = (0.138, 0.048, 0.138)
YAW = 0.3
TURN = math.radians(30.0)


def _grid_rectangle(center, half, angle, step=2 * MM):
    """Points (n, 2) on a ``step`` grid over a rectangle turned ``angle`` [rad]."""
    u = np.arange(-half[0] + step / 2, half[0], step)
    v = np.arange(-half[1] + step / 2, half[1], step)
    uu, vv = np.meshgrid(u, v)
    c, s = math.cos(angle), math.sin(angle)
    local = np.stack([uu.ravel(), vv.ravel()], axis=1)
    return np.asarray(center) + local @ np.array([[c, s], [-s, c]])


def _two_rectangles(turn, gap=1 * MM):
    """Return a rectangle 120 x 95 mm on the axes, one 138 x 48 mm turned ``turn`` beside it.

    The second's extent along x is 69 cos + 24 sin of its turn either side of its
    centre, which lies that far plus ``gap`` beyond the first's side at x = 60 mm: the
    line x = 60 mm + gap / 2 parts them.
    """
    first = _grid_rectangle((0.0, 0.0), (0.060, 0.0475), 0.0)
    reach = 0.069 * math.cos(turn) + 0.024 * math.sin(turn)
    second = _grid_rectangle((0.060 + gap + reach, 0.0), (0.069, 0.024), turn)
    return np.vstack([first, second]), np.r_[np.zeros(len(first), bool),
                                              np.ones(len(second), bool)]


@pytest.mark.parametrize("turn_deg", [13.0, 30.0, 45.0])
def test_two_turned_rectangles_are_parted_by_the_line_between_them(turn_deg):
    xy, second = _two_rectangles(math.radians(turn_deg))
    side = footprint_split(xy, 150)
    assert side is not None
    assert np.array_equal(side, second) or np.array_equal(side, ~second)


def test_the_parting_line_turned_with_the_footprint():
    # The same two rectangles turned 70 deg together: the line turns with them.
    xy, second = _two_rectangles(TURN)
    c, s = math.cos(1.2), math.sin(1.2)
    side = footprint_split(xy @ np.array([[c, s], [-s, c]]) + [0.3, -0.2], 150)
    assert side is not None
    assert np.array_equal(side, second) or np.array_equal(side, ~second)


def test_no_parting_into_rectangles_of_one_heading():
    # Rectangles turned 13 deg against each other part with min_turn 8 deg, not with 15
    # deg; two rectangles of one heading side by side (one box's two halves, 1 mm apart)
    # part with none and not with 8 deg.
    xy, second = _two_rectangles(math.radians(13.0))
    side = footprint_split(xy, 150, math.radians(8.0))
    assert side is not None and (np.array_equal(side, second) or np.array_equal(side, ~second))
    assert footprint_split(xy, 150, math.radians(15.0)) is None
    halves = np.vstack([_grid_rectangle((0.0, 0.0), (0.060, 0.0475), 0.4),
                        _grid_rectangle((0.1215 * math.cos(0.4), 0.1215 * math.sin(0.4)),
                                        (0.060, 0.0475), 0.4)])
    assert footprint_split(halves, 150) is not None
    assert footprint_split(halves, 150, math.radians(8.0)) is None


def test_no_part_smaller_than_min_points():
    xy, second = _two_rectangles(TURN)
    assert footprint_split(xy[:299], 150) is None  # fewer than two parts' worth
    # A second footprint of fewer points than asked is never a part of its own.
    small = _grid_rectangle((0.095, 0.0), (0.03, 0.01), 0.5, step=3 * MM)  # 60 points
    xy = np.vstack([_grid_rectangle((0.0, 0.0), (0.060, 0.0475), 0.0), small])
    side = footprint_split(xy, 150)
    if side is not None:
        assert min(np.count_nonzero(side), np.count_nonzero(~side)) >= 150


def _box(center, half, oid=1):
    return Primitive(oid, PrimitiveType.CUBOID, np.asarray(center, float), np.eye(3),
                     {"length": 2 * half, "width": 2 * half, "height": 2 * half}, 100, 0.0)


def _wall(z, half=0.3, step=5 * MM):
    u = np.arange(-half, half + step / 2, step)
    xx, yy = np.meshgrid(u, u)
    return np.stack([xx.ravel(), yy.ravel(), np.full(xx.size, z)], axis=1)


def test_a_wall_behind_a_box_seen_through_it():
    # A cube 0.2 m across at 1 m on the optical axis, a wall at 1.5 m. A ray from the
    # origin to the wall point (x, y, 1.5) enters the cube shrunk by w / 2 through its
    # front face z = 0.9 + w / 2 (its spread grows with depth: it leaves the square
    # sideways only after entering), so where max(|x|, |y|) (0.9 + w / 2) / 1.5 <
    # 0.1 - w / 2; the wall lies far beyond that entry.
    w = 0.01
    wall = _wall(1.5)
    box = _box((0.0, 0.0, 1.0), 0.1)
    bound = (0.1 - w / 2) * 1.5 / (0.9 + w / 2)
    expected = int(np.count_nonzero(np.max(np.abs(wall[:, :2]), axis=1) < bound))
    assert expected > 500
    labels = np.full(len(wall), 7)
    assert seen_through(box, Returns(wall, 1), labels, w) == expected
    # Counted on every fourth return and scaled back (the default), within 5 %.
    assert seen_through(box, Returns(wall), labels, w) == pytest.approx(expected, rel=0.05)
    # The same points labelled the box's own are no evidence against it.
    assert seen_through(box, Returns(wall, 1), np.full(len(wall), 1), w) == 0


def test_returns_in_front_of_or_within_a_band_behind_the_entry_are_not_seen_through():
    w = 0.01
    box = _box((0.0, 0.0, 1.0), 0.1)
    # A plane in front of the cube (an occluder), and one just behind its shrunk front
    # face, less than w beyond the entry (noise on the front face itself).
    for z in (0.7, 0.9 + w / 2 + 0.8 * w):
        plane = _wall(z, half=0.05)
        assert seen_through(box, Returns(plane, 1), np.full(len(plane), 7), w) == 0
    # ... one w and more beyond the entry is.
    plane = _wall(0.9 + w / 2 + 1.2 * w, half=0.05)
    assert seen_through(box, Returns(plane, 1), np.full(len(plane), 7), w) == len(plane)


def test_rows_without_a_return_and_other_types_count_nothing():
    w = 0.01
    wall = _wall(1.5)
    wall[::3] = np.nan
    wall[1::3] = 0.0
    rays = Returns(wall, 1)
    labels = np.full(len(wall), 7)
    box = _box((0.0, 0.0, 1.0), 0.1)
    bound = (0.1 - w / 2) * 1.5 / (0.9 + w / 2)
    kept = _wall(1.5)[2::3]
    assert seen_through(box, rays, labels, w) == int(np.count_nonzero(
        np.max(np.abs(kept[:, :2]), axis=1) < bound))
    # Garbage rows (finite but far beyond any sensor, beyond float32) count nothing and
    # raise nothing.
    junk = np.vstack([wall, [[1e300, 0.0, 1.5], [0.0, -1e300, 1e300], [1e30, 1e30, 1e30]]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert seen_through(box, Returns(junk, 1), np.full(len(junk), 7), w) == \
            seen_through(box, rays, labels, w)
    sphere = Primitive(1, PrimitiveType.SPHERE, np.array([0.0, 0.0, 1.0]), np.eye(3),
                       {"radius": 0.1}, 100, 0.0)
    assert seen_through(sphere, rays, labels, w) == 0
    # A box round the sensor, or thinner than the band, tells nothing.
    assert seen_through(_box((0.0, 0.0, 0.05), 0.1), rays, labels, w) == 0
    assert seen_through(_box((0.0, 0.0, 1.0), 0.004), rays, labels, w) == 0


def _round(kind, center, rotation, **dims):
    return Primitive(1, kind, np.asarray(center, float), np.asarray(rotation, float), dims,
                     100, 0.0)


def _sampled_count(inside, wall, w, samples=6000):
    # Independent of the crossing's algebra: each wall point's ray sampled densely; it
    # counts when a sample lies in the inner solid and the point lies farther than w
    # beyond the first such sample.
    t = np.linspace(0.0, 1.0, samples)
    count = 0
    for p in wall:
        hit = np.flatnonzero(inside(t[:, None] * p))
        count += bool(len(hit)) and (1.0 - t[hit[0]]) * np.linalg.norm(p) > w
    return count


def test_free_space_inside_a_cylinder_seen_end_on():
    # A cylinder of radius 0.1 m and height 0.2 m centred 1 m down the optical axis, its
    # axis the optical axis, before the wall at 1.5 m: as for the cube, the ray enters the
    # inner solid through its front disc, where hypot(x, y) (0.9 + w / 2) / 1.5 <
    # 0.1 - w / 2.
    w = 0.01
    wall = _wall(1.5)
    rays, labels = Returns(wall, 1), np.full(len(wall), 7)
    can = _round(PrimitiveType.CYLINDER, (0.0, 0.0, 1.0), np.eye(3), radius=0.1, height=0.2)
    bound = (0.1 - w / 2) * 1.5 / (0.9 + w / 2)
    expected = int(np.count_nonzero(np.hypot(wall[:, 0], wall[:, 1]) < bound))
    assert expected > 1000
    assert seen_through(can, rays, labels, w) == expected
    # A frustum looks into the cylinder of its smaller radius; a cone and a sphere into
    # nothing.
    cup = _round(PrimitiveType.FRUSTUM, (0.0, 0.0, 1.0), np.eye(3), radius=0.1,
                 top_radius=0.05, height=0.2)
    bound = (0.05 - w / 2) * 1.5 / (0.9 + w / 2)
    assert seen_through(cup, rays, labels, w) == int(np.count_nonzero(
        np.hypot(wall[:, 0], wall[:, 1]) < bound))
    cone = _round(PrimitiveType.CONE, (0.0, 0.0, 1.0), np.eye(3), radius=0.1, height=0.2)
    assert seen_through(cone, rays, labels, w) == 0
    # Its own returns and a cylinder thinner than the band tell nothing.
    assert seen_through(can, rays, np.full(len(wall), 1), w) == 0
    thin = _round(PrimitiveType.CYLINDER, (0.0, 0.0, 1.0), np.eye(3), radius=0.004,
                  height=0.2)
    assert seen_through(thin, rays, labels, w) == 0


@pytest.mark.parametrize("center, axis", [((0.0, 0.0, 1.0), (1.0, 0.0, 0.0)),
                                          ((0.05, -0.08, 1.1), (0.6, 0.0, 0.8)),
                                          ((-0.1, 0.1, 1.0), (0.0, 0.6, -0.8))])
def test_free_space_inside_a_cylinder_at_any_heading_by_sampled_rays(center, axis):
    # A cylinder of radius 0.06 m, 0.24 m long, lying across the view or tilted, counted
    # against every wall ray sampled at 6,000 steps (a ray grazing the boundary may differ).
    w = 0.01
    wall = _wall(1.5, half=0.25, step=10 * MM)
    axis = np.asarray(axis) / np.linalg.norm(axis)
    e1 = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    rotation = np.stack([e1, np.cross(axis, e1), axis], axis=1)
    can = _round(PrimitiveType.CYLINDER, center, rotation, radius=0.06, height=0.24)

    def inside(q):
        local = (q - np.asarray(center)) @ rotation
        return (np.hypot(local[:, 0], local[:, 1]) < 0.06 - w / 2) & (
            np.abs(local[:, 2]) < 0.12 - w / 2)

    expected = _sampled_count(inside, wall, w)
    assert expected > 100
    got = seen_through(can, Returns(wall, 1), np.full(len(wall), 7), w)
    assert abs(got - expected) <= 2


@pytest.mark.parametrize("seen_first, seen_second", [(True, False), (False, True),
                                                     (False, False)])
def test_a_split_is_seen_through_when_either_part_is(seen_first, seen_second):
    # The wall of the test above; a cube on the axis in front of it is seen through, one
    # 0.5 m aside (nothing behind it) is not. The split object's own rows (the first
    # two) are relabelled to the two parts; every other return is the wall's. The whole
    # held no more free space than an object's worth: the bar is seg_min_cluster_points.
    wall = _wall(1.5)
    labels = np.full(len(wall), 7)
    seen = _SeenThrough(wall, ModelingParams(), None)
    first = _box((0.0, 0.0, 1.0) if seen_first else (0.5, 0.0, 1.0), 0.1, oid=1)
    second = _box((0.0, 0.0, 1.0) if seen_second else (-0.5, 0.0, 1.0), 0.1, oid=1)
    rows, in_second = np.array([0, 1]), np.array([False, True])
    assert seen.either(0, first, second, rows, in_second, 9, labels) == (
        seen_first or seen_second)


def test_a_part_is_still_seen_through_only_with_half_the_whole_s_free_space():
    # The cube on the axis before the wall holds c returns of free space (the count
    # worked out by hand in the test above, sampled every fourth return: within 5 %).
    # Its parting is refused while it keeps half the whole's count or more, kept when
    # the whole held more than twice as much (the parting explained most of it).
    wall = _wall(1.5)
    labels = np.full(len(wall), 7)
    seen = _SeenThrough(wall, ModelingParams(), None)
    part = _box((0.0, 0.0, 1.0), 0.1, oid=1)
    other = _box((0.5, 0.0, 1.0), 0.1, oid=1)
    c = seen.count(part, labels)
    w = ModelingParams().ransac_threshold
    bound = (0.1 - w / 2) * 1.5 / (0.9 + w / 2)
    assert c == pytest.approx(np.count_nonzero(np.max(np.abs(wall[:, :2]), axis=1) < bound),
                              rel=0.05)
    assert c > 2 * ModelingParams().seg_min_cluster_points
    rows, in_second = np.array([0, 1]), np.array([False, True])
    for whole, still in ((0, True), (c, True), (2 * c, True), (2 * c + 4, False),
                         (10 * c, False)):
        assert seen.either(whole, part, other, rows, in_second, 9, labels) == still, whole
        assert seen.either(whole, other, part, rows, in_second, 9, labels) == still, whole
    # An object's worth stays the least bar: a part that holds fewer returns is never
    # seen through, whatever the whole held.
    assert not seen.either(0, other, other, rows, in_second, 9, labels)


def _cuboid(yaw_deg, oid=1, x=0.0, y=0.0):
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    return Primitive(oid, PrimitiveType.CUBOID, np.array([x, y, 1.0]),
                     np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]),
                     {"length": 0.12, "width": 0.05, "height": 0.1}, 100, 0.0)


@pytest.mark.parametrize("second_yaw, kind, one", [
    (30.0, PrimitiveType.CUBOID, False),   # two boxes turned 30 deg: a pair
    (120.0, PrimitiveType.CUBOID, False),  # turned 30 deg modulo a quarter turn
    (5.0, PrimitiveType.CUBOID, True),     # within angle_tolerance (8 deg): one heading
    (90.0, PrimitiveType.CUBOID, True),    # a quarter turn: one heading
    (30.0, PrimitiveType.CYLINDER, True),  # a box and no box
])
def test_the_footprint_s_parts_are_two_boxes_turned_against_each_other(second_yaw, kind, one):
    first = _cuboid(0.0)
    second = _cuboid(second_yaw, 2, 0.2)
    if kind != PrimitiveType.CUBOID:
        second = Primitive(2, kind, second.center, second.rotation,
                           {"radius": 0.03, "height": 0.1}, 100, 0.0)
    points = np.zeros((10, 3))
    assert _parts_of_one_box("footprint", first, second, points, ModelingParams(), None) == one
    # Stricter than the levels' rule: two boxes of one heading beside each other, 30 mm
    # apart across (one section neither way), are two there.
    assert not _parts_of_one_box("level", first, _cuboid(0.0, 2, 0.2, 0.03), points,
                                 ModelingParams(), None)


# --------------------------------------------------------------------------- scenes
def _touching(first, second, direction):
    """``second`` moved along ``direction`` [rad] until it just clears ``first``."""
    d = np.array([math.cos(direction), math.sin(direction)])
    lo, hi = 0.0, 1.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if footprints_overlap(first.footprint, second.at(d * mid).footprint):
            lo = mid
        else:
            hi = mid
    return second.at(d * (hi + 0.5 * MM))


def _two_boxes(pose, noise=None):
    first = make_box(*FIRST, yaw=YAW)
    second = _touching(first, make_box(*SECOND, yaw=YAW + TURN), YAW + 0.4)
    return render_layout([first, second], [0, 0], pose, noise=noise, rng=3)


def test_two_boxes_turned_30_deg_against_each_other_are_two_boxes():
    # Noise-free from 0.9 m, 35 deg above the desk: one cuboid 112 x 140 x 287 mm held the
    # second box and part of the first.
    scene = _two_boxes(camera_pose(0.9, math.radians(35.0), 0.0))
    found = []
    for gt_id, size in ((1, FIRST), (2, SECOND)):
        obj, labels = best_object_and_labels(scene, gt_id)
        assert obj.type == "cuboid", obj.reason
        assert scene_iou(labels, scene, gt_id, obj.id) > 0.95
        assert box_sizes(obj) == pytest.approx(sorted(size), abs=EDGE_TOL)
        found.append(obj.id)
    assert found[0] != found[1]


LOW = (math.radians(15.0), math.radians(25.0))


@pytest.mark.parametrize("seed, views, pair, least_iou", [
    (75, CAMERA_ELEVATION, (1, 3), 0.85), (80, CAMERA_ELEVATION, (1, 2), 0.85),
    (22, LOW, (1, 7), 0.9), (29, LOW, (5, 10), 0.9)])
def test_kinect_real_clutter_boxes_side_by_side_are_two(seed, views, pair, least_iou):
    # Seed 75: boxes 120 x 95 x 142 and 138 x 48 x 140 mm turned 30 deg to each other at
    # 1.0-1.1 m; seed 80: 44 x 88 x 100 and 141 x 64 x 103 mm turned 13 deg at 1.2 m. One
    # cuboid held each pair (IoU 0.70 / 0.28 and 0.34 / 0.66).
    # Seen 15-25 deg above the desk, seed 22: boxes of 51 x 92 x 85 and 125 x 67 x 82 mm
    # came as one cylinder of 176 mm radius (IoU 0.40 / 0.58), the free space inside it
    # 2,428 returns. Seed 29: boxes of 72 x 71 x 98 and 69 x 48 x 97 mm, the first seen
    # over the second's top, came as one cuboid (IoU 0.19 / 0.77); its parting left 180 of
    # the whole's 19,460 returns of free space in the farther box (whose hidden side was
    # completed a little too far) and was refused.
    scene = render_clutter(seed, OPTIONAL_NOISE["kinect-real"], KINECT_CAMERA, views)
    assert [scene.kinds[g] for g in pair] == ["box", "box"]
    found = []
    for gt_id in pair:
        obj, labels = best_object_and_labels(scene, gt_id)
        assert obj.type == "cuboid", obj.reason
        assert scene_iou(labels, scene, gt_id, obj.id) > least_iou
        found.append(obj.id)
    assert found[0] != found[1]


def test_the_line_s_parts_keep_their_sizes():
    # Kinect-real seed 80's box 2 (141 x 64 x 103 mm at 1.2 m) beside box 1, whose top
    # continues its own: handed points by distance across the contact round by round it
    # came out 16 mm too deep. As the line parts them, its sizes are within the benchmark's
    # p90 size error under that noise (6.5 mm).
    scene = render_clutter(80, OPTIONAL_NOISE["kinect-real"], KINECT_CAMERA, CAMERA_ELEVATION)
    obj, _ = best_object_and_labels(scene, 2)
    truth = scene.objects[2].dimensions
    assert box_sizes(obj) == pytest.approx(
        sorted(truth[k] for k in ("length", "width", "height")), abs=6.5 * MM)


def test_a_box_whose_model_reaches_too_far_stays_whole():
    # Kinect-real clutter seed 72's box 14 (116 x 80 x 78 mm at 0.7 m): its cuboid is
    # 16 mm too wide and seen through (633 returns), but it is one box: the line's two
    # parts are no two boxes, and nothing is parted off it.
    scene = render_clutter(72, OPTIONAL_NOISE["kinect-real"], KINECT_CAMERA, CAMERA_ELEVATION)
    obj, labels = best_object_and_labels(scene, 14)
    assert obj.type == "cuboid", obj.reason
    assert scene_iou(labels, scene, 14, obj.id) > 0.95
    mine = labels[scene.label_image.ravel() == 14]
    assert np.count_nonzero((mine != obj.id) & (mine >= 0)) < 50


@pytest.mark.parametrize("noise, seed, gt_id", [
    ("kinect-class", 79, 6),   # 145 x 49 x 103 mm: parted into cuboids 66 and 49 mm deep
    ("kinect-class", 8, 10),   # 92 x 111 x 54 mm: parted into two cuboids of one heading
    ("kinect-class", 30, 6),   # 99 x 111 x 58 mm: likewise
    ("kinect-real", 136, 16),  # 144 x 45 x 51 mm: parted into a cuboid and a cylinder
])
def test_a_box_seen_through_is_not_cut_into_two_of_one_heading_or_a_box_and_no_box(
        noise, seed, gt_id):
    # Each box's model reaches too far on its hidden side and is seen through; the line
    # across its footprint leaves two cuboids of one heading (seeds 79, 8, 30, clutter
    # noise) or a cuboid and a cylinder (held-out seed 136): no two boxes turned against
    # each other.
    scene = render_clutter(seed, KINECT_NOISE if noise == "kinect-class"
                           else OPTIONAL_NOISE[noise], KINECT_CAMERA, CAMERA_ELEVATION)
    obj, labels = best_object_and_labels(scene, gt_id)
    assert obj.type == "cuboid", obj.reason
    assert scene_iou(labels, scene, gt_id, obj.id) > 0.95


def test_a_line_whose_parts_are_still_seen_through_parts_nothing():
    # Kinect-real clutter seed 103: box 6 (120 x 62 x 132 mm, 25,800 points) is seen
    # through; the footprint's line would hand 23,600 of its points to box 1 beside it,
    # a cuboid still seen through (3,100 returns): refused, box 6 stays whole.
    scene = render_clutter(103, OPTIONAL_NOISE["kinect-real"], KINECT_CAMERA,
                           CAMERA_ELEVATION)
    obj, labels = best_object_and_labels(scene, 6)
    assert obj.type == "cuboid", obj.reason
    assert scene_iou(labels, scene, 6, obj.id) > 0.95


def test_a_can_beside_a_box_from_low_is_parted_off_as_before():
    # Kinect-real clutter seed 26 from 15-25 deg above the desk: a can (r 28 mm) against
    # a box (48 x 97 x 128 mm), one cuboid seen through. The line (the footprint of their
    # fronts seen from low) cuts the box, and the can with a strip of it is no box: the
    # can's group off the box's model parts them as before.
    scene = render_clutter(26, OPTIONAL_NOISE["kinect-real"], KINECT_CAMERA, LOW)
    can, labels = best_object_and_labels(scene, 12)
    assert can.type == "cylinder", can.reason
    assert scene_iou(labels, scene, 12, can.id) > 0.95
    assert scene_iou(labels, scene, 1, int(np.bincount(
        labels[(scene.label_image.ravel() == 1) & (labels >= 0)]).argmax())) > 0.95


def test_a_can_on_a_box_seen_through_is_parted_at_the_level_as_before():
    # Kinect-real clutter seed 29: a can (r 30 mm) on a box (69 x 103 x 104 mm), one
    # cuboid seen through. The footprint's line leaves a cylinder reaching down through
    # the box and a plane: no two boxes. The level at the box's top parts them.
    scene = render_clutter(29, OPTIONAL_NOISE["kinect-real"], KINECT_CAMERA, CAMERA_ELEVATION)
    assert scene.bases[8] == 2
    can, labels = best_object_and_labels(scene, 8)
    assert can.type == "cylinder", can.reason
    assert scene_iou(labels, scene, 8, can.id) > 0.9
    box_id = int(np.bincount(labels[(scene.label_image.ravel() == 2) & (labels >= 0)]).argmax())
    assert box_id != can.id


def test_the_desk_below_a_wrong_round_model_stays_the_desk_s():
    # From 45 deg above the desk and 1.5 rad round it under kinect-real noise the two
    # boxes come as one segment modeled as a cylinder 279 mm in radius, 15 % of its turn
    # seen: no container looked into, so no open top, and none of the 216,000 desk points
    # below it is given to it as its floor (78,000 were).
    scene = _two_boxes(camera_pose(0.9, math.radians(45.0), 1.5),
                       OPTIONAL_NOISE["kinect-real"])
    labels, result = model_scene(scene.organized, ModelingParams())
    desk = scene.label_image.ravel() == 0
    supports = set(result.supports)
    taken = labels[desk & (labels >= 0) & ~np.isin(labels, list(supports))]
    assert len(taken) < 0.01 * np.count_nonzero(desk)
