"""Room-scale sizes: completion at the field of view's edge, to a floor segment, grazing sides.

Scenes are ray-cast (noise-free) in the camera's optical frame (x right, y down, z forward):
a floor 1 m below the camera, a back wall, and a box standing on the floor or floating
above it. The camera's lower image edge looks 21.8 deg down (tan = 0.4), so the floor is
seen only from 2.5 m on, and a box standing nearer has its lower part below the image. The
expectations come from the construction: the shapes' sizes, the floor plane, and which
heights of the box the render shows (measured on its points by label, independently of
the method).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from geomodel_ros.core.fitting.cuboid import _kept_values
from geomodel_ros.core.modeling import model_objects
from geomodel_ros.core.view import SceneView
from geomodel_ros.tools.synth import Box, PinholeCamera, Rectangle
from geomodel_ros.tools.synth.scenes import room_scene

CAMERA = PinholeCamera(fx=300.0, fy=300.0, cx=159.5, cy=119.5, width=320, height=240)
#: tan of the angle below the optical axis of the lowest image row's centre.
TAN_LOW = 120.0 / 300.0
FLOOR_Y = 1.0
WALL_Z = 6.0
UP = np.array([0.0, -1.0, 0.0])
#: The floor as n . x + d = 0, normal towards the camera (up).
FLOOR = (UP, FLOOR_Y)
WALL = (np.array([0.0, 0.0, -1.0]), WALL_Z)
BOX = (0.4, 0.4, 0.6)  # length, width, height [m]
#: Noise-free sizes: a box's faces are fitted to a fraction of a millimetre at 2-4 m, and
#: a completed end lies on the floor's fitted plane.
SIZE_TOL = 1e-3


def _yawed(deg: float) -> np.ndarray:
    """Box axes: x, y in the floor plane turned by ``deg``, z up."""
    a = math.radians(deg)
    x = np.array([math.cos(a), 0.0, math.sin(a)])
    return np.column_stack([x, np.cross(UP, x), UP])


def _box(z: float, lift: float) -> Box:
    """Place the test box at depth ``z`` [m], its bottom ``lift`` [m] above the floor."""
    return Box(*BOX, center=[0.1, FLOOR_Y - lift - BOX[2] / 2, z], rotation=_yawed(20.0))


SCENES = {
    "standing, cut by the image edge": (_box(2.0, 0.0), True),
    "floating in view": (_box(4.0, 0.7), True),
    "standing, cut, no floor": (_box(2.0, 0.0), False),
}


@functools.lru_cache(maxsize=None)
def render(name: str) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) [m] and labels (floor 0, wall 1, box 2) of a test scene."""
    box, with_floor = SCENES[name]
    floor = Rectangle(6.0, WALL_Z - 0.5, center=[0.0, FLOOR_Y, (WALL_Z + 0.5) / 2],
                      rotation=np.column_stack([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], UP]))
    wall = Rectangle(6.0, 3.0, center=[0.0, FLOOR_Y - 1.5, WALL_Z],
                     rotation=np.column_stack([[1.0, 0.0, 0.0], UP, [0.0, 0.0, -1.0]]))
    shapes = [floor if with_floor else None, wall, box]
    organized, labels = CAMERA.render([s for s in shapes if s is not None])
    labels = labels.reshape(-1).astype(np.int64)
    if not with_floor:
        labels[labels >= 0] += 1
    return organized.reshape(-1, 3), labels


def heights_seen(name: str) -> np.ndarray:
    """Heights [m] above the floor of the box's rendered points."""
    points, labels = render(name)
    return points[labels == 2] @ FLOOR[0] + FLOOR[1]


def modeled(name: str):
    """Model the scene from its labels, the wall as the one support; return the box."""
    points, labels = render(name)
    result = model_objects(points, labels, supports={1: WALL})
    return next(o for o in result.objects if o.id == 2)


def upright(obj) -> str:
    """Name of the cuboid dimension along the floor normal."""
    return ("length", "width", "height")[int(np.argmax(np.abs(obj.rotation.T @ UP)))]


def test_scenes_show_what_they_should():
    # The standing box's lowest seen points lie where the lowest image row meets it
    # (its nearest corner about 1.6 m away: 1 - 0.4 * 1.6 = 0.36 m above the floor, less
    # below the corner's sides), far above any contact tolerance; the floating box's
    # lowest points are its bottom edge, 0.7 m up; the floor is seen, but only beyond
    # 2.5 m (behind the standing box).
    cut = heights_seen("standing, cut by the image edge")
    assert cut.min() > 0.1 and cut.max() == pytest.approx(BOX[2], abs=1e-6)
    assert heights_seen("floating in view").min() == pytest.approx(0.7, abs=1e-3)
    points, labels = render("standing, cut by the image edge")
    assert points[labels == 0][:, 2].min() > FLOOR_Y / TAN_LOW - 0.01
    # Every return lies within the image's rays, and nothing below the lowest row.
    view = SceneView(points, labels, 20.0)
    v_max = view.image_bounds[3]
    assert v_max == pytest.approx(TAN_LOW - 0.5 / 300.0, abs=1e-3)


def test_box_cut_by_the_image_edge_is_completed_to_the_floor_segment():
    # The floor is not a support (only the wall is): it is one large plane segment of
    # the scene, and the box's hidden lower part lies below the image, never looked at.
    box = modeled("standing, cut by the image edge")
    assert box.type == "cuboid"
    up = upright(box)
    assert box.dimensions[up] == pytest.approx(BOX[2], abs=SIZE_TOL)
    assert sorted(v for k, v in box.dimensions.items() if k != up) == \
        pytest.approx(sorted(BOX[:2]), abs=SIZE_TOL)
    assert box.completed == (up,)


def test_box_floating_in_view_above_a_seen_floor_is_not_completed():
    # Rays under the box see the floor behind the hypothesised extension: empty space.
    box = modeled("floating in view")
    up = upright(box)
    # Its bottom edge is a sampled edge at 4 m (13 mm spacing): within half a spacing.
    assert box.dimensions[up] == pytest.approx(BOX[2], abs=0.5 * 4.0 / CAMERA.fy)
    assert box.completed == ()


def test_box_cut_by_the_image_edge_without_a_plane_below_keeps_its_seen_height():
    box = modeled("standing, cut, no floor")
    up = upright(box)
    seen = heights_seen("standing, cut, no floor")
    assert box.dimensions[up] == pytest.approx(seen.max() - seen.min(), abs=0.02)
    assert box.dimensions[up] < BOX[2] - 0.1
    assert box.completed == ()


def test_rays_behind_the_camera_or_beyond_the_returns_are_outside_the_image():
    pts = np.array([[-1.0, -0.5, 2.0], [1.0, 0.5, 2.0], [0.0, 0.0, 4.0]])
    view = SceneView(pts, np.zeros(3, dtype=np.int64), 10.0)
    assert view.image_bounds == pytest.approx([-0.5, 0.5, -0.25, 0.25])
    targets = np.array([[0.0, 0.0, 1.0], [0.49, 0.24, 1.0], [0.6, 0.0, 1.0],
                        [0.0, -0.3, 1.0], [0.0, 0.0, -1.0]])
    assert view.beyond_image(targets).tolist() == [False, False, True, True, True]
    # A cloud that surrounds the sensor (returns behind it) has no image: nothing is
    # outside.
    around = SceneView(np.vstack([pts, [[0.0, 0.0, -3.0]]]), np.zeros(4, dtype=np.int64), 10.0)
    assert around.image_bounds is None
    assert not around.beyond_image(targets).any()


# --------------------------------------------------------------------------- grazing sides
def test_side_seen_at_a_grazing_angle_is_no_stray_but_flying_pixels_past_it_are():
    # A box seen face on: 5000 front points at depth 0 (its front plane, 1 mm noise) and
    # a side face of 40 points spread evenly over the box's depth, 0.5 m (0.8 % of the
    # points: one image column on a face seen at 87 deg). The bulk of all points is the
    # front, a few millimetres deep; the side's own points span the depth and are kept.
    rng = np.random.default_rng(0)
    front = rng.normal(0.0, 0.001, 5000)
    side = np.linspace(0.0, 0.5, 40)
    kept = _kept_values(np.r_[front, side], [side])
    assert kept.max() == pytest.approx(0.5)
    # Without the side's own judgement (no face runs along the axis) they are strays.
    assert _kept_values(np.r_[front, side], []).max() < 0.05
    # Two flying pixels 0.3 m past the side's end are strays of the side too.
    side_fp = np.r_[side, 0.8, 0.81]
    assert _kept_values(np.r_[front, side_fp], [side_fp]).max() == pytest.approx(0.5)
    # A face of a few points (below MIN_SIDE_POINTS) decides nothing.
    few = np.linspace(0.0, 0.5, 10)
    assert _kept_values(np.r_[front, few], [few]).max() < 0.05


def test_room_cabinet_keeps_its_grazing_side():
    # The room's cabinet (0.8 x 0.5 x 1.8 m at 6 m, turned 10 deg): its 0.5 m side is seen
    # at about 87 deg from its normal by a few dozen points. From the true labels, with
    # the room's walls as supports, the side's depth comes out within the spacing of its
    # samples along the face (the side's points themselves reach 0.45 m and more).
    scene = room_scene(noise=None)
    side_depth = next(sorted(o.dimensions.values()) for o in scene.objects if o.id == 5)[0]
    assert side_depth == pytest.approx(0.5)
    walls = {i: _plane_of(scene.points[scene.labels == i]) for i in (1, 2, 3)}
    result = model_objects(scene.points, scene.labels, supports=walls)
    cabinet = next(o for o in result.objects if o.id == 5)
    assert cabinet.type == "cuboid"
    got = sorted(cabinet.dimensions.values())
    assert got[0] == pytest.approx(0.5, abs=0.03)
    assert got[1:] == pytest.approx([0.8, 1.8], abs=0.015)


def test_room_table_below_the_field_of_view_is_completed_to_the_floor():
    # The room's table (1.6 x 0.8 x 0.75 m at 3 m) shows only its top 0.18 m: the rest is
    # below the image. The floor is an object of the scene (label 0), the walls the
    # supports.
    scene = room_scene(noise=None)
    table_pts = scene.points[scene.labels == 4]
    floor = _plane_of(scene.points[scene.labels == 0])
    seen = table_pts @ floor[0] + floor[1]
    assert seen.min() > 0.5 and seen.max() == pytest.approx(0.75, abs=1e-3)
    walls = {i: _plane_of(scene.points[scene.labels == i]) for i in (1, 2, 3)}
    result = model_objects(scene.points, scene.labels, supports=walls)
    table = next(o for o in result.objects if o.id == 4)
    up = ("length", "width", "height")[int(np.argmax(np.abs(table.rotation.T @ floor[0])))]
    assert table.dimensions[up] == pytest.approx(0.75, abs=0.005)
    assert table.completed == (up,)
    assert sorted(v for k, v in table.dimensions.items() if k != up) == \
        pytest.approx([0.8, 1.6], abs=0.005)


def _plane_of(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane n . x + d = 0 of ``points`` (k, 3), normal towards the origin."""
    c = points.mean(axis=0)
    n = np.linalg.svd(points - c, full_matrices=False)[2][2]
    n = -n if n @ c > 0 else n
    return n, float(-n @ c)


# --------------------------------------------------------------------------- end planes
def _grid(a: tuple[float, float], b: tuple[float, float], step: float = 0.01) -> np.ndarray:
    ga, gb = np.meshgrid(np.arange(a[0], a[1], step), np.arange(b[0], b[1], step))
    return np.column_stack([ga.ravel(), gb.ravel()])


def test_end_planes_are_the_supports_and_the_large_plane_segments():
    from types import SimpleNamespace

    from geomodel_ros.core.fitting.completion import end_planes
    from geomodel_ros.core.params import ModelingParams

    # In the camera frame: a floor 1 m below (2 x 2 m, label 3), a wall 4 m ahead (label
    # 4, also given as a support), a small plate (0.2 x 0.2 m = 0.04 m^2, below the
    # support area 0.1 m^2; label 5) and a box corner (two perpendicular 0.5 x 0.5 m
    # faces, one segment; label 6).
    xz = _grid((-1.0, 1.0), (1.0, 3.0))
    floor = np.column_stack([xz[:, 0], np.full(len(xz), FLOOR_Y), xz[:, 1]])
    xy = _grid((-2.0, 2.0), (-1.0, 1.0))
    wall = np.column_stack([xy, np.full(len(xy), 4.0)])
    pl = _grid((0.0, 0.2), (0.0, 0.2))
    plate = np.column_stack([pl, np.full(len(pl), 2.0)])
    sq = _grid((0.0, 0.5), (0.0, 0.5))
    corner = np.vstack([np.column_stack([sq[:, 0] - 0.8, sq[:, 1] - 0.5,
                                         np.full(len(sq), 2.5)]),
                        np.column_stack([np.full(len(sq), -0.3), sq[:, 1] - 0.5,
                                         sq[:, 0] + 2.5])])
    parts = [floor, wall, plate, corner]
    points = np.vstack(parts)
    labels = np.concatenate([np.full(len(p), 3 + i) for i, p in enumerate(parts)])
    near_wall = (np.array([0.0, 0.0, -1.0]), 4.0)
    cloud = SimpleNamespace(view=SceneView(points, labels, 10.0), params=ModelingParams(),
                            oid=7, supports=(near_wall,))
    planes = end_planes(cloud)
    # The wall once (as the support), then the floor, normal up (towards the camera).
    assert len(planes) == 2
    assert planes[0] is near_wall
    assert planes[1][0] == pytest.approx(FLOOR[0], abs=1e-9)
    assert planes[1][1] == pytest.approx(FLOOR[1], abs=1e-9)
    # The object's own segment is never a plane to complete it to.
    cloud.oid = 3
    assert len(end_planes(cloud)) == 1
