"""Support-aware sizes: hidden lower parts are completed down to the support, nothing else.

Scenes are ray-cast (noise-free) with the synthetic desk of the paper's scenes: a box or a
can standing on the desk, seen from the paper's camera (320 x 181), with or without a thin
wall-like box in front of it that hides its lower part. The expectations come from the
scene's construction: the true sizes of the shapes, the desk plane, and which of the
object's heights above the desk the sensor saw (measured on the rendered points by label,
independently of the method).
"""

from __future__ import annotations

import functools
import math
from types import SimpleNamespace

import numpy as np
import pytest

from geomodel_ros.core.fitting.completion import (CircleSection, Extension, RectangleSection,
                                                  hidden_extension)
from geomodel_ros.core.modeling import estimate_spacing, model_object, model_objects, model_scene
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.view import SceneView
from geomodel_ros.tools.synth import Box, Cone, Cylinder, Frustum, Rectangle
from geomodel_ros.tools.synth.scenes import (DESK_CENTER, DESK_NORMAL, DESK_SIZE,
                                             SEGMENTATION_CAMERA, desk_frame, render_scene,
                                             scene_geometry)

MM = 1e-3
FRAME = desk_frame()
#: Desk plane n . x + d = 0, normal towards the camera (as the segmentation reports it).
DESK_D = -float(DESK_NORMAL @ DESK_CENTER)
SUPPORTS = {0: (DESK_NORMAL.copy(), DESK_D)}
#: Noise-free sizes come out within this of the truth (the method's accuracy on these
#: renders is about 0.05 mm; a completed end lies on the desk plane exactly).
SIZE_TOL = 0.5 * MM
#: The segmentation's contact tolerance: an object whose lowest points lie farther above
#: the desk than this has a gap the old sizing could not close
#: (SUPPORT_END_FACTOR * seg_plane_threshold).
CONTACT = 2.0 * ModelingParams().seg_plane_threshold


def _at(u_mm: float, v_mm: float, lift: float) -> np.ndarray:
    """Point at desk coordinates (u, v) [mm], ``lift`` [m] above the desk."""
    return DESK_CENTER + MM * (u_mm * FRAME[:, 0] + v_mm * FRAME[:, 1]) + lift * DESK_NORMAL


def _yawed(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return FRAME @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _box(size_mm: tuple[float, float, float], u: float, v: float, yaw: float = 0.0,
         gap: float = 0.0) -> Box:
    """Upright box standing on the desk (or ``gap`` [m] above it) at (u, v) [mm]."""
    a, b, c = (MM * s for s in size_mm)
    return Box(a, b, c, center=_at(u, v, c / 2 + gap), rotation=_yawed(yaw))


def _can(radius_mm: float, height_mm: float, u: float, v: float) -> Cylinder:
    r, h = MM * radius_mm, MM * height_mm
    return Cylinder(r, h, center=_at(u, v, h / 2), rotation=FRAME)


def _cone(radius_mm: float, height_mm: float, u: float, v: float, gap: float = 0.0) -> Cone:
    """Return a cone standing on its base on the desk (or ``gap`` [m] above it), apex up."""
    r, h = MM * radius_mm, MM * height_mm
    return Cone(r, h, center=_at(u, v, h / 2 + gap), rotation=FRAME)


def _frustum(radius_mm: float, top_mm: float, height_mm: float, u: float, v: float,
             on_small_end: bool = False) -> Frustum:
    """Return a closed frustum on the desk, on its larger circle (a flower pot) or smaller."""
    r, rt, h = MM * radius_mm, MM * top_mm, MM * height_mm
    rotation = FRAME @ np.diag([1.0, -1.0, -1.0]) if on_small_end else FRAME
    return Frustum(r, rt, h, center=_at(u, v, h / 2), rotation=rotation)


#: A thin wall-like box 200 mm wide standing between the camera and the object (the camera
#: looks at the desk from its -v side).
def _wall(height_mm: float, v: float) -> Box:
    return _box((200.0, 10.0, height_mm), 0.0, v)


BOX = (80.0, 60.0, 100.0)  # length, width, height [mm] of the test box
CAN = (30.0, 100.0)  # radius, height [mm]
CONE = (45.0, 100.0)  # base radius, height [mm]
POT = (50.0, 35.0, 90.0)  # radius (base, the larger circle), top radius, height [mm]
UPSIDE = (60.0, 40.0, 70.0)  # the same, for a frustum standing on its smaller circle
SCENES = {
    "box seen": [_box(BOX, 0.0, 10.0, 20.0)],
    "box behind wall": [_box(BOX, 0.0, 10.0, 20.0), _wall(70.0, -50.0)],
    "box floating": [_box((80.0, 60.0, 60.0), 0.0, 10.0, 20.0, gap=0.05)],
    "can behind wall": [_can(*CAN, 0.0, 10.0), _wall(80.0, -40.0)],
    "cone behind wall": [_cone(*CONE, 0.0, 10.0), _wall(60.0, -50.0)],
    "cone floating": [_cone(*CONE, 0.0, 10.0, gap=0.05)],
    "pot behind wall": [_frustum(*POT, 0.0, 10.0), _wall(60.0, -50.0)],
    "frustum on small end behind wall": [_frustum(*UPSIDE, 0.0, 10.0, on_small_end=True),
                                         _wall(45.0, -60.0)],
}


@functools.lru_cache(maxsize=None)
def render(name: str) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) [m] and labels (desk 0, object 1, wall 2) of a test scene."""
    desk = Rectangle(DESK_SIZE, DESK_SIZE, center=DESK_CENTER, rotation=_yawed(10.0))
    organized, labels = SEGMENTATION_CAMERA.render([desk] + SCENES[name])
    return organized.reshape(-1, 3), labels.reshape(-1).astype(np.int64)


def heights_seen(name: str) -> np.ndarray:
    """Heights [m] above the desk of the object's rendered points."""
    points, labels = render(name)
    return points[labels == 1] @ DESK_NORMAL + DESK_D


def modeled(name: str, supports=SUPPORTS):
    """Model the scene from its ground-truth labels; return the object (label 1)."""
    points, labels = render(name)
    result = model_objects(points, labels, supports=supports)
    return next(o for o in result.objects if o.id == 1)


def upright_dimension(obj) -> str:
    """Name of the cuboid dimension along the desk normal."""
    a = int(np.argmax(np.abs(obj.rotation.T @ DESK_NORMAL)))
    return ("length", "width", "height")[a]


def sorted_sizes(obj, skip: str) -> list[float]:
    return sorted(v for k, v in obj.dimensions.items() if k != skip)


# --------------------------------------------------------------------------- boxes
def test_scenes_hide_what_they_should():
    # Preconditions of the tests below, from the renders alone: the wall hides the lower
    # part of the box and of the can beyond the contact tolerance; the visible box reaches
    # the desk; the floating box's lowest points are its bottom, 5 cm above the desk.
    assert heights_seen("box seen").min() < 1 * MM
    assert heights_seen("box behind wall").min() > 3 * CONTACT
    assert heights_seen("can behind wall").min() > 0.5 * CAN[1] * MM
    assert heights_seen("box floating").min() == pytest.approx(0.05, abs=0.1 * MM)
    for name in ("cone behind wall", "pot behind wall", "frustum on small end behind wall"):
        assert heights_seen(name).min() > CONTACT, name
    assert heights_seen("cone floating").min() == pytest.approx(0.05, abs=0.1 * MM)


def test_box_with_hidden_lower_part_gets_its_full_height_marked_completed():
    box = modeled("box behind wall")
    assert box.type == "cuboid"
    up = upright_dimension(box)
    assert box.completed == (up,)
    assert box.dimensions[up] == pytest.approx(BOX[2] * MM, abs=SIZE_TOL)
    assert sorted_sizes(box, up) == pytest.approx([BOX[1] * MM, BOX[0] * MM], abs=SIZE_TOL)
    # Its lower face lies on the desk: the box centre is half its height above it.
    assert float(DESK_NORMAL @ box.center + DESK_D) == pytest.approx(BOX[2] / 2 * MM,
                                                                     abs=SIZE_TOL)


def test_box_with_hidden_lower_part_without_support_keeps_its_observed_height():
    # Negative: no support known -> nothing to complete to; the height is what was seen.
    box = modeled("box behind wall", supports=None)
    up = upright_dimension(box)
    seen = float(np.ptp(heights_seen("box behind wall")))
    assert box.completed == ()
    # The open lower end gets the edge correction (at most about one point spacing, 1.7
    # mm on the box here).
    assert seen - 0.1 * MM <= box.dimensions[up] <= seen + 2 * MM
    assert box.dimensions[up] < BOX[2] * MM - 2 * CONTACT


def test_fully_seen_box_is_observed_and_unchanged_by_the_scene_view():
    points, labels = render("box seen")
    box = modeled("box seen")
    up = upright_dimension(box)
    assert box.completed == ()
    assert box.dimensions[up] == pytest.approx(BOX[2] * MM, abs=SIZE_TOL)
    # Exactly what the sizing gives without any look at the rest of the scene.
    own = points[labels == 1]
    params = ModelingParams()
    rng = np.random.default_rng(5)
    spacing = estimate_spacing(own, rng)
    planes = (SUPPORTS[0],)
    with_view = model_object(own, 1, params, np.random.default_rng(3), spacing, supports=planes,
                             view=SceneView(points, labels, params.max_range))
    without = model_object(own, 1, params, np.random.default_rng(3), spacing, supports=planes)
    assert with_view.dimensions == without.dimensions
    np.testing.assert_array_equal(with_view.center, without.center)


def test_box_floating_above_the_desk_is_not_extended_to_it():
    # The sensor sees the desk through the 5 cm gap under the box.
    box = modeled("box floating")
    up = upright_dimension(box)
    assert box.completed == ()
    assert box.dimensions[up] == pytest.approx(0.06, abs=SIZE_TOL)
    assert float(DESK_NORMAL @ box.center + DESK_D) == pytest.approx(0.05 + 0.03, abs=SIZE_TOL)


def test_box_behind_wall_is_completed_end_to_end_with_the_segmentations_desk():
    points, _ = render("box behind wall")
    _, result = model_scene(points)
    boxes = [o for o in result.objects if o.completed]
    assert len(boxes) == 1, [(o.type, o.dimensions) for o in result.objects]
    box = boxes[0]
    up = upright_dimension(box)
    assert box.type == "cuboid" and box.completed == (up,)
    assert box.dimensions[up] == pytest.approx(BOX[2] * MM, abs=1 * MM)


# --------------------------------------------------------------------------- cylinders
def test_standing_can_with_lower_half_hidden_gets_its_height():
    can = modeled("can behind wall")
    assert can.type == "cylinder"
    assert can.completed == ("height",)
    assert can.dimensions["height"] == pytest.approx(CAN[1] * MM, abs=SIZE_TOL)
    assert can.dimensions["radius"] == pytest.approx(CAN[0] * MM, abs=SIZE_TOL)
    assert abs(float(can.rotation[:, 2] @ DESK_NORMAL)) == pytest.approx(1.0, abs=1e-4)


def test_cone_with_hidden_base_is_completed_with_its_taper():
    # The base of a cone seen behind a wall lies on the desk: the height grows to the
    # desk and the base radius with the side's taper (both marked completed).
    cone = modeled("cone behind wall")
    assert cone.type == "cone"
    assert set(cone.completed) == {"radius", "height"}
    assert cone.dimensions["height"] == pytest.approx(CONE[1] * MM, abs=SIZE_TOL)
    assert cone.dimensions["radius"] == pytest.approx(CONE[0] * MM, abs=SIZE_TOL)
    # Its base lies on the desk: the centre is half the height above it.
    assert float(DESK_NORMAL @ cone.center + DESK_D) == pytest.approx(CONE[1] / 2 * MM,
                                                                      abs=SIZE_TOL)


def test_cone_floating_above_the_desk_is_not_extended_to_it():
    # Negative: the desk is seen through the gap below the base.
    cone = modeled("cone floating")
    assert cone.type == "cone" and cone.completed == ()
    assert cone.dimensions["height"] == pytest.approx(CONE[1] * MM, abs=SIZE_TOL)


@pytest.mark.parametrize("name, size, end", [("pot behind wall", POT, "radius"),
                                             ("frustum on small end behind wall", UPSIDE,
                                              "top_radius")])
def test_frustum_with_hidden_lower_end_is_completed_at_that_end(name, size, end):
    # A flower pot stands on its larger circle, the other frustum on its smaller one: the
    # hidden end is completed down to the desk with the side's taper, whichever it is.
    frustum = modeled(name)
    assert frustum.type == "frustum"
    assert set(frustum.completed) == {end, "height"}
    got = [frustum.dimensions[k] for k in ("radius", "top_radius", "height")]
    assert got == pytest.approx([s * MM for s in size], abs=SIZE_TOL)
    assert float(DESK_NORMAL @ frustum.center + DESK_D) == pytest.approx(size[2] / 2 * MM,
                                                                         abs=SIZE_TOL)


def test_lying_cylinder_and_fully_seen_objects_of_the_paper_scenes_are_not_completed():
    # Negative: scene2 holds a lying cylinder (its axis parallel to the desk: no plane
    # beyond its ends), scene1 boxes and scene2 spheres, cone, standing cylinder, all
    # seen down to the desk.
    for name in ("scene1", "scene2"):
        scene = render_scene(name)
        result = model_objects(scene.points, scene.labels, supports=SUPPORTS)
        assert all(o.completed == () for o in result.objects), name


def test_object_standing_on_another_is_not_extended_through_it():
    # Negative: in `stacked` a box stands on a larger box and a can on another box; their
    # lower ends rest on the top faces seen around them (ledges), not on the desk.
    camera, shapes = scene_geometry("stacked")
    organized, labels = camera.render(shapes)
    points, labels = organized.reshape(-1, 3), labels.reshape(-1).astype(np.int64)
    result = model_objects(points, labels, supports=SUPPORTS)
    by_id = {o.id: o for o in result.objects}
    assert [by_id[i].type for i in (2, 4)] == ["cuboid", "cylinder"]
    assert all(o.completed == () for o in result.objects)
    assert by_id[4].dimensions["height"] == pytest.approx(0.06, abs=SIZE_TOL)


# --------------------------------------------------------------------------- the parts
def test_scene_view_returns_nearest_return_along_each_ray():
    # A wall of returns at z = 1 m (label 7) and a nearer patch at z = 0.5 m (label 3)
    # over x > 0.05: rays towards targets find the nearest return in their cell.
    g = np.linspace(-0.2, 0.2, 201)
    xx, yy = np.meshgrid(g, g)
    wall = np.column_stack([xx.ravel(), yy.ravel(), np.ones(xx.size)])
    patch = wall[wall[:, 0] > 0.05] * 0.5
    points = np.vstack([wall, patch, [[np.nan, np.nan, np.nan]]])
    labels = np.r_[np.full(len(wall), 7), np.full(len(patch), 3), -1]
    view = SceneView(points, labels, 10.0)
    targets = np.array([[-0.1, 0.0, 0.8],   # in front of the wall: the wall is behind it
                        [-0.1, 0.0, 1.2],   # behind the wall: blocked by it
                        [0.15, 0.0, 0.9],   # behind the patch (the patch hides the wall)
                        [0.0, 1.5, 0.5]])   # no return in that direction at all
    got = view.returns(targets, cell=0.004)
    # Along the ray to t the plane z = c lies at range c |t| / t_z.
    expected = [1.0 * np.linalg.norm(t) / t[2] for t in targets[:2]] + \
        [0.5 * np.linalg.norm(targets[2]) / targets[2][2]]
    # Cells are 4 mrad wide: the nearest return in a cell is within about one cell of the
    # exact ray's (on the wall at 1 m, 4 mm; a hand-derived bound, not a fitted one).
    assert got.nearest[:3] == pytest.approx(expected, abs=0.006)
    assert list(got.nearest_label[:3]) == [7, 7, 3]
    assert math.isnan(got.nearest[3]) and got.nearest_label[3] == -1
    assert got.ranges == pytest.approx(np.linalg.norm(targets, axis=1))


def test_extension_probes_lie_on_the_sides_that_face_the_sensor():
    # A 100 x 60 mm box section, axis along +y (down in the camera frame), 1 m in front of
    # the camera: only the side at z = 0.97 (facing the origin) and the sides x = +-0.05
    # (seen at an angle from the origin) face it; the far side z = 1.03 does not.
    frame = np.column_stack([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    section = RectangleSection(np.array([-0.05, 0.97]), np.array([0.05, 1.03]))
    ext = Extension(frame, np.zeros(3), section, t_end=0.02, t_plane=0.1)
    probes = ext.probes()
    assert len(probes) > 0
    assert np.all((probes[:, 1] > 0.02) & (probes[:, 1] < 0.1))
    on_front = np.isclose(probes[:, 2], 0.97)
    on_sides = np.isclose(np.abs(probes[:, 0]), 0.05)
    assert np.all(on_front | on_sides)
    assert not np.any(np.isclose(probes[:, 2], 1.03))
    # A round section 1 m ahead: its probes are the near half of the circle.
    ext = Extension(frame, np.array([0.0, 0.0, 1.0]), CircleSection(0.03), 0.02, 0.1)
    probes = ext.probes()
    assert np.all(probes[:, 2] < 1.0)
    assert np.linalg.norm(probes[:, [0, 2]] - [0.0, 1.0], axis=1) == pytest.approx(0.03)


def test_tapered_extension_probes_and_inside_follow_the_taper():
    # A cone's hidden part: axis +y (down in the camera frame) through (0, 0, 1) m, radius
    # 20 mm at the observed end y = 0, growing by 0.5 mm per mm down to y = 0.04 m.
    frame = np.column_stack([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    ext = Extension(frame, np.array([0.0, 0.0, 1.0]), CircleSection(0.02), 0.0, 0.04, 0.5)
    probes = ext.probes()
    assert len(probes) > 0
    # Each probe lies on the cone: its distance from the axis is 20 mm + 0.5 y.
    radius = np.linalg.norm(probes[:, [0, 2]] - [0.0, 1.0], axis=1)
    assert radius == pytest.approx(0.02 + 0.5 * probes[:, 1])
    # The extent it spans grows by the growth at the plane on either side.
    flat = Extension(frame, np.array([0.0, 0.0, 1.0]), CircleSection(0.02), 0.0, 0.04)
    assert ext.diameter() == pytest.approx(flat.diameter() + 2 * 0.5 * 0.04)
    # Other returns on a ring 22 mm off the axis at y = 25 mm lie inside the cone there
    # (radius 32.5 mm) by more than the contact tolerance (``tol``), but not inside the
    # end's section (20 mm): the growth is taken into account.
    from geomodel_ros.core.fitting.cloud import SUPPORT_END_FACTOR
    from geomodel_ros.core.fitting.completion import _held_or_filled

    params = ModelingParams()
    tol = SUPPORT_END_FACTOR * params.seg_plane_threshold
    assert 0.022 < 0.02 + 0.5 * 0.025 - tol and 0.022 > 0.02 - tol
    assert tol < 0.025 < 0.04 - tol  # between the two ends, clear of both
    ring = np.array([[0.022 * math.cos(a), 0.025, 1.0 + 0.022 * math.sin(a)]
                     for a in np.linspace(0.0, 2 * math.pi, 40, endpoint=False)])
    cloud = SimpleNamespace(params=params)
    assert _held_or_filled(cloud, ext, ring)
    assert not _held_or_filled(cloud, flat, ring)


def _patch(x: tuple[float, float], y: tuple[float, float], z: float, step: float = 0.001
           ) -> np.ndarray:
    gx, gy = np.meshgrid(np.arange(x[0], x[1], step), np.arange(y[0], y[1], step))
    return np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)])


def _round_extension() -> Extension:
    # A can's hidden part: radius 30 mm round the axis x = 0, z = 1 m, from y = 0 (its
    # observed lower end) to y = 0.1 m (the support plane; +y is down in the camera frame).
    frame = np.column_stack([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    return Extension(frame, np.array([0.0, 0.0, 1.0]), CircleSection(0.03), 0.0, 0.1)


def _cloud_seeing(points: np.ndarray, labels: np.ndarray):
    """Stand in for an object cloud (id 1): the parts the hidden-extension test reads."""
    from types import SimpleNamespace

    return SimpleNamespace(view=SceneView(points, labels, 10.0), center=np.array([0, 0, 1.0]),
                           spacing=0.002, params=ModelingParams(), oid=1)


def test_hidden_extension_needs_another_occluder_in_front_and_nothing_inside():
    from geomodel_ros.core.fitting.completion import hidden_extension

    # A sheet of returns at z = 0.8 m in front of the whole extension.
    sheet = _patch((-0.1, 0.1), (-0.03, 0.15), 0.8)
    ext = _round_extension()
    assert len(ext.probes()) > 0
    # Another object's sheet hides it: completed.
    assert hidden_extension(_cloud_seeing(sheet, np.full(len(sheet), 2)), ext)
    # The object's own points in front say nothing about what lies behind them.
    assert not hidden_extension(_cloud_seeing(sheet, np.full(len(sheet), 1)), ext)
    # Returns behind the extension (a wall at 1.2 m seen through it): not hidden.
    wall = _patch((-0.1, 0.1), (-0.03, 0.15), 1.2)
    assert not hidden_extension(_cloud_seeing(wall, np.full(len(wall), 2)), ext)
    # No returns along the rays but returns all round them (a hole in the data inside
    # the field of view): unknown, not completed.
    left, right = _patch((-0.3, -0.1), (-0.1, 0.3), 1.0), _patch((0.1, 0.3), (-0.1, 0.3), 1.0)
    frame = np.vstack([left, right])
    assert not hidden_extension(_cloud_seeing(frame, np.full(len(frame), 2)), ext)
    # The same rays outside the field of view (every return lies at x / z > 0.1 or
    # y / z < -0.03, the extension's rays at |x / z| < 0.031, 0 < y / z < 0.11): never
    # looked along, hidden, completed.
    aside = _patch((0.1, 0.3), (-0.1, 0.3), 1.0)
    assert hidden_extension(_cloud_seeing(aside, np.full(len(aside), 2)), ext)
    above = _patch((-0.3, 0.3), (-0.3, -0.03), 1.0)
    assert hidden_extension(_cloud_seeing(above, np.full(len(above), 2)), ext)
    # Something else inside the extension (a horizontal disc of another object at
    # y = 0.05, 1 mm grid): it is not the can's.
    disc = _patch((-0.02, 0.02), (0.0, 0.04), 0.0)[:, [0, 2, 1]] + [0.0, 0.05, 0.98]
    points = np.vstack([sheet, disc])
    labels = np.r_[np.full(len(sheet), 2), np.full(len(disc), 3)]
    assert not hidden_extension(_cloud_seeing(points, labels), ext)
    # A ledge: another object's surface at the can's observed end right round it.
    ledge = _patch((-0.045, 0.045), (0.94, 1.06), 0.0)[:, [0, 2, 1]]
    points = np.vstack([sheet, ledge])
    labels = np.r_[np.full(len(sheet), 2), np.full(len(ledge), 3)]
    assert not hidden_extension(_cloud_seeing(points, labels), ext)


# --------------------------------------------------------------------------- messages
def test_objects_message_and_labels_say_which_dimensions_were_completed():
    from std_msgs.msg import Header

    from geomodel_ros.core.primitives import Confidence, Primitive
    from msg_adapters.markers import LABEL_NAMESPACE, primitives_to_markers
    from msg_adapters.objects import objects_to_primitives, primitives_to_objects

    conf = Confidence(0.8125, 0.875, 0.5, None)  # exact in float32
    box = Primitive(3, "cuboid", np.array([0.0, 0.1, 0.6]), np.eye(3),
                    {"length": 0.08, "width": 0.06, "height": 0.1}, 500, 0.001,
                    completed=("height",), confidence=conf)
    seen = Primitive(4, "cylinder", np.array([0.1, 0.1, 0.6]), np.eye(3),
                     {"radius": 0.03, "height": 0.1}, 500, 0.001, confidence=conf)
    header = Header(frame_id="camera_optical")
    msg = primitives_to_objects([box, seen], header)
    assert list(msg.primitives[0].dimension_names) == ["length", "width", "height"]
    assert list(msg.primitives[0].dimension_completed) == [False, False, True]
    assert list(msg.primitives[1].dimension_completed) == [False, False]
    assert [m.confidence for m in msg.primitives] == [0.8125, 0.8125]
    back = objects_to_primitives(msg)
    assert [p.completed for p in back] == [("height",), ()]
    labels = {m.id: m.text for m in primitives_to_markers([box, seen], header).markers
              if m.ns == LABEL_NAMESPACE}
    assert labels == {3: "cuboid l=80.0 w=60.0 h=100.0* mm, confidence 0.81",
                      4: "cylinder r=30.0 h=100.0 mm, confidence 0.81"}


def test_no_hidden_extension_is_judged_without_a_point_spacing():
    # Every point a duplicate: the spacing is 0 and the rays' angular cells would be too;
    # without a cell there is no evidence, and nothing is completed.
    ext = SimpleNamespace(probes=lambda: np.array([[0.0, 0.0, 1.0]]))
    cloud = SimpleNamespace(view=object(), center=np.array([0.0, 0.0, 1.0]), spacing=0.0,
                            params=ModelingParams())
    assert hidden_extension(cloud, ext) is False
