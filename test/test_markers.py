"""msg_adapters.markers: primitives -> MarkerArray, labelled clouds (no rclpy.init)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from sensor_msgs.msg import PointField
from std_msgs.msg import Header
from visualization_msgs.msg import Marker

from geomodel_ros.core.primitives import Primitive
from msg_adapters.markers import (CONE_SEGMENTS, LABEL_NAMESPACE, PLANE_THICKNESS,
                                  UNKNOWN_MARKER_SIZE, object_colours, primitives_to_markers,
                                  reconstruction_cloud, rotation_to_quaternion, segments_cloud)
from msg_adapters.pointcloud2 import cloud_to_fields, cloud_to_xyz_and_mask, pack_rgb

HEADER = Header(stamp=Time(sec=1234, nanosec=567_000_000), frame_id="camera_optical")


def quat_to_matrix(q) -> np.ndarray:
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def axis_angle(axis, angle) -> np.ndarray:
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


def random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def marker_rotation(m: Marker) -> np.ndarray:
    o = m.pose.orientation
    return quat_to_matrix((o.x, o.y, o.z, o.w))


def marker_position(m: Marker) -> np.ndarray:
    p = m.pose.position
    return np.array([p.x, p.y, p.z])


# --------------------------------------------------------------------------- quaternions
@pytest.mark.parametrize("axis, angle, expected", [
    ((1, 0, 0), 0.0, (0, 0, 0, 1)),
    ((0, 0, 1), math.pi / 2, (0, 0, math.sqrt(0.5), math.sqrt(0.5))),
    ((1, 0, 0), math.pi / 2, (math.sqrt(0.5), 0, 0, math.sqrt(0.5))),
    ((0, 1, 0), -math.pi / 3, (0, -0.5, 0, math.sqrt(0.75))),
    ((1, 0, 0), math.pi, (1, 0, 0, 0)),
    ((0, 1, 0), math.pi, (0, 1, 0, 0)),
    ((0, 0, 1), math.pi, (0, 0, 1, 0)),
    ((1, 1, 0), math.pi, (math.sqrt(0.5), math.sqrt(0.5), 0, 0)),
])
def test_quaternion_of_known_rotations(axis, angle, expected):
    q = rotation_to_quaternion(axis_angle(axis, angle))
    exp = np.array(expected, dtype=float)
    # q and -q are the same rotation; w >= 0 fixes the sign except at w == 0
    assert np.allclose(q, exp, atol=1e-12) or np.allclose(q, -exp, atol=1e-12)
    assert q[3] >= 0.0


def test_quaternion_round_trip_random_rotations():
    rng = np.random.default_rng(7)
    for _ in range(500):
        r = random_rotation(rng)
        q = rotation_to_quaternion(r)
        assert abs(np.linalg.norm(q) - 1.0) < 1e-12
        assert q[3] >= 0.0
        assert np.allclose(quat_to_matrix(q), r, atol=1e-12)


def test_quaternion_near_pi_rotations_are_accurate():
    # trace close to -1: the branch where the naive w-based formula loses all precision
    rng = np.random.default_rng(3)
    for _ in range(100):
        axis = rng.normal(size=3)
        r = axis_angle(axis, math.pi - 1e-9)
        assert np.allclose(quat_to_matrix(rotation_to_quaternion(r)), r, atol=1e-9)


def test_quaternion_of_nearly_orthonormal_matrix_is_the_nearest_rotation():
    rng = np.random.default_rng(11)
    r = random_rotation(rng)
    q = rotation_to_quaternion(r + 1e-4 * rng.normal(size=(3, 3)))
    assert abs(np.linalg.norm(q) - 1.0) < 1e-12
    assert np.allclose(quat_to_matrix(q), r, atol=1e-3)


def test_quaternion_of_reflection_keeps_the_z_axis():
    rng = np.random.default_rng(5)
    r = random_rotation(rng)
    reflected = r.copy()
    reflected[:, 0] = -reflected[:, 0]
    back = quat_to_matrix(rotation_to_quaternion(reflected))
    assert np.allclose(back, r, atol=1e-12)
    assert np.allclose(back[:, 2], reflected[:, 2])


@pytest.mark.parametrize("bad, match", [
    (np.eye(2), "finite \\(3, 3\\)"),
    (np.full((3, 3), np.nan), "finite"),
    (np.zeros((3, 3)), "full rank"),
    (np.outer([1, 0, 0], [1, 1, 1]), "full rank"),
])
def test_quaternion_rejects_invalid_matrices(bad, match):
    with pytest.raises(ValueError, match=match):
        rotation_to_quaternion(bad)


# --------------------------------------------------------------------------- markers
ROT = axis_angle((1, 2, 3), 0.7)


def prim(oid, kind, dims, center=(0.1, -0.05, 0.6), rotation=ROT) -> Primitive:
    return Primitive(oid, kind, np.array(center, dtype=float), np.array(rotation, dtype=float),
                     dict(dims), 1000, 0.0005)


SCENE = [
    prim(0, "plane", {"length": 0.4, "width": 0.3}),
    prim(1, "cuboid", {"length": 0.08, "width": 0.06, "height": 0.05}),
    prim(2, "cylinder", {"radius": 0.05, "height": 0.06}),
    prim(3, "cone", {"radius": 0.03, "height": 0.05}),
    prim(4, "sphere", {"radius": 0.025}, rotation=np.eye(3)),
    prim(5, "unknown", {}, rotation=np.eye(3)),
    prim(6, "frustum", {"radius": 0.045, "top_radius": 0.03, "height": 0.09}),
]


def by_ns(array, ns) -> list[Marker]:
    return [m for m in array.markers if m.ns == ns and m.action == Marker.ADD]


def test_deleteall_first_and_header_copied_everywhere():
    out = primitives_to_markers(SCENE, HEADER)
    assert out.markers[0].action == Marker.DELETEALL
    assert all(m.action == Marker.ADD for m in out.markers[1:])
    for m in out.markers:
        assert m.header.frame_id == "camera_optical"
        assert (m.header.stamp.sec, m.header.stamp.nanosec) == (1234, 567_000_000)
        assert m.header is not HEADER
    # one shape and one label per object
    assert len(out.markers) == 1 + 2 * len(SCENE)


def test_every_marker_has_finite_pose_unit_quaternion_and_positive_scale():
    out = primitives_to_markers(SCENE, HEADER)
    for m in out.markers[1:]:
        p, o, s = m.pose.position, m.pose.orientation, m.scale
        assert all(math.isfinite(v) for v in (p.x, p.y, p.z, o.x, o.y, o.z, o.w))
        assert abs(math.sqrt(o.x ** 2 + o.y ** 2 + o.z ** 2 + o.w ** 2) - 1.0) < 1e-9
        assert s.x > 0 and s.y > 0 and s.z > 0


def test_ids_are_object_ids_and_unique_per_namespace():
    out = primitives_to_markers(SCENE, HEADER)
    keys = [(m.ns, m.id) for m in out.markers[1:]]
    assert len(keys) == len(set(keys))
    for p in SCENE:
        assert (p.type, p.id) in keys
        assert (LABEL_NAMESPACE, p.id) in keys
    big = primitives_to_markers([prim(2**31 + 5, "sphere", {"radius": 0.01})], HEADER)
    assert -(2**31) <= big.markers[1].id < 2**31


def test_plane_is_a_thin_cube_with_the_plane_pose():
    (m,) = by_ns(primitives_to_markers(SCENE, HEADER), "plane")
    assert m.type == Marker.CUBE
    assert (m.scale.x, m.scale.y, m.scale.z) == (0.4, 0.3, PLANE_THICKNESS)
    assert np.allclose(marker_position(m), SCENE[0].center)
    assert np.allclose(marker_rotation(m), ROT, atol=1e-12)


def test_cuboid_is_a_cube_with_its_extents_along_its_axes():
    (m,) = by_ns(primitives_to_markers(SCENE, HEADER), "cuboid")
    assert m.type == Marker.CUBE
    assert (m.scale.x, m.scale.y, m.scale.z) == (0.08, 0.06, 0.05)
    assert np.allclose(marker_rotation(m), ROT, atol=1e-12)


def test_cylinder_scale_is_diameter_and_height_with_marker_z_on_the_axis():
    (m,) = by_ns(primitives_to_markers(SCENE, HEADER), "cylinder")
    assert m.type == Marker.CYLINDER
    assert (m.scale.x, m.scale.y, m.scale.z) == (0.1, 0.1, 0.06)
    assert np.allclose(marker_position(m), SCENE[2].center)
    assert np.allclose(marker_rotation(m)[:, 2], ROT[:, 2], atol=1e-12)


def test_sphere_scale_is_the_diameter():
    (m,) = by_ns(primitives_to_markers(SCENE, HEADER), "sphere")
    assert m.type == Marker.SPHERE
    assert (m.scale.x, m.scale.y, m.scale.z) == (0.05, 0.05, 0.05)
    assert np.allclose(marker_position(m), SCENE[4].center)


def test_cone_is_a_closed_triangle_mesh_from_base_to_apex():
    (m,) = by_ns(primitives_to_markers(SCENE, HEADER), "cone")
    assert m.type == Marker.TRIANGLE_LIST
    assert (m.scale.x, m.scale.y, m.scale.z) == (1.0, 1.0, 1.0)
    local = np.array([[p.x, p.y, p.z] for p in m.points])
    assert len(local) == 6 * CONE_SEGMENTS  # lateral + base triangles, 3 points each
    r, h = 0.03, 0.05
    assert np.all(np.hypot(local[:, 0], local[:, 1]) <= r + 1e-12)
    assert local[:, 2].min() == pytest.approx(-h / 2) and local[:, 2].max() == pytest.approx(h / 2)
    # apex and base centre in the scene frame: centre -+ h/2 along the object's z (base->apex)
    world = local @ marker_rotation(m).T + marker_position(m)
    apex = SCENE[3].center + h / 2 * ROT[:, 2]
    assert np.min(np.linalg.norm(world - apex, axis=1)) < 1e-9
    base_rim = world[np.isclose(local[:, 2], -h / 2) & (np.hypot(local[:, 0], local[:, 1]) > r / 2)]
    base_center = SCENE[3].center - h / 2 * ROT[:, 2]
    assert np.allclose(np.linalg.norm(base_rim - base_center, axis=1), r)
    # lateral triangles face outwards
    tri = local[: 3 * CONE_SEGMENTS].reshape(-1, 3, 3)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centroids = tri.mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", normals[:, :2], centroids[:, :2]) > 0)


def test_frustum_is_a_closed_triangle_mesh_on_its_analytic_surface():
    (m,) = by_ns(primitives_to_markers(SCENE, HEADER), "frustum")
    assert m.type == Marker.TRIANGLE_LIST
    assert (m.scale.x, m.scale.y, m.scale.z) == (1.0, 1.0, 1.0)  # vertices in metres
    local = np.array([[p.x, p.y, p.z] for p in m.points])
    # per segment: two side triangles, one of the base disc, one of the top disc
    assert len(local) == 12 * CONE_SEGMENTS
    r, top, h = 0.045, 0.03, 0.09
    rho, z = np.hypot(local[:, 0], local[:, 1]), local[:, 2]
    # Every vertex is a disc centre or on a rim: base (rho = r, z = -h/2) or top
    # (rho = top, z = +h/2); the side between the rims is the line joining them.
    at_base, at_top = np.isclose(z, -h / 2, atol=1e-15), np.isclose(z, h / 2, atol=1e-15)
    assert np.all(at_base | at_top)
    assert np.allclose(rho[at_base & (rho > 1e-12)], r, atol=1e-15)
    assert np.allclose(rho[at_top & (rho > 1e-12)], top, atol=1e-15)
    tri = local.reshape(-1, 3, 3)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centroids = tri.mean(axis=1)
    side = slice(0, 2 * CONE_SEGMENTS)
    # side triangles face outwards; their centroids lie on the side's plane chords, inside
    # the analytic surface rho = r - (r - top) (z + h/2) / h by at most the chord's sag
    assert np.all(np.einsum("ij,ij->i", normals[side, :2], centroids[side, :2]) > 0)
    surface_rho = r - (r - top) * (centroids[side, 2] + h / 2) / h
    sag = 1.0 - math.cos(math.pi / CONE_SEGMENTS)
    assert np.all(np.hypot(centroids[side, 0], centroids[side, 1]) <= surface_rho + 1e-15)
    assert np.all(np.hypot(centroids[side, 0], centroids[side, 1]) >= surface_rho * (1 - sag))
    base_n = normals[2 * CONE_SEGMENTS:3 * CONE_SEGMENTS]
    lid_n = normals[3 * CONE_SEGMENTS:]
    assert np.all(base_n[:, 2] < 0) and np.all(lid_n[:, 2] > 0)  # caps face out
    # in the scene frame the base centre is centre - h/2 z, the top's centre + h/2 z
    world = local @ marker_rotation(m).T + marker_position(m)
    for sign, radius in ((-1.0, r), (1.0, top)):
        ring = world[np.isclose(z, sign * h / 2, atol=1e-15) & (rho > 1e-12)]
        centre = SCENE[6].center + sign * h / 2 * ROT[:, 2]
        assert np.allclose(np.linalg.norm(ring - centre, axis=1), radius, atol=1e-12)


def test_unknown_object_gets_a_small_sphere_and_a_label_only():
    out = primitives_to_markers(SCENE, HEADER)
    (m,) = by_ns(out, "unknown")
    assert m.type == Marker.SPHERE and m.scale.x == pytest.approx(UNKNOWN_MARKER_SIZE)
    (label,) = [t for t in by_ns(out, LABEL_NAMESPACE) if t.id == 5]
    assert label.text == "unknown"


def test_label_texts_give_type_and_dimensions_in_mm():
    out = primitives_to_markers(SCENE, HEADER)
    texts = {m.id: m.text for m in by_ns(out, LABEL_NAMESPACE)}
    assert texts == {
        0: "plane l=400.0 w=300.0 mm",
        1: "cuboid l=80.0 w=60.0 h=50.0 mm",
        2: "cylinder r=50.0 h=60.0 mm",
        3: "cone r=30.0 h=50.0 mm",
        4: "sphere r=25.0 mm",
        5: "unknown",
        6: "frustum r=45.0 t=30.0 h=90.0 mm",
    }
    for m in by_ns(out, LABEL_NAMESPACE):
        assert m.type == Marker.TEXT_VIEW_FACING and m.scale.z > 0


def test_labels_sit_above_their_object():
    # optical frame: up is -y; a sphere of radius 25 mm -> label at least 25 mm higher
    out = primitives_to_markers([SCENE[4]], HEADER)
    label = by_ns(out, LABEL_NAMESPACE)[0]
    lift = SCENE[4].center - marker_position(label)
    assert lift[1] > 0.025 and abs(lift[0]) < 1e-12 and abs(lift[2]) < 1e-12
    # z-up frame (REP 103 body frames)
    base = Header(stamp=HEADER.stamp, frame_id="base_link")
    label = by_ns(primitives_to_markers([SCENE[4]], base), LABEL_NAMESPACE)[0]
    assert marker_position(label)[2] - SCENE[4].center[2] > 0.025
    # a standing cylinder (axis = up) of height 60 mm: label above its top
    standing = prim(9, "cylinder", {"radius": 0.05, "height": 0.06}, rotation=np.eye(3))
    label = by_ns(primitives_to_markers([standing], base), LABEL_NAMESPACE)[0]
    assert marker_position(label)[2] - standing.center[2] > 0.03
    explicit = by_ns(primitives_to_markers([standing], base, up=(1, 0, 0)), LABEL_NAMESPACE)[0]
    assert marker_position(explicit)[0] - standing.center[0] > 0.05


def test_text_false_and_lifetime():
    out = primitives_to_markers(SCENE, HEADER, text=False, lifetime_s=1.25)
    assert not by_ns(out, LABEL_NAMESPACE)
    assert len(out.markers) == 1 + len(SCENE)
    for m in out.markers[1:]:
        assert (m.lifetime.sec, m.lifetime.nanosec) == (1, 250_000_000)


def test_empty_input_gives_only_deleteall():
    out = primitives_to_markers([], HEADER)
    assert len(out.markers) == 1 and out.markers[0].action == Marker.DELETEALL


def test_degenerate_primitives_are_drawn_safely():
    bad = [
        prim(1, "cylinder", {"radius": 0.0, "height": 0.05}),
        prim(2, "cuboid", {"length": float("nan"), "width": 0.1, "height": 0.1}),
        prim(3, "sphere", {"radius": 0.02}, center=(np.nan, 0, 1)),  # cannot be placed
        prim(4, "plane", {"length": 0.1, "width": 0.1}, rotation=np.zeros((3, 3))),
    ]
    out = primitives_to_markers(bad, HEADER)
    texts = {m.id: m.text for m in by_ns(out, LABEL_NAMESPACE)}
    assert texts == {1: "cylinder (invalid size)", 2: "cuboid (invalid size)",
                     4: "plane l=100.0 w=100.0 mm"}
    for m in out.markers[1:]:
        o, s = m.pose.orientation, m.scale
        assert all(math.isfinite(v) for v in (o.x, o.y, o.z, o.w))
        assert s.x > 0 and s.y > 0 and s.z > 0


@pytest.mark.parametrize("kwargs, match", [
    ({"lifetime_s": -1.0}, "lifetime_s"),
    ({"lifetime_s": float("inf")}, "lifetime_s"),
    ({"text_size": 0.0}, "text_size"),
    ({"up": (0, 0, 0)}, "up"),
    ({"up": (1, 0)}, "up"),
])
def test_invalid_arguments_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        primitives_to_markers(SCENE, HEADER, **kwargs)


# --------------------------------------------------------------------------- clouds
def test_object_colours_are_deterministic_and_distinct():
    ids = np.arange(-1, 12)
    a, b = object_colours(ids), object_colours(ids[::-1])[::-1]
    assert a.dtype == np.uint8 and a.shape == (13, 3)
    assert np.array_equal(a, b)
    assert tuple(a[0]) == (128, 128, 128)
    assert len({tuple(c) for c in a}) == 13
    # sparse ids (looked up through np.unique) get the same colours as dense ones
    sparse = object_colours(np.array([5, 10**12, -3, 5]))
    assert np.array_equal(sparse[[0, 3]], object_colours(np.array([5, 5])))
    assert tuple(sparse[2]) == (128, 128, 128)
    assert object_colours(np.zeros(0, dtype=np.int32)).shape == (0, 3)


@pytest.mark.parametrize("build", [segments_cloud, reconstruction_cloud])
def test_labelled_cloud_round_trip(build):
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, size=(500, 3))
    ids = rng.integers(-1, 7, size=500)
    msg = build(pts, ids, HEADER)
    assert msg.header.frame_id == "camera_optical"
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1234, 567_000_000)
    types = {f.name: f.datatype for f in msg.fields}
    assert types == {"x": PointField.FLOAT32, "y": PointField.FLOAT32, "z": PointField.FLOAT32,
                     "object_id": PointField.INT32, "rgb": PointField.FLOAT32}
    xyz, mask = cloud_to_xyz_and_mask(msg)
    assert mask.all()
    assert np.allclose(xyz, pts, atol=1e-6)
    fields = cloud_to_fields(msg, ["object_id", "rgb"], mask=mask)
    assert fields["object_id"].dtype == np.int32
    assert np.array_equal(fields["object_id"], ids)
    assert np.array_equal(fields["rgb"], pack_rgb(object_colours(ids)))


def test_segments_and_reconstruction_colours_agree_per_object():
    pts = np.zeros((3, 3))
    a = cloud_to_fields(segments_cloud(pts, np.array([4, 4, -1]), HEADER), ["rgb"])["rgb"]
    b = cloud_to_fields(reconstruction_cloud(pts, np.array([4, 2, 4]), HEADER), ["rgb"])["rgb"]
    assert a[0] == a[1] == b[0] == b[2] and a[2] != a[0] and b[1] != b[0]


def test_empty_labelled_cloud():
    msg = reconstruction_cloud(np.zeros((0, 3)), np.zeros(0, dtype=np.int32), HEADER)
    assert msg.width == 0 and len(msg.data) == 0
    assert {f.name for f in msg.fields} == {"x", "y", "z", "object_id", "rgb"}


@pytest.mark.parametrize("pts, ids, match", [
    (np.zeros((4, 2)), np.zeros(4, dtype=int), "\\(N, 3\\)"),
    (np.zeros((4, 3)), np.zeros(3, dtype=int), "aligned"),
    (np.zeros((4, 3)), np.zeros(4), "integer"),
    (np.zeros((2, 3)), np.array([0, 2**40]), "int32"),
])
def test_labelled_cloud_rejects_bad_input(pts, ids, match):
    with pytest.raises(ValueError, match=match):
        segments_cloud(pts, ids, HEADER)


def test_markers_to_primitives_inverts_primitives_to_markers():
    from msg_adapters.markers import markers_to_primitives
    from std_msgs.msg import Header

    rng = np.random.default_rng(5)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    rot = q * np.sign(np.linalg.det(q))
    prims = [
        Primitive(1, "plane", np.array([0.0, 0.1, 0.8]), rot, {"length": 0.4, "width": 0.3},
                  10, 0.0),
        Primitive(2, "cuboid", np.array([0.1, 0.0, 0.6]), rot, {"length": 0.05, "width": 0.06,
                                                                "height": 0.07}, 10, 0.0),
        Primitive(3, "cylinder", np.array([-0.1, 0.0, 0.6]), rot, {"radius": 0.02, "height": 0.08},
                  10, 0.0),
        Primitive(4, "cone", np.array([0.0, -0.1, 0.7]), rot, {"radius": 0.03, "height": 0.05},
                  10, 0.0),
        Primitive(5, "sphere", np.array([0.2, 0.2, 0.9]), np.eye(3), {"radius": 0.025}, 10, 0.0),
        Primitive(6, "unknown", np.array([0.0, 0.0, 1.0]), np.eye(3), {}, 10, 0.0),
        Primitive(7, "frustum", np.array([0.1, 0.1, 0.8]), rot,
                  {"radius": 0.045, "top_radius": 0.03, "height": 0.09}, 10, 0.0),
    ]
    back = markers_to_primitives(primitives_to_markers(prims, Header(frame_id="cam")))
    assert [p.id for p in back] == [1, 2, 3, 4, 5, 7]  # unknown has no shape to recover
    prims = [p for p in prims if p.type != "unknown"]
    for orig, got in zip(prims, back):
        assert got.type == orig.type
        np.testing.assert_allclose(got.center, orig.center, atol=1e-9)
        for k, v in orig.dimensions.items():
            assert got.dimensions[k] == pytest.approx(v, abs=1e-9)
        if orig.type != "sphere":
            np.testing.assert_allclose(got.rotation, orig.rotation, atol=1e-9)
