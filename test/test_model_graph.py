"""The basic geometric model graph (geomodel_ros.core.model_graph) on hand-built faces."""

from __future__ import annotations

import inspect
import math

import numpy as np
import pytest

from geomodel_ros.core.model_graph import FaceInfo, GraphDecision, curvature_candidates, decide_type
from geomodel_ros.core.modeling import model_objects
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import PrimitiveType

TOL = 0.14  # angle tolerance [rad] (the default)
COPLANAR = 0.006  # coplanarity tolerance [m] (3 x the default RANSAC threshold)
SPHERE_RATIO, DEVELOPABLE_RATIO, CONE_VARIATION = 0.45, 0.3, 0.25


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def planar(normal, point, size):
    """Planar face through ``point`` [m] with ``normal``; offset d of n . x + d = 0."""
    n = _unit(normal)
    p = np.asarray(point, dtype=float)
    return FaceInfo(True, n, float(-n @ p), size, np.tile(n, (size, 1)), p)


def curved(point_normals):
    pn = _unit(point_normals)
    mean = _unit(pn.mean(axis=0))
    return FaceInfo(False, mean, 0.0, len(pn), pn)


def all_adjacent(k):
    return ~np.eye(k, dtype=bool)


def decide(faces, adjacency=None, curvature=None):
    adj = all_adjacent(len(faces)) if adjacency is None else adjacency
    return decide_type(faces, adj, TOL, COPLANAR, curvature, SPHERE_RATIO, DEVELOPABLE_RATIO,
                       CONE_VARIATION)


def _rotation(yaw, pitch):
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1.0]])
    rx = np.array([[1.0, 0, 0], [0, cp, -sp], [0, sp, cp]])
    return rx @ rz


# ---------------------------------------------------------------------------------------
# Only planar faces
# ---------------------------------------------------------------------------------------


def test_no_faces_is_empty():
    d = decide_type([], np.zeros((0, 0), dtype=bool), TOL, COPLANAR)
    assert d == GraphDecision("empty", (), -1, (), "no faces")


def _box_seen_from_outside():
    """Return (rotation, centre [m], its three faces seen from outside, 300/200/100 points)."""
    rot = _rotation(0.3, 0.7)
    c = np.array([0.0, 0.0, 0.5])
    return rot, c, [planar(-rot[:, 0], c - 0.03 * rot[:, 0], 300),
                    planar(-rot[:, 1], c - 0.02 * rot[:, 1], 200),
                    planar(-rot[:, 2], c - 0.04 * rot[:, 2], 100)]


def test_box_faces_give_cuboid_with_axis_assignment():
    _, _, faces = _box_seen_from_outside()
    d = decide(faces)
    assert d.category == "planar"
    assert d.candidates == ("cuboid",)
    assert d.main_face == 0
    assert d.axis_of_face == (0, 1, 2)


def test_box_axes_follow_face_sizes():
    """Main = largest face (axis 0), second = largest adjacent perpendicular face (axis 1)."""
    rot = _rotation(-0.4, 0.2)
    c = np.array([0.05, 0.0, 0.6])
    faces = [planar(-rot[:, 2], c - 0.04 * rot[:, 2], 100),   # smallest -> axis 2
             planar(-rot[:, 0], c - 0.03 * rot[:, 0], 300),   # largest  -> axis 0 (main)
             planar(-rot[:, 1], c - 0.02 * rot[:, 1], 200)]   # second   -> axis 1
    d = decide(faces)
    assert d.candidates == ("cuboid",)
    assert d.main_face == 1
    assert d.axis_of_face == (2, 0, 1)


def test_box_with_two_parallel_faces_shares_an_axis():
    rot = _rotation(0.1, 0.5)
    c = np.array([0.0, 0.0, 0.5])
    faces = [planar(-rot[:, 0], c - 0.03 * rot[:, 0], 300),
             planar(-rot[:, 1], c - 0.02 * rot[:, 1], 200),
             planar(rot[:, 0], c + 0.03 * rot[:, 0], 50)]   # opposite side of face 0
    d = decide(faces)
    assert d.candidates == ("cuboid",)
    assert d.axis_of_face == (0, 1, 0)


def test_perpendicular_faces_that_do_not_touch_are_not_a_cuboid():
    c = np.array([0.0, 0.0, 0.5])
    faces = [planar([0, 0, -1], c, 300), planar([1, 0, 0], c + [0.2, 0, 0], 200)]
    d = decide(faces, adjacency=np.zeros((2, 2), dtype=bool))
    assert d.candidates == ()
    assert d.category == "planar"


def test_nearly_perpendicular_face_off_the_box_axes_rejects_cuboid():
    c = np.array([0.0, 0.0, 0.5])
    faces = [planar([0, 0, -1], c, 300), planar([1, 0, 0], c, 200),
             planar(_unit([1, 1, 0]), c, 100)]   # 45 deg between the box axes
    d = decide(faces)
    assert d.candidates == ()
    assert d.axis_of_face == ()


def _corner(front_x, side_x, side_z):
    """Build a face at z = 3 m and a perpendicular one at x = ``side_x``, depth ``side_z``.

    Both face the sensor at the origin (normals -z and -x).
    """
    front = planar([0.0, 0.0, -1.0], [front_x, 0.0, 3.0], 300)
    side = planar([-1.0, 0.0, 0.0], [side_x, 0.0, side_z], 200)
    return [front, side]


def test_a_box_edge_seen_from_outside_is_a_cuboid():
    # The box spans x 0.2 .. 1.2 m and z 3 .. 4 m; its left side faces the sensor.
    d = decide(_corner(0.7, 0.2, 3.5))
    assert d.candidates == ("cuboid",)
    assert not d.concave_corner


def test_a_room_corner_seen_from_inside_is_flagged():
    # A back wall at z = 3 m (x -0.5 .. 1 m) and a side wall at x = 1 m (z 2 .. 3 m)
    # meeting it: each wall's centre lies 0.5 m in front of the other's plane.
    d = decide(_corner(0.25, 1.0, 2.5))
    # The cuboid stays a candidate for its rivals (a round model of all faces may replace
    # it); as the outcome it is refused (fitting.strategies.run_strategies).
    assert d.candidates == ("cuboid",)
    assert d.concave_corner
    assert "concave" in d.reason


def test_a_concave_corner_beside_a_box_face_is_flagged():
    # A box seen from outside (three faces) and, touching its front face, a perpendicular
    # piece of another surface that stands in front of it (a wall's foot beside the box).
    rot, c, box = _box_seen_from_outside()
    assert not decide(box).concave_corner
    # In front of face 0's plane (along its outward normal -rot[:, 0]), its own normal
    # along rot[:, 1] pointing back over face 0: the two centres each lie in front of the
    # other's plane.
    piece = planar(rot[:, 1], c - 0.08 * rot[:, 0] - 0.02 * rot[:, 1], 100)
    adjacency = np.zeros((4, 4), dtype=bool)
    adjacency[0, 1:] = adjacency[1:, 0] = True
    adjacency[1, 2] = adjacency[2, 1] = True
    assert decide(box + [piece], adjacency).concave_corner
    # Not adjacent to any face it is concave with: the box stands.
    adjacency[0, 3] = adjacency[3, 0] = False
    assert not decide(box + [piece], adjacency).concave_corner


def _grid(origin, u, v, n):
    a, b = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="ij")
    return np.asarray(origin) + a.reshape(-1, 1) * np.asarray(u) + b.reshape(-1, 1) * v


def test_a_room_corner_is_not_modeled_as_a_cuboid():
    # Two 0.4 m walls seen from inside their corner, 1.5 m away, as one object: the model
    # graph's cuboid is refused as the outcome (no round model fits either).
    back = _grid((0.0, -0.2, 1.5), (0.4, 0.0, 0.0), np.array([0.0, 0.4, 0.0]), 80)
    side = _grid((0.4, -0.2, 1.1), (0.0, 0.0, 0.4), np.array([0.0, 0.4, 0.0]), 80)
    pts = np.vstack([back, side])
    params = ModelingParams(noise_model="fixed")
    corner = model_objects(pts, np.zeros(len(pts), dtype=np.int64), params).objects[0]
    assert corner.type == PrimitiveType.UNKNOWN
    assert "cuboid refused" in corner.reason
    # The same two faces as a box's edge seen from outside: a cuboid.
    front = _grid((0.1, -0.2, 1.5), (0.4, 0.0, 0.0), np.array([0.0, 0.4, 0.0]), 80)
    left = _grid((0.1, -0.2, 1.5), (0.0, 0.0, 0.4), np.array([0.0, 0.4, 0.0]), 80)
    pts = np.vstack([front, left])
    box = model_objects(pts, np.zeros(len(pts), dtype=np.int64), params).objects[0]
    assert box.type == PrimitiveType.CUBOID


def test_a_side_bent_into_two_pieces_is_still_a_cuboid():
    # The front face of a box in two pieces that meet concavely by 4 deg (a sensor's
    # slow error bends it): pieces of one side are not a corner.
    tilt = math.radians(2.0)
    left = planar([math.sin(tilt), 0.0, -math.cos(tilt)], [0.35, 0.0, 3.0], 200)
    right = planar([-math.sin(tilt), 0.0, -math.cos(tilt)], [0.85, 0.0, 3.0], 200)
    # Each piece's centre lies in front of the other's plane ...
    for a, b in ((left, right), (right, left)):
        assert float(b.normal @ a.center) + b.offset > 0.0
    side = planar([-1.0, 0.0, 0.0], [0.1, 0.0, 3.3], 150)  # the box's left side
    d = decide([left, right, side])
    assert d.candidates == ("cuboid",)
    assert not d.concave_corner


def test_a_concave_sliver_is_not_flagged():
    rot, c, box = _box_seen_from_outside()
    sliver = planar(rot[:, 1], c - 0.08 * rot[:, 0] - 0.02 * rot[:, 1], 20)  # 20 / 620 < 5 %
    assert not decide(box + [sliver]).concave_corner


def test_single_planar_face_is_a_plane():
    d = decide([planar([0, -0.6, -0.8], [0, 0, 0.5], 500)])
    assert d.candidates == ("plane",)
    assert d.main_face == 0


def test_parallel_coplanar_faces_give_one_plane():
    n = _unit([0.0, -0.766, -0.643])
    p0 = np.array([0.0, -0.04, 0.52])
    x = _unit(np.cross(n, [1.0, 0, 0]))
    faces = [planar(n, p0, 500), planar(n, p0 + 0.1 * x, 80),
             planar(-n, p0 - 0.1 * x, 40)]   # same plane, normal flipped
    d = decide(faces)
    assert d.candidates == ("plane",)
    assert d.main_face == 0


# A face lying on the main plane whose fitted normal is tilted by a small angle (inside the
# parallel tolerance) has a plane offset d far from the main face's (~ angle * distance from
# the sensor origin); coplanarity must be judged where the faces are.

def test_coplanar_face_with_slightly_tilted_normal_gives_one_plane():
    p0 = np.array([0.0, 0.0, 0.5])
    p1 = np.array([0.3, 0.0, 0.5])   # on the same plane z = 0.5
    tilt = math.radians(3.0)
    faces = [planar([0, 0, -1], p0, 500),
             planar([math.sin(tilt), 0, -math.cos(tilt)], p1, 40)]
    d = decide(faces)
    assert d.candidates == ("plane",)


def test_parallel_faces_at_different_offsets_give_no_candidate():
    n = np.array([0.0, 0.0, -1.0])
    faces = [planar(n, [0, 0, 0.5], 500), planar(n, [0.05, 0, 0.52], 200)]
    d = decide(faces)
    assert d.candidates == ()
    assert d.reason == "parallel planar faces at different offsets"


def test_wedge_gives_no_candidate():
    c = np.array([0.0, 0.0, 0.5])
    faces = [planar([0, 0, -1], c, 300),
             planar(_unit([math.sin(math.pi / 4), 0, -math.cos(math.pi / 4)]), c, 200)]
    d = decide(faces)
    assert d.category == "planar"
    assert d.candidates == ()
    assert d.reason == "planar faces neither perpendicular nor parallel to the main face"


# ---------------------------------------------------------------------------------------
# Planar + curved faces
# ---------------------------------------------------------------------------------------


def _ring_normals(axis, angle_to_plane, m=200):
    """Return normals around ``axis`` at ``angle_to_plane`` [rad] to its perpendicular plane."""
    a = _unit(axis)
    helper = np.array([1.0, 0, 0]) if abs(a[0]) < 0.9 else np.array([0, 1.0, 0])
    x = _unit(np.cross(helper, a))
    y = np.cross(a, x)
    th = np.linspace(0, np.pi, m)   # the visible half
    radial = np.cos(th)[:, None] * x + np.sin(th)[:, None] * y
    return radial * math.cos(angle_to_plane) + a * math.sin(angle_to_plane)


def test_cap_and_perpendicular_curved_normals_give_cylinder_first():
    axis = _unit([0.1, -0.7, -0.7])
    faces = [curved(_ring_normals(axis, 0.0, 400)), planar(axis, [0, 0, 0.5], 100)]
    d = decide(faces)
    assert d.category == "mixed"
    assert d.candidates == ("cylinder", "cone", "frustum")
    assert d.main_face == 1


def test_base_and_constant_angle_normals_give_cone_first():
    axis = _unit([0.0, -0.8, -0.6])
    faces = [curved(_ring_normals(axis, math.radians(31), 400)), planar(-axis, [0, 0, 0.5], 120)]
    d = decide(faces)
    assert d.category == "mixed"
    assert d.candidates == ("cone", "frustum", "cylinder")
    assert d.main_face == 1


def test_plane_with_normals_at_varying_angles_gives_no_candidate():
    """A sphere-like curved face next to a plane: normal angles spread over 0-80 deg."""
    axis = np.array([0.0, 0.0, -1.0])
    pn = np.vstack([_ring_normals(axis, math.radians(a), 50) for a in range(0, 81, 10)])
    d = decide([curved(pn), planar(axis, [0, 0, 0.5], 100)])
    assert d.category == "mixed"
    assert d.candidates == ()


def test_big_oblique_planar_face_with_curved_faces_gives_no_candidate():
    axis = np.array([0.0, 0.0, -1.0])
    faces = [curved(_ring_normals(axis, 0.0, 300)), planar(axis, [0, 0, 0.5], 200),
             planar(_unit([1, 0, -1]), [0, 0, 0.5], 150)]
    d = decide(faces)
    assert d.candidates == ()


# ---------------------------------------------------------------------------------------
# Only curved faces: principal curvatures
# ---------------------------------------------------------------------------------------


def _cands(k_max, k_min):
    return curvature_candidates(np.asarray(k_max, float), np.asarray(k_min, float),
                                SPHERE_RATIO, DEVELOPABLE_RATIO, CONE_VARIATION)[0]


def test_sphere_like_curvatures():
    rng = np.random.default_rng(0)
    k = 1 / 0.03 + rng.normal(0, 1.0, 500)
    assert _cands(k, k * rng.uniform(0.9, 1.0, 500)) == ("sphere",)


def test_cylinder_like_curvatures():
    rng = np.random.default_rng(1)
    assert _cands(1 / 0.02 + rng.normal(0, 1.0, 500), rng.normal(0, 1.0, 500)) == \
        ("cylinder", "cone", "frustum")


def test_cone_like_curvatures():
    """k1 = cos(alpha) / r(s) with the radius growing from 10 to 40 mm along the cone."""
    rng = np.random.default_rng(2)
    radius = rng.uniform(0.01, 0.04, 500)
    k1 = math.cos(math.radians(30)) / radius
    assert _cands(k1, rng.normal(0, 0.5, 500)) == ("cone", "frustum", "cylinder")


def test_torus_like_curvatures_give_no_candidate():
    """Torus R = 20 mm, r = 15 mm: k1 = 1/r, k2 = cos(t) / (R + r cos(t)) (outer half).

    (A slender torus, R >> r, has k2 ~ 0 and looks developable to the curvature rule; the
    RANSAC verification rejects it, see test_pipeline.)
    """
    t = np.linspace(-math.pi / 2, math.pi / 2, 500)
    big, small = 0.02, 0.015
    k2 = np.cos(t) / (big + small * np.cos(t))
    k1 = np.full_like(t, 1 / small)
    ratio = np.median(np.abs(k2)) / np.median(k1)
    assert DEVELOPABLE_RATIO < ratio < SPHERE_RATIO   # the configuration tested
    cands, why = curvature_candidates(k1, k2, SPHERE_RATIO, DEVELOPABLE_RATIO, CONE_VARIATION)
    assert cands == ()
    assert why.startswith("principal curvature ratio")


def test_flat_or_nan_curvatures_give_no_candidate():
    assert _cands(np.zeros(10), np.zeros(10)) == ()
    assert _cands(np.full(10, np.nan), np.full(10, np.nan)) == ()


def test_all_curved_uses_curvature_in_decide_type():
    rng = np.random.default_rng(3)
    faces = [curved(_unit(rng.normal(size=(100, 3))))]
    k = np.full(100, 1 / 0.03)
    d = decide(faces, curvature=(k, k))
    assert d == GraphDecision("curved", ("sphere",), -1, (), d.reason)
    d = decide(faces, curvature=None)
    assert d.candidates == ("cylinder", "cone", "sphere", "frustum")


def test_a_curved_sliver_on_a_box_does_not_make_it_mixed():
    # Three perpendicular box faces and a small rounded edge (2 % of the points).
    faces = [planar([0, 0, -1], [0, 0, 0.5], 400), planar([1, 0, 0], [0.05, 0, 0.52], 300),
             planar([0, 1, 0], [0, 0.05, 0.52], 300),
             curved(np.c_[np.cos(np.linspace(0, 1.5, 20)), np.zeros(20),
                          -np.sin(np.linspace(0, 1.5, 20))])]
    d = decide(faces)
    assert d.candidates == ("cuboid",) and "curved slivers ignored" in d.reason
    assert sorted(d.axis_of_face[:3]) == [0, 1, 2]
    # A larger curved part keeps the mixed rules (the box-with-rounded-side is no cuboid).
    big = faces[:3] + [curved(np.tile([[0.7, 0, -0.7]], (200, 1)))]
    assert decide(big).category == "mixed"


# ---------------------------------------------------------------------------------------
# Mixed objects: an oblique planar face vetoes the cylinder/cone rules only when it is
# large. Rule (worked out by hand): it vetoes iff its size > 10 % of all working points
# (2 x the 5 % sliver share). With a curved face of 300 points and a cap of 200, an
# oblique face of s points vetoes iff s > 0.1 (500 + s), i.e. s > 55.6.
# ---------------------------------------------------------------------------------------


def _cap_ring_and_oblique(oblique_size):
    axis = np.array([0.0, 0.0, -1.0])
    return [curved(_ring_normals(axis, 0.0, 300)), planar(axis, [0, 0, 0.5], 200),
            planar(_unit([1, 0, -1]), [0.03, 0, 0.5], oblique_size)]


@pytest.mark.parametrize("size", [10, 50])   # 2 % and 9.1 % of the object
def test_small_oblique_planar_sliver_does_not_veto_the_cylinder(size):
    d = decide(_cap_ring_and_oblique(size))
    assert d.category == "mixed"
    assert d.candidates == ("cylinder", "cone", "frustum")
    assert d.main_face == 1


@pytest.mark.parametrize("size", [60, 150])   # 10.7 % and 23 % of the object
def test_large_oblique_planar_face_vetoes_the_cylinder(size):
    d = decide(_cap_ring_and_oblique(size))
    assert d.category == "mixed"
    assert d.candidates == ()
    assert d.reason == "several non-parallel planar faces with curved faces"


def test_decide_type_defaults_are_the_parameter_defaults():
    """decide_type repeats no default: its curvature ratios are ModelingParams'."""
    defaults = ModelingParams()
    sig = inspect.signature(decide_type).parameters
    assert sig["sphere_ratio"].default == defaults.sphere_curvature_ratio
    assert sig["developable_ratio"].default == defaults.developable_curvature_ratio
    assert sig["cone_variation"].default == defaults.cone_curvature_variation
    # A ratio of 0.4 lies between the default developable (0.35) and sphere (0.45) ratios.
    faces = [curved(_unit(np.random.default_rng(4).normal(size=(100, 3))))]
    k1 = np.full(100, 10.0)
    d = decide_type(faces, all_adjacent(1), TOL, COPLANAR, curvature=(k1, 0.4 * k1))
    assert d.candidates == ()
