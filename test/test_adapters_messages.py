"""The small adapters, without ``rclpy.init``.

Headers and stamps, CDR bytes, diagnostics, parameter descriptors, reading a frame's
markers back, and a cloud as the core takes it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterType
from sensor_msgs.msg import PointCloud2
from shape_msgs.msg import SolidPrimitive
from std_msgs.msg import Header
from visualization_msgs.msg import Marker

from geomodel_ros.core.params import ParamSpec
from geomodel_ros.core.primitives import Primitive
from msg_adapters.diagnostics import diagnostics_message, read_status_values
from msg_adapters.header import (StampedFrame, header_of, make_header, set_stamp, stamp_ns,
                                 stamp_text, time_from_ns)
from msg_adapters.markers import (marker_array_frame, marker_array_problem, primitives_to_markers,
                                  tracked_markers)
from msg_adapters.objects import PrimitiveMsg, objects_to_primitives, primitives_to_objects
from msg_adapters.parameters import option_descriptor, set_parameters_result, spec_descriptor
from msg_adapters.pointcloud2 import cloud_size, cloud_to_scene, xyz_to_cloud
from msg_adapters.serialization import DeserializationError, deserialize_cloud, serialize


# --------------------------------------------------------------------------- headers
@pytest.mark.parametrize("ns, sec, nanosec", [
    (0, 0, 0),
    (1_500_000_001, 1, 500_000_001),
    (1_767_225_600 * 10**9 + 999_999_999, 1_767_225_600, 999_999_999),
    (-1, -1, 999_999_999),  # before the epoch: nanosec stays in [0, 1e9)
])
def test_stamp_ns_maps_to_sec_and_nanosec_and_back(ns, sec, nanosec):
    t = time_from_ns(ns)
    assert (t.sec, t.nanosec) == (sec, nanosec)
    header = make_header("cam", ns)
    assert header.frame_id == "cam" and (header.stamp.sec, header.stamp.nanosec) == (sec, nanosec)
    assert stamp_ns(header) == ns


def test_header_of_reads_a_message_or_a_header():
    header = Header(stamp=Time(sec=3, nanosec=7), frame_id="base_link")
    cloud = xyz_to_cloud(np.zeros((1, 3)), header)
    assert header_of(cloud) == StampedFrame("base_link", 3 * 10**9 + 7)
    assert header_of(header) == ("base_link", 3_000_000_007)
    assert stamp_ns(cloud) == 3_000_000_007


def test_set_stamp_changes_only_the_stamp():
    cloud = xyz_to_cloud(np.zeros((2, 3)), make_header("cam", 5))
    data = bytes(cloud.data)
    set_stamp(cloud, 2 * 10**9 + 1)
    assert header_of(cloud) == ("cam", 2_000_000_001)
    assert bytes(cloud.data) == data


def test_stamp_text_has_nine_digits_of_nanoseconds():
    assert stamp_text(1_000_000_005) == "1.000000005"
    assert stamp_text(42 * 10**9 + 500) == "42.000000500"


# --------------------------------------------------------------------------- CDR
def test_cloud_survives_serialization_byte_for_byte():
    pts = np.array([[0.1, -0.2, 1.5], [np.nan, np.nan, np.nan]], dtype=np.float32)
    msg = xyz_to_cloud(pts, make_header("cam", 12_345), fields={"object_id": np.array([3, -1])})
    back = deserialize_cloud(serialize(msg))
    assert isinstance(back, PointCloud2)
    assert header_of(back) == ("cam", 12_345)
    assert (back.height, back.width, back.point_step, back.row_step) == (
        msg.height, msg.width, msg.point_step, msg.row_step)
    assert [(f.name, f.offset, f.datatype) for f in back.fields] == [
        (f.name, f.offset, f.datatype) for f in msg.fields]
    assert bytes(back.data) == bytes(msg.data)


@pytest.mark.parametrize("raw", [b"", b"\x00\x01\x00\x00\x05"])
def test_garbage_bytes_are_a_deserialization_error(raw):
    with pytest.raises(DeserializationError):
        deserialize_cloud(raw)


# --------------------------------------------------------------------------- diagnostics
def test_diagnostics_message_holds_one_status_in_order():
    msg = diagnostics_message("modeler: modeling", "/modeler", "warn", "frames failed",
                              {"b": "2", "a": "1"}, 7 * 10**9 + 3)
    assert isinstance(msg, DiagnosticArray) and stamp_ns(msg) == 7_000_000_003
    (status,) = msg.status
    assert status.level == DiagnosticStatus.WARN
    assert (status.name, status.hardware_id, status.message) == (
        "modeler: modeling", "/modeler", "frames failed")
    assert [(kv.key, kv.value) for kv in status.values] == [("b", "2"), ("a", "1")]
    with pytest.raises(ValueError, match="level 'fine' is not allowed"):
        diagnostics_message("n", "h", "fine", "", {}, 0)


def test_read_status_values_picks_the_status_of_the_hardware_id():
    other = DiagnosticStatus(hardware_id="/camera", values=[KeyValue(key="k", value="x")])
    ours = DiagnosticStatus(hardware_id="/robot/modeler", values=[KeyValue(key="k", value="y")])
    assert read_status_values(DiagnosticArray(status=[other, ours]), "/modeler") == {"k": "y"}
    assert read_status_values(DiagnosticArray(status=[other]), "/modeler") is None


# --------------------------------------------------------------------------- parameters
def test_spec_descriptor_types_ranges_and_description():
    d = spec_descriptor(ParamSpec("voxel_size", 0.003, "m", 0.0005, 0.05, "Voxel edge."))
    assert d.type == ParameterType.PARAMETER_DOUBLE
    assert d.description == "Voxel edge. [m] Range [0.0005, 0.05]."
    r = d.floating_point_range[0]
    assert (r.from_value, r.to_value, r.step) == (0.0005, 0.05, 0.0)

    d = spec_descriptor(ParamSpec("seed", 0, "count", 0, None, "Seed."))
    assert d.type == ParameterType.PARAMETER_INTEGER
    r = d.integer_range[0]
    assert (r.from_value, r.to_value) == (0, 2**63 - 1)  # open end = int64 maximum

    d = spec_descriptor(ParamSpec("edge_correction", True, "", None, None, "Correct edges."))
    assert d.type == ParameterType.PARAMETER_BOOL and d.description == "Correct edges."
    assert not d.floating_point_range and not d.integer_range


def test_option_descriptor_and_results():
    d = option_descriptor("qos_depth", 1, "Depth.", read_only=True, low=1, high=1000)
    assert d.type == ParameterType.PARAMETER_INTEGER and d.read_only
    assert (d.integer_range[0].from_value, d.integer_range[0].to_value) == (1, 1000)
    d = option_descriptor("qos_reliability", "best_effort", "R.", constraints="one of: a, b")
    assert d.type == ParameterType.PARAMETER_STRING and d.additional_constraints == "one of: a, b"
    assert option_descriptor("diagnostics", True, "D.").type == ParameterType.PARAMETER_BOOL
    assert set_parameters_result().successful
    rejected = set_parameters_result("min_radius must be < max_radius")
    assert not rejected.successful and rejected.reason == "min_radius must be < max_radius"


# --------------------------------------------------------------------------- markers
def _markers(stamp: int = 9):
    box = Primitive(1, "cuboid", np.array([0.0, 0.0, 1.0]), np.eye(3),
                    {"length": 0.1, "width": 0.08, "height": 0.05}, 100, 0.0)
    return primitives_to_markers([box], make_header("cam", stamp))


def test_marker_array_frame_is_the_inputs_header():
    assert marker_array_frame(_markers(11)) == ("cam", 11)
    empty = _markers()
    empty.markers = []
    assert marker_array_frame(empty) is None


def test_marker_array_problem_accepts_the_adapters_output():
    assert marker_array_problem(_markers(9), StampedFrame("cam", 9)) is None


@pytest.mark.parametrize("break_it, why", [
    (lambda a: a.markers.append(Marker(header=a.markers[0].header, action=Marker.DELETEALL)),
     "DELETEALL after the first marker"),
    (lambda a: a.markers.clear(), "is empty"),
    (lambda a: setattr(a.markers[1].header, "frame_id", "map"), "another header"),
    (lambda a: setattr(a.markers[1].pose.position, "x", math.nan), "non-finite pose"),
    (lambda a: setattr(a.markers[1].scale, "z", 0.0), "non-positive or non-finite scale"),
    (lambda a: setattr(a.markers[2].scale, "x", math.inf), "non-positive or non-finite"),
])
def test_marker_array_problem_names_what_is_wrong(break_it, why):
    markers = _markers(9)
    assert markers.markers[1].type == Marker.CUBE  # the shape; [2] is its label
    break_it(markers)
    assert why in marker_array_problem(markers, StampedFrame("cam", 9))


def test_marker_array_problem_checks_the_stamp():
    assert "another header" in marker_array_problem(_markers(9), StampedFrame("cam", 10))


# --------------------------------------------------------------------------- clouds
def test_cloud_to_scene_keeps_every_row_and_the_grid():
    grid = np.arange(2 * 3 * 3, dtype=np.float32).reshape(2, 3, 3)
    grid[1, 2] = np.nan
    scene = cloud_to_scene(xyz_to_cloud(grid, make_header("cam", 4)))
    assert scene.points.shape == (6, 3) and scene.points.dtype == np.float64
    np.testing.assert_array_equal(scene.points, grid.reshape(-1, 3).astype(np.float64))
    assert scene.organized_shape == (2, 3)
    assert header_of(scene.header) == ("cam", 4)

    flat = cloud_to_scene(xyz_to_cloud(grid.reshape(-1, 3), make_header("cam", 4)))
    assert flat.organized_shape is None and flat.points.shape == (6, 3)


def test_cloud_size_is_the_declared_grid_and_payload():
    msg = xyz_to_cloud(np.zeros((4, 5, 3)), make_header("cam"))
    assert cloud_size(msg) == (4, 5, 4 * 5 * 12)  # x, y, z float32: 12 bytes per point


# --------------------------------------------------------------------------- typed objects
def _quat_matrix(q) -> np.ndarray:
    """Rotation of a unit quaternion (x, y, z, w), the textbook formula."""
    x, y, z, w = q.x, q.y, q.z, q.w
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _frame_with_z(z) -> np.ndarray:
    z = np.asarray(z, float) / np.linalg.norm(z)
    x = np.cross([0.0, 0.0, 1.0], z) if abs(z[2]) < 0.9 else np.cross([1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _position(m) -> np.ndarray:
    return np.array([m.pose.position.x, m.pose.position.y, m.pose.position.z])


def test_cylinder_becomes_a_solid_cylinder_along_the_pose_z():
    axis = np.array([1.0, 1.0, 0.0]) / math.sqrt(2.0)
    cyl = Primitive(3, "cylinder", np.array([0.1, -0.2, 0.8]), _frame_with_z(axis),
                    {"radius": 0.04, "height": 0.12}, 1500, 0.002, reason="cylinder verified")
    (m,) = primitives_to_objects([cyl], make_header("cam", 5)).primitives
    assert m.type == PrimitiveMsg.CYLINDER and m.id == 3
    assert m.shape.type == SolidPrimitive.CYLINDER
    assert list(m.shape.dimensions) == [0.12, 0.04]  # MoveIt: [height, radius]
    assert _position(m) == pytest.approx([0.1, -0.2, 0.8])
    assert _quat_matrix(m.pose.orientation)[:, 2] == pytest.approx(axis, abs=1e-12)
    assert list(m.dimension_names) == ["radius", "height"]
    assert list(m.dimensions) == [0.04, 0.12]
    assert (m.point_count, m.reason) == (1500, "cylinder verified")
    assert m.rmse == pytest.approx(0.002, rel=1e-6)  # float32
    assert math.isnan(m.confidence)  # not estimated yet
    assert list(m.plane.coef) == [0.0, 0.0, 0.0, 0.0]


def test_cone_tip_is_at_plus_half_height_along_the_pose_z():
    apex = np.array([0.0, 0.1, 0.9])
    up = np.array([0.0, -1.0, 0.0])  # base -> apex
    h, r = 0.08, 0.03
    cone = Primitive(1, "cone", apex - up * h / 2, _frame_with_z(up), {"radius": r, "height": h},
                     800, 0.001)
    (m,) = primitives_to_objects([cone], make_header("cam", 5)).primitives
    assert m.shape.type == SolidPrimitive.CONE and list(m.shape.dimensions) == [h, r]
    tip = _position(m) + _quat_matrix(m.pose.orientation)[:, 2] * m.shape.dimensions[0] / 2
    assert tip == pytest.approx(apex, abs=1e-12)


def test_cuboid_box_dimensions_follow_the_rotation_columns_and_w_is_not_negative():
    # 270 degrees about z: the quaternion (0, 0, sin 135, cos 135) has w < 0; its negation
    # (0, 0, -sin 135, -cos 135) = (0, 0, -0.7071, 0.7071) is the same rotation.
    rot = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    box = Primitive(2, "cuboid", np.zeros(3), rot, {"length": 0.3, "width": 0.2, "height": 0.1},
                    100, 0.001)
    (m,) = primitives_to_objects([box], make_header("cam", 5)).primitives
    assert m.shape.type == SolidPrimitive.BOX and list(m.shape.dimensions) == [0.3, 0.2, 0.1]
    q = m.pose.orientation
    assert (q.x, q.y, q.z, q.w) == pytest.approx((0.0, 0.0, -math.sqrt(0.5), math.sqrt(0.5)))


def test_plane_is_a_flat_box_with_its_equation_facing_the_sensor():
    # a wall 1 m in front of the sensor, normal towards it (-z): -z + 1 = 0
    wall = Primitive(0, "plane", np.array([0.2, 0.0, 1.0]), _frame_with_z([0.0, 0.0, -1.0]),
                     {"length": 0.8, "width": 0.5}, 5000, 0.003)
    out = primitives_to_objects([wall], make_header("cam", 5),
                                supports={0: (np.array([0.0, 0.0, -2.0]), 1.0),
                                          9: (np.array([0.0, 1.0, 0.0]), 0.0)},
                                supported={0: [4, 5]})
    (m,) = out.primitives
    assert m.type == PrimitiveMsg.PLANE
    assert m.shape.type == SolidPrimitive.BOX and list(m.shape.dimensions) == [0.8, 0.5, 0.0]
    assert list(m.plane.coef) == pytest.approx([0.0, 0.0, -1.0, 1.0])
    assert sum(c * v for c, v in zip(m.plane.coef, [0.0, 0.0, 0.0, 1.0])) > 0  # sensor side
    (surface,) = out.support_surfaces  # id 9 is no plane of the message
    assert surface.id == 0 and list(surface.supported_ids) == [4, 5]
    assert list(surface.plane.coef) == pytest.approx([0.0, 0.0, -1.0, 1.0])  # normalised


def test_sphere_unknown_invalid_and_non_finite_objects():
    prims = [
        Primitive(0, "sphere", np.array([0.0, 0.0, 1.0]), np.eye(3), {"radius": 0.05}, 10, 0.0),
        Primitive(1, "unknown", np.array([0.1, 0.0, 1.0]), np.eye(3), {}, 10, 0.0,
                  reason="no rule accepted it"),
        Primitive(2, "cuboid", np.array([0.2, 0.0, 1.0]), np.eye(3),
                  {"length": math.nan, "width": 0.1, "height": 0.1}, 10, 0.0),
        Primitive(3, "cuboid", np.array([math.inf, 0.0, 1.0]), np.eye(3),
                  {"length": 0.1, "width": 0.1, "height": 0.1}, 10, 0.0),
    ]
    out = primitives_to_objects(prims, make_header("cam", 5))
    assert [m.id for m in out.primitives] == [0, 1, 2]  # the non-finite centre is left out
    sphere, unknown, invalid = out.primitives
    assert sphere.shape.type == SolidPrimitive.SPHERE and list(sphere.shape.dimensions) == [0.05]
    for m in (unknown, invalid):
        assert m.type == PrimitiveMsg.UNKNOWN
        assert list(m.dimensions) == [] and list(m.shape.dimensions) == []
    assert unknown.reason == "no rule accepted it"


def test_objects_carry_the_input_header_and_round_trip():
    header = make_header("camera_optical", 1_700_000_000_123_456_789)
    prims = [
        Primitive(7, "cuboid", np.array([0.1, 0.2, 0.9]), _frame_with_z([0.0, 1.0, 1.0]),
                  {"length": 0.1, "width": 0.06, "height": 0.04}, 321, 0.0015, reason="box"),
        Primitive(8, "cylinder", np.array([-0.1, 0.0, 1.1]), _frame_with_z([1.0, 0.0, 0.2]),
                  {"radius": 0.03, "height": 0.2}, 99, 0.001),
        Primitive(9, "sphere", np.array([0.0, 0.1, 0.7]), np.eye(3), {"radius": 0.02}, 5, 0.0),
    ]
    msg = primitives_to_objects(prims, header)
    assert header_of(msg) == StampedFrame("camera_optical", 1_700_000_000_123_456_789)
    back = objects_to_primitives(msg)
    for p, q in zip(prims, back, strict=True):
        assert (q.id, str(q.type), q.point_count, q.reason) == (p.id, str(p.type),
                                                                 p.point_count, p.reason)
        assert q.center == pytest.approx(p.center, abs=1e-15)
        assert q.rotation == pytest.approx(p.rotation, abs=1e-12)
        assert q.dimensions == p.dimensions
        assert q.rmse == pytest.approx(p.rmse, rel=1e-6)


# --------------------------------------------------------------------------- tracked markers
def _box(oid: int, kind: str = "cuboid") -> Primitive:
    dims = {"length": 0.1, "width": 0.1, "height": 0.1} if kind == "cuboid" else \
        {"radius": 0.05, "height": 0.1}
    return Primitive(oid, kind, np.array([0.1 * oid, 0.0, 1.0]), np.eye(3), dims, 10, 0.0)


def test_tracked_markers_add_per_id_and_delete_retired_and_retyped_ones():
    header = make_header("cam", 1)
    first, shown = tracked_markers([_box(1), _box(2)], header, clear=True)
    assert first.markers[0].action == Marker.DELETEALL
    assert shown == {1: "cuboid", 2: "cuboid"}
    # id 1 retired, id 2 now a cylinder, id 3 new: no DELETEALL
    second, shown = tracked_markers([_box(2, "cylinder"), _box(3)], header, deleted_ids=(1,),
                                    previous=shown)
    actions = [(m.action, m.ns, m.id) for m in second.markers]
    assert Marker.DELETEALL not in [a for a, _, _ in actions]
    deletes = {(ns, i) for a, ns, i in actions if a == Marker.DELETE}
    assert deletes == {("cuboid", 1), ("labels", 1), ("cuboid", 2)}
    adds = {(ns, i) for a, ns, i in actions if a == Marker.ADD}
    assert adds == {("cylinder", 2), ("labels", 2), ("cuboid", 3), ("labels", 3)}
    assert shown == {2: "cylinder", 3: "cuboid"}
    assert marker_array_problem(second, StampedFrame("cam", 1)) is None
