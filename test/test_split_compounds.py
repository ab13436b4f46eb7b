"""A segment holding two bodies is split by their models (``compounds.split_compounds``).

Hand-built scenes seen from a sensor at the origin (optical frame, y down): a box and a
standing can in one segment come apart with the box's and the can's own sizes; objects
segmented apart and a single noisy can stay as they are. The body test (``_in_body``) on
exact primitives: a cup's inner wall, rim and floor belong to its body, a box beside it or
under it does not. End to end on clutter scenes with exact per-point truth: segments that
held a box and a can under Kinect-like noise are two objects; bowls and cups seen
without noise (inner floor, rim) and a box whose cuboid fits badly stay one. A segment no
model fits is split from the model of one of its faces (two cans side by side, a lying can
against a standing one); a torus and a can whose lid lies on its side's box stay whole.
"""

from __future__ import annotations

import numpy as np
import pytest

from geomodel_ros.core.compounds import (_bands_of_a_round_body, _faces_of_a_box, _in_body,
                                         _Part, _two_models, split_compounds)
from geomodel_ros.core.modeling import PartModeler, model_objects, model_scene
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import Primitive, PrimitiveType
from geomodel_ros.tools.synth import render_scene
from geomodel_ros.tools.synth.clutter import KINECT_NOISE, render_clutter
from geomodel_ros.tools.synth.scenes import KINECT_REAL_NOISE
from test_box_pieces import STEP, _box, _can_side, _disc, _prim

PARAMS = ModelingParams(noise_model="fixed")
BOX = (0.2, 0.15, 0.2)  # the box's x, y, z extents [m]
CORNER = np.array([0.0, 0.1, 0.9])  # its corner nearest the sensor [m]
RADIUS, HEIGHT = 0.04, 0.12  # the can [m]


def _box_and_can() -> tuple[np.ndarray, np.ndarray]:
    """Sample a box and a can on one floor, the can against the box's front face."""
    front, top, left = _box(*CORNER, BOX)
    floor_y = CORNER[1] + BOX[1]
    cx, cz = CORNER[0] + 0.1, CORNER[2] - RADIUS
    can = np.vstack([_can_side(cx, cz, floor_y - HEIGHT, floor_y, RADIUS),
                     _disc(cx, floor_y - HEIGHT, cz, 0.0, RADIUS)])
    # The front face's points behind the can are hidden from the sensor.
    scale = CORNER[2] / cz
    hidden = (np.abs(front[:, 0] - cx) < RADIUS * scale) & \
        (front[:, 1] > (floor_y - HEIGHT) * scale)
    return np.vstack([front[~hidden], top, left]), can


def _split(pts: np.ndarray, labels: np.ndarray):
    """Model ``pts`` with ``labels`` (fixed noise), then split; return labels and result."""
    result = model_objects(pts, labels, PARAMS)
    out = split_compounds(pts, labels, result, PARAMS, {}, None,
                          PartModeler(pts, PARAMS, {}, None))
    return out, result


def test_a_can_against_a_box_in_one_segment_is_split_into_both():
    box, can = _box_and_can()
    pts = np.vstack([box, can])
    labels = np.zeros(len(pts), dtype=np.int64)
    out, result = _split(pts, labels)
    types = sorted((o.type, o.id) for o in result.objects)
    assert [t for t, _ in types] == [PrimitiveType.CUBOID, PrimitiveType.CYLINDER]
    by_type = {o.type: o for o in result.objects}
    cuboid, cylinder = by_type[PrimitiveType.CUBOID], by_type[PrimitiveType.CYLINDER]
    assert sorted(cuboid.dimensions.values()) == pytest.approx(sorted(BOX), abs=2 * STEP)
    assert cylinder.dimensions["radius"] == pytest.approx(RADIUS, abs=1e-3)
    assert cylinder.dimensions["height"] == pytest.approx(HEIGHT, abs=2 * STEP)
    # Every point goes with its own body; the new id is above the labels given.
    assert np.all(out[:len(box)] == cuboid.id)
    assert np.all(out[len(box):] == cylinder.id)
    assert cylinder.id == 1 and cuboid.id == 0
    assert (cuboid.point_count, cylinder.point_count) == (len(box), len(can))
    assert np.all(labels == 0)  # the labels given are not changed in place


def test_a_box_and_a_can_segmented_apart_stay_as_they_are():
    box, can = _box_and_can()
    pts = np.vstack([box, can])
    labels = np.r_[np.zeros(len(box)), np.ones(len(can))].astype(np.int64)
    before = model_objects(pts, labels, PARAMS)
    out, result = _split(pts, labels)
    assert np.array_equal(out, labels)
    assert [(o.id, o.type, o.dimensions) for o in result.objects] == \
        [(o.id, o.type, o.dimensions) for o in before.objects]


def _two_cans() -> tuple[np.ndarray, np.ndarray]:
    """Sample two standing cans of other radii and heights touching side by side."""
    floor_y, z = 0.25, 0.8
    wide = np.vstack([_can_side(0.0, z, floor_y - 0.12, floor_y, 0.04),
                      _disc(0.0, floor_y - 0.12, z, 0.0, 0.04)])
    tall = np.vstack([_can_side(0.075, z, floor_y - 0.18, floor_y, 0.035),
                      _disc(0.075, floor_y - 0.18, z, 0.0, 0.035)])
    return wide, tall


def test_two_cans_in_one_unknown_segment_are_split_from_a_face_model():
    wide, tall = _two_cans()
    pts = np.vstack([wide, tall])
    labels = np.zeros(len(pts), dtype=np.int64)
    assert [o.type for o in model_objects(pts, labels, PARAMS).objects] == \
        [PrimitiveType.UNKNOWN]  # no one model holds both
    out, result = _split(pts, labels)
    assert [o.type for o in result.objects] == [PrimitiveType.CYLINDER] * 2
    by_id = {o.id: o for o in result.objects}
    own_wide, own_tall = by_id[out[0]], by_id[out[-1]]
    assert own_wide.id != own_tall.id
    assert own_wide.dimensions["radius"] == pytest.approx(0.04, abs=1e-3)
    assert own_tall.dimensions["radius"] == pytest.approx(0.035, abs=1e-3)
    assert own_wide.dimensions["height"] == pytest.approx(0.12, abs=2 * STEP)
    assert own_tall.dimensions["height"] == pytest.approx(0.18, abs=2 * STEP)
    assert np.all(out[:len(wide)] == own_wide.id) and np.all(out[len(wide):] == own_tall.id)


@pytest.mark.parametrize("noise", [None, KINECT_REAL_NOISE])
def test_an_irregular_object_stays_one_unknown_object(noise):
    # A torus: none of its faces is a body of its own.
    scene = render_scene("torus", noise=noise, rng=np.random.default_rng(1))
    labels, result = model_scene(scene.points, ModelingParams())
    torus = scene.labels == next(o.id for o in scene.objects if o.type == "torus")
    own = labels[torus]
    best = np.bincount(own[own >= 0]).argmax()
    assert np.mean(own == best) >= 0.95
    assert {o.id: o.type for o in result.objects}[best] == PrimitiveType.UNKNOWN


def test_a_noisy_can_alone_is_not_split():
    rng = np.random.default_rng(5)
    can = np.vstack([_can_side(0.05, 0.7, 0.1, 0.1 + HEIGHT, RADIUS),
                     _disc(0.05, 0.1, 0.7, 0.0, RADIUS)])
    can = can + rng.normal(0.0, 0.0007, can.shape)
    labels = np.zeros(len(can), dtype=np.int64)
    out, result = _split(can, labels)
    assert [o.type for o in result.objects] == [PrimitiveType.CYLINDER]
    assert np.all(out == 0)


# ------------------------------------------------------------------ the body test
R, H, THR = 0.04, 0.1, 0.002  # an upright cylinder at the origin, axis +z [m]
CYL = Primitive(0, PrimitiveType.CYLINDER, np.zeros(3), np.eye(3), {"radius": R, "height": H},
                100, 0.0)


def _ring(r_in: float, r_out: float, z: float) -> np.ndarray:
    """Sample the flat ring r_in <= rho < r_out at height ``z`` round the axis."""
    ring = _disc(0.0, z, 0.0, r_in, r_out)
    return ring[:, [0, 2, 1]]  # (x, y = height, z) -> (x, z, height)


def _wall(radius: float, z0: float, z1: float) -> np.ndarray:
    """Sample the circle of ``radius`` round the axis between heights z0 and z1."""
    ang = np.linspace(0.0, 2 * np.pi, 90, endpoint=False)
    a, z = np.meshgrid(ang, np.linspace(z0, z1, 20))
    return np.c_[radius * np.cos(a.ravel()), radius * np.sin(a.ravel()), z.ravel()]


def test_a_cups_inner_wall_rim_and_floor_belong_to_its_body():
    assert _in_body(CYL, _wall(R - 0.006, -0.03, H / 2), THR)  # inner wall, 6 mm deep
    assert _in_body(CYL, _ring(R - 0.006, 1.15 * R, H / 2 + 0.002), THR)  # rim with a lip
    assert _in_body(CYL, _ring(0.0, R - 0.006, H / 2 - 0.04), THR)  # inner floor


def test_a_box_beside_or_under_a_can_is_no_part_of_its_body():
    # The top face of a box the can stands on reaches 2.4 radii from the axis.
    assert not _in_body(CYL, _ring(0.0, 2.4 * R, -H / 2), THR)
    # A box face beside the can, outside its solid.
    face = np.c_[np.full(400, R + 0.001), np.repeat(np.linspace(-0.05, 0.05, 20), 20),
                 np.tile(np.linspace(-H / 2, H / 2, 20), 20)]
    assert not _in_body(CYL, face, THR)
    # A plane has no body.
    plane = Primitive(1, PrimitiveType.PLANE, np.zeros(3), np.eye(3),
                      {"length": 1.0, "width": 1.0}, 100, 0.0)
    assert not _in_body(plane, _wall(R - 0.006, -0.03, H / 2), THR)


def _plane(normal) -> Primitive:
    """Return a plane primitive of unit ``normal`` (its rotation's third column)."""
    n = np.asarray(normal, dtype=float) / np.linalg.norm(normal)
    u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    return Primitive(1, PrimitiveType.PLANE, np.zeros(3), np.c_[u, np.cross(n, u), n],
                     {"length": 0.1, "width": 0.1}, 100, 0.0)


def test_a_plane_along_a_box_face_may_be_that_box_face():
    yaw = np.radians(30.0)
    rot = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0],
                    [0.0, 0.0, 1.0]])
    box = Primitive(0, PrimitiveType.CUBOID, np.zeros(3), rot,
                    {"length": 0.1, "width": 0.1, "height": 0.1}, 100, 0.0)
    tol = PARAMS.angle_tolerance
    for axis in range(3):  # parallel to any face, up to the tolerance, either side
        assert _faces_of_a_box(box, _plane(rot[:, axis]), tol)
        assert _faces_of_a_box(_plane(-rot[:, axis]), box, tol)
    tilted = rot @ [np.cos(0.9 * tol), np.sin(0.9 * tol), 0.0]
    assert _faces_of_a_box(box, _plane(tilted), tol)
    assert _faces_of_a_box(_plane([0, 0, 1]), _plane([1, 0, 0]), tol)  # two planes
    # Not a face: a plane across the box's faces, or beside a round body.
    assert not _faces_of_a_box(box, _plane(rot @ [1.0, 1.0, 0.0]), tol)
    tilted = rot @ [np.cos(1.5 * tol), np.sin(1.5 * tol), 0.0]
    assert not _faces_of_a_box(box, _plane(tilted), tol)
    assert not _faces_of_a_box(CYL, _plane([0, 0, 1]), tol)


def test_coaxial_round_parts_are_bands_of_one_body():
    # A cup's wall (r 30 -> 39 mm) taken apart at a face border: a frustum below a
    # cylinder on the same axis (up to a few mm and degrees), in either order.
    tol = PARAMS.angle_tolerance
    low = _prim(PrimitiveType.FRUSTUM, (0.0, 0.0, 0.03), (0.0, 0.0, 1.0),
                radius=0.030, top_radius=0.036, height=0.06)
    tilt = np.array([np.sin(0.5 * tol), 0.0, np.cos(0.5 * tol)])
    high = _prim(PrimitiveType.CYLINDER, (0.004, 0.0, 0.09), tilt, radius=0.038, height=0.06)
    assert _bands_of_a_round_body(low, high, tol)
    assert _bands_of_a_round_body(high, low, tol)
    assert _bands_of_a_round_body(low, _prim(PrimitiveType.CONE, (0.0, 0.002, 0.1),
                                             (0.0, 0.0, -1.0), radius=0.04, height=0.05), tol)
    # What must stay two bodies: cans side by side (parallel axes, the sum of their
    # radii apart), a can lying on a can, a box or a ball beside a can.
    beside = _prim(PrimitiveType.CYLINDER, (0.07, 0.0, 0.03), (0.0, 0.0, 1.0),
                   radius=0.035, height=0.06)
    assert not _bands_of_a_round_body(low, beside, tol)
    lying = _prim(PrimitiveType.CYLINDER, (0.0, 0.0, 0.1), (1.0, 0.0, 0.0),
                  radius=0.03, height=0.12)
    assert not _bands_of_a_round_body(low, lying, tol)
    tilted = np.array([np.sin(1.5 * tol), 0.0, np.cos(1.5 * tol)])
    assert not _bands_of_a_round_body(low, _prim(PrimitiveType.CYLINDER, (0.0, 0.0, 0.09),
                                                 tilted, radius=0.038, height=0.06), tol)
    box = _prim(PrimitiveType.CUBOID, (0.0, 0.0, 0.09), (0.0, 0.0, 1.0),
                length=0.06, width=0.06, height=0.06)
    ball = _prim(PrimitiveType.SPHERE, (0.0, 0.0, 0.09), (0.0, 0.0, 1.0), radius=0.03)
    assert not _bands_of_a_round_body(low, box, tol)
    assert not _bands_of_a_round_body(ball, low, tol)


class _CountingModeler:
    """Stands for a PartModeler: every part is modeled as ``second``; calls are counted."""

    def __init__(self, second: Primitive) -> None:
        self.second, self.calls = second, 0

    def context(self, _labels):
        return None, None

    def __call__(self, _points, _object_id, _key, _context):
        self.calls += 1
        return self.second


@pytest.mark.parametrize("case, calls", [("band on the axis", 1), ("band 5 mm off", 1),
                                         ("lid", 1), ("another can", 3)])
def test_the_hand_off_starts_only_from_two_bodies(case, calls):
    # A can (r 40 mm, axis along y) modeled as its cylinder, and a second can 150 mm to its
    # side in the same segment. The second part starts from the other can's side or from
    # the first can's lid, and its first model is given here. A band of the first can's
    # side (a cylinder round its upper half, on its axis within half a radius) is the same
    # body, and so is the lid, which lies on the can's end: there is no second body to
    # hand points to, and no part is refitted (one model made). The other can's cylinder
    # is another body: the points nearer to it are handed over and both parts refitted
    # (two more models); the refits give the same pair, no split.
    side, lid = _can_side(0.0, 0.9, 0.0, HEIGHT, RADIUS), _disc(0.0, 0.0, 0.9, 0.0, RADIUS)
    other = _can_side(0.15, 0.9, 0.0, HEIGHT, RADIUS)
    pts = np.vstack([side, lid, other])
    whole = _prim(PrimitiveType.CYLINDER, (0.0, HEIGHT / 2, 0.9), (0.0, 1.0, 0.0),
                  radius=RADIUS, height=HEIGHT)
    group = np.zeros(len(pts), dtype=bool)
    if case == "lid":
        group[len(side):len(side) + len(lid)] = True
        second = _prim(PrimitiveType.PLANE, lid.mean(axis=0), (0.0, -1.0, 0.0),
                       length=2 * RADIUS, width=2 * RADIUS)
    else:
        group[len(side) + len(lid):] = True
        x = {"band on the axis": 0.0, "band 5 mm off": 0.005, "another can": 0.15}[case]
        y, height = (0.75 * HEIGHT, HEIGHT / 2) if x < 0.1 else (HEIGHT / 2, HEIGHT)
        second = _prim(PrimitiveType.CYLINDER, (x, y, 0.9), (0.0, 1.0, 0.0),
                       radius=RADIUS, height=height)
    assert _bands_of_a_round_body(whole, second, PARAMS.angle_tolerance) == case.startswith(
        "band")
    modeler = _CountingModeler(second)
    out = _two_models(whole, _Part(pts, np.arange(len(pts))), group, False, 1,
                      np.zeros(len(pts), dtype=np.int64), PARAMS, None, modeler)
    assert out is None
    assert modeler.calls == calls


# ------------------------------------------------------------------ end to end
def _best_iou(seed: int, noise, gt: int) -> tuple[float, int]:
    """IoU of clutter object ``gt`` with its best segment, and that segment's id."""
    scene = render_clutter(seed, noise)
    truth = scene.label_image.ravel()
    labels, _ = model_scene(scene.organized.reshape(-1, 3), ModelingParams(),
                            organized_shape=scene.label_image.shape)
    own = labels[truth == gt]
    best = int(np.bincount(own[own >= 0]).argmax())
    inter = np.count_nonzero(own == best)
    return inter / (np.count_nonzero(truth == gt) + np.count_nonzero(labels == best)
                    - inter), best


@pytest.mark.parametrize("seed, box, can", [(3, 6, 13), (26, 1, 12), (10, 1, 9), (32, 4, 9)])
def test_kinect_real_segments_of_a_box_and_a_can_are_two_objects(seed, box, can):
    # Before the split: one segment each, typed cylinder (seed 3) and cuboid (seed 26);
    # box IoU 0.48 / 0.54, can 0.51 / 0.44. Seeds 10 and 32 (a lying can) are split from
    # the model of one of their faces: the models of the whole, a cuboid and a cone,
    # hold both bodies within their bands (box IoU 0.37 / 0.66, can 0.61 / 0.34).
    iou_box, seg_box = _best_iou(seed, KINECT_REAL_NOISE, box)
    iou_can, seg_can = _best_iou(seed, KINECT_REAL_NOISE, can)
    assert seg_box != seg_can
    assert iou_box >= 0.9 and iou_can >= 0.9


def test_kinect_real_unknown_segments_of_two_bodies_are_two_objects():
    # Before: a lying can and a standing can in one `unknown` segment (IoU 0.60 / 0.39),
    # a ball with a box's face in another (ball 0.57).
    iou_lying, seg_lying = _best_iou(39, KINECT_REAL_NOISE, 1)
    iou_can, seg_can = _best_iou(39, KINECT_REAL_NOISE, 8)
    assert seg_lying != seg_can
    assert iou_lying >= 0.9 and iou_can >= 0.9
    assert _best_iou(8, KINECT_REAL_NOISE, 14)[0] >= 0.9


def test_kinect_real_ball_beside_a_bowl_is_split_though_a_refit_fails_on_the_way():
    # Seed 36: a ball (r 33.6 mm) and a bowl (r 53-86 mm) at 1 m in one segment, modeled
    # as one frustum. The group off it starts the ball's part; the first refit of the
    # bowl's part, which still holds a third of the ball, was `unknown` and the split
    # was given up (ball IoU 0.17). With the bowl's part keeping its model for the next
    # hand-off, the ball is a sphere of its own.
    scene = render_clutter(36, KINECT_REAL_NOISE)
    truth = scene.label_image.ravel()
    labels, result = model_scene(scene.organized.reshape(-1, 3), ModelingParams(),
                                 organized_shape=scene.label_image.shape)
    own = labels[truth == 2]
    ball = int(np.bincount(own[own >= 0]).argmax())
    assert np.mean(own == ball) >= 0.95 and np.mean(truth[labels == ball] == 2) >= 0.95
    model = {o.id: o for o in result.objects}[ball]
    assert model.type == PrimitiveType.SPHERE
    assert model.dimensions["radius"] == pytest.approx(0.0336, abs=0.004)
    # The bowl's segment holds no ball.
    own = labels[truth == 4]
    bowl = int(np.bincount(own[own >= 0]).argmax())
    assert bowl != ball
    assert np.count_nonzero((labels == bowl) & (truth == 2)) < 0.05 * np.count_nonzero(truth == 2)


@pytest.mark.parametrize("seed, gt", [(27, 3), (44, 9), (127, 2)])
def test_kinect_real_unknown_single_bodies_are_not_split(seed, gt):
    # Cans no model fitted whose side, modeled alone, is a box leave their lid on the box's
    # top face: the lid is part of that body (IoU 0.64 and 0.86 when it was split off).
    # A box no model fitted came apart into a cuboid and a plane along one of its faces
    # (IoU 0.50).
    assert _best_iou(seed, KINECT_REAL_NOISE, gt)[0] >= 0.9


def test_a_typed_segments_planar_faces_seed_no_split():
    # Kinect-class seed 104: a cup (r 46.5 -> 54 mm) at 0.77 m, one frustum. Seeded by the
    # model of a planar face, a split took a 64 x 19 mm plane off it (IoU 0.97 -> 0.78).
    iou, _ = _best_iou(104, KINECT_NOISE, 2)
    assert iou >= 0.9


@pytest.mark.parametrize("seed, gt", [(9, 9), (18, 10), (13, 2)])
def test_noise_free_bowls_and_cups_stay_one_object(seed, gt):
    # Their inner floor or rim lies off the fitted frustum / cylinder: a bowl's floor and
    # a cup's rim, modeled apart, were planes beside the round body.
    iou, _ = _best_iou(seed, None, gt)
    assert iou >= 0.95


def test_a_box_fitted_badly_is_not_taken_apart_into_its_faces():
    # Noise-free seed 22: box 7's cuboid holds 74 % of its points; its two faces, modeled
    # apart, are two planes that each explain their own part.
    iou, _ = _best_iou(22, None, 7)
    assert iou >= 0.95
