"""Objects resting on support planes: the solid's nearest point, by hand, and whole scenes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.primitives import Primitive
from geomodel_ros.core.resting import plane_offset, resting_objects
from geomodel_ros.tools.synth import render_scene

UP = np.array([0.0, 0.0, 1.0])  # plane z = 0, normal +z


def _rot_x(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _prim(kind: str, center, rotation, **dims) -> Primitive:
    return Primitive(7, kind, np.asarray(center, dtype=float), rotation, dims, 100, 0.0)


def test_box_nearest_point_is_its_lowest_corner():
    # Upright 0.2 x 0.1 x 0.3 box centred 0.15 above z = 0: its base is on the plane.
    box = _prim("cuboid", [0, 0, 0.15], np.eye(3), length=0.2, width=0.1, height=0.3)
    assert plane_offset(box, UP, 0.0) == pytest.approx(0.0, abs=1e-12)
    # Turned 45 deg about x: lowest edge at z_c - (0.1 cos45 + 0.3 sin45) / 2.
    tilted = _prim("cuboid", [0, 0, 0.5], _rot_x(45), length=0.2, width=0.1, height=0.3)
    want = 0.5 - (0.1 + 0.3) * math.sqrt(0.5) / 2
    assert plane_offset(tilted, UP, 0.0) == pytest.approx(want, abs=1e-12)


def test_round_solids_nearest_point():
    # Standing cylinder r 0.04, h 0.1, centre at z 0.05: bottom circle on the plane.
    cyl = _prim("cylinder", [0, 0, 0.05], np.eye(3), radius=0.04, height=0.1)
    assert plane_offset(cyl, UP, 0.0) == pytest.approx(0.0, abs=1e-12)
    # Lying (axis along x), centre at z 0.04: touches along a line at z = 0.
    lying = _prim("cylinder", [0, 0, 0.04], np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0.0]]),
                  radius=0.04, height=0.1)
    assert plane_offset(lying, UP, 0.0) == pytest.approx(0.0, abs=1e-12)
    # Cone standing on its base (z base -> apex up) and upside down on its apex.
    cone = _prim("cone", [0, 0, 0.06], np.eye(3), radius=0.03, height=0.12)
    assert plane_offset(cone, UP, 0.0) == pytest.approx(0.0, abs=1e-12)
    flipped = _prim("cone", [0, 0, 0.06], np.diag([1.0, -1.0, -1.0]), radius=0.03, height=0.12)
    assert plane_offset(flipped, UP, 0.0) == pytest.approx(0.0, abs=1e-12)
    # Frustum on its smaller (top) circle: z points down, the top circle at the bottom.
    cup = _prim("frustum", [0, 0, 0.045], np.diag([1.0, -1.0, -1.0]), radius=0.04,
                top_radius=0.03, height=0.09)
    assert plane_offset(cup, UP, 0.0) == pytest.approx(0.0, abs=1e-12)
    ball = _prim("sphere", [0, 0, 0.25], np.eye(3), radius=0.05)
    assert plane_offset(ball, UP, 0.0) == pytest.approx(0.2, abs=1e-12)
    assert plane_offset(_prim("unknown", [0, 0, 1], np.eye(3)), UP, 0.0) is None


def test_resting_needs_contact_the_sensor_side_and_the_patch():
    desk = Primitive(0, "plane", np.zeros(3), np.eye(3), {"length": 1.0, "width": 1.0}, 1000,
                     0.0)
    on = Primitive(1, "sphere", np.array([0.1, 0, 0.05]), np.eye(3), {"radius": 0.05}, 50, 0.0)
    floating = Primitive(2, "sphere", np.array([0, 0.1, 0.10]), np.eye(3), {"radius": 0.05}, 50,
                         0.0)
    beside = Primitive(3, "sphere", np.array([0.8, 0, 0.05]), np.eye(3), {"radius": 0.05}, 50,
                       0.0)
    below = Primitive(4, "sphere", np.array([0, 0, -0.05]), np.eye(3), {"radius": 0.05}, 50,
                      0.0)
    got = resting_objects([desk, on, floating, beside, below], {0: (UP, 0.0)},
                          lambda _o: 0.004)
    assert got == {0: [1]}


def test_stacked_scene_only_the_lower_objects_rest_on_the_desk():
    # Ground truth (tools/synth scenes._stacked): 1 and 3 stand on the desk (0); 2 stands on
    # 1 and 4 on 3.
    scene = render_scene("stacked")
    labels, result = model_scene(scene.points)
    to_gt = {}
    for o in result.objects:
        gt = np.bincount(scene.labels[(labels == o.id) & (scene.labels >= 0)])
        to_gt[o.id] = int(np.argmax(gt))
    desk = [k for k in result.supported if to_gt[k] == 0]
    assert len(desk) == 1
    assert sorted(to_gt[i] for i in result.supported[desk[0]]) == [1, 3]


def test_paper_scene_every_object_rests_on_the_desk():
    scene = render_scene("scene3")
    _, result = model_scene(scene.points)
    assert list(result.supported) == [0]
    assert sorted(result.supported[0]) == sorted(o.id for o in result.objects if o.id != 0)
    assert len(result.supported[0]) == 7


def test_published_relation_uses_the_tracked_ids():
    from geomodel_ros.core.primitives import ModelingResult
    from geomodel_ros.ros.processing import _supports_by_id

    desk = Primitive(0, "plane", np.zeros(3), np.eye(3), {"length": 1.0, "width": 1.0}, 9, 0.0)
    ball = Primitive(1, "sphere", np.array([0, 0, 0.05]), np.eye(3), {"radius": 0.05}, 9, 0.0)
    gone = Primitive(2, "sphere", np.array([0.2, 0, 0.05]), np.eye(3), {"radius": 0.05}, 9, 0.0)
    result = ModelingResult(objects=[desk, ball, gone], timing={}, supports={0: (UP, 0.0)},
                            supported={0: [1, 2]})
    shown = [Primitive(40, "plane", desk.center, desk.rotation, desk.dimensions, 9, 0.0),
             Primitive(41, "sphere", ball.center, ball.rotation, ball.dimensions, 9, 0.0)]
    got = _supports_by_id(result, [desk, ball], shown)
    assert list(got["supports"]) == [40]
    assert got["supported"] == {40: [41]}  # 2 is not published: left out
