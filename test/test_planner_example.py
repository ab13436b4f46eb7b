"""The planner example: geomodel_msgs/PrimitiveArray -> MoveIt-style collision objects.

Messages are built directly (no node).  Expected values are worked out by hand from
MoveIt's conventions (``moveit_msgs/CollisionObject``: ``primitives`` + ``primitive_poses``,
``shape_msgs/SolidPrimitive`` dimension order) and the contract of ``Primitive.msg``; the
example node is run once over real rclpy pub/sub in a private context.
"""

from __future__ import annotations

import math
import threading
import time

import pytest
import rclpy
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, Quaternion
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from shape_msgs.msg import SolidPrimitive
from std_msgs.msg import Header

from geomodel_msgs.msg import Primitive, PrimitiveArray
from geomodel_ros.tools.planner_example import (PLANE_THICKNESS, PlannerExample,
                                                to_collision_objects)

FRAME = "camera_optical"
STAMP = Time(sec=1_700_000_123, nanosec=456_000_000)
HEADER = {"frame_id": FRAME, "stamp": {"sec": 1_700_000_123, "nanosec": 456_000_000}}
S = math.sqrt(0.5)
#: Rotation of 180 degrees about x: the pose's z axis is (0, 0, -1), towards a sensor at
#: the origin looking along +z (a wall or desk seen head-on).
FACING_SENSOR = (1.0, 0.0, 0.0, 0.0)
#: Rotation of +90 degrees about x: z axis (0, -1, 0), i.e. "up" in an optical frame (y
#: down): the floor seen by a camera above it.
FLOOR_UP = (S, 0.0, 0.0, S)
IDENTITY = (0.0, 0.0, 0.0, 1.0)
TIMEOUT = 30.0


def _primitive(pid, ptype, shape_type, dims, position, quat=IDENTITY) -> Primitive:
    x, y, z, w = quat
    return Primitive(id=pid, type=ptype,
                     shape=SolidPrimitive(type=shape_type, dimensions=list(dims)),
                     pose=Pose(position=Point(x=position[0], y=position[1], z=position[2]),
                               orientation=Quaternion(x=x, y=y, z=z, w=w)))


def _array(*primitives) -> PrimitiveArray:
    return PrimitiveArray(header=Header(frame_id=FRAME, stamp=STAMP),
                          primitives=list(primitives))


def _pose(position, quat=IDENTITY):
    return {"position": dict(zip("xyz", position)), "orientation": dict(zip("xyzw", quat))}


def _only(msg, previous=()):
    (obj,) = to_collision_objects(msg, previous)
    return obj


def test_cuboid_is_a_box_with_its_edge_lengths():
    obj = _only(_array(_primitive(7, Primitive.CUBOID, SolidPrimitive.BOX, (0.1, 0.2, 0.3),
                                  (0.1, -0.2, 0.8), (0.0, 0.0, S, S))))
    assert obj == {"id": "geomodel_7", "header": HEADER,
                   "primitives": [{"type": "box", "dimensions": [0.1, 0.2, 0.3]}],
                   "primitive_poses": [_pose((0.1, -0.2, 0.8), (0.0, 0.0, S, S))],
                   "operation": "add"}


@pytest.mark.parametrize("ptype, shape_type, dims, name", [
    (Primitive.CYLINDER, SolidPrimitive.CYLINDER, (0.12, 0.04), "cylinder"),  # [h, r]
    (Primitive.CONE, SolidPrimitive.CONE, (0.10, 0.03), "cone"),
    (Primitive.SPHERE, SolidPrimitive.SPHERE, (0.05,), "sphere"),
    # a frustum travels as its enclosing cylinder [height, bottom radius]
    (Primitive.FRUSTUM, SolidPrimitive.CYLINDER, (0.09, 0.045), "cylinder"),
])
def test_round_shapes_keep_moveit_dimensions_and_pose(ptype, shape_type, dims, name):
    obj = _only(_array(_primitive(3, ptype, shape_type, dims, (0.0, 0.1, 0.6), FLOOR_UP)))
    assert obj["primitives"] == [{"type": name, "dimensions": list(dims)}]
    assert obj["primitive_poses"] == [_pose((0.0, 0.1, 0.6), FLOOR_UP)]
    assert obj["id"] == "geomodel_3" and obj["operation"] == "add"


def test_plane_seen_head_on_becomes_a_thin_box_behind_its_surface():
    # a wall 1 m in front of the sensor; normal (0, 0, -1) towards the sensor
    obj = _only(_array(_primitive(1, Primitive.PLANE, SolidPrimitive.BOX, (1.2, 0.8, 0.0),
                                  (0.0, 0.3, 1.0), FACING_SENSOR)))
    assert obj["primitives"] == [{"type": "box", "dimensions": [1.2, 0.8, PLANE_THICKNESS]}]
    (pose,) = obj["primitive_poses"]
    # the box spans z in [1, 1 + thickness]: its face nearest the sensor is the wall
    assert pose["position"] == pytest.approx({"x": 0.0, "y": 0.3,
                                              "z": 1.0 + PLANE_THICKNESS / 2}, abs=1e-12)
    assert pose["orientation"] == dict(zip("xyzw", FACING_SENSOR))


def test_floor_becomes_a_thin_box_below_its_surface():
    # floor 0.5 m below an optical-frame camera (y down), normal (0, -1, 0) = up
    obj = _only(_array(_primitive(2, Primitive.PLANE, SolidPrimitive.BOX, (3.0, 2.0, 0.0),
                                  (0.2, 0.5, 2.0), FLOOR_UP)))
    position = obj["primitive_poses"][0]["position"]
    assert position == pytest.approx({"x": 0.2, "y": 0.5 + PLANE_THICKNESS / 2, "z": 2.0},
                                     abs=1e-12)
    assert position["y"] - PLANE_THICKNESS / 2 == pytest.approx(0.5, abs=1e-12)  # top face


def test_unknown_objects_are_skipped():
    msg = _array(_primitive(4, Primitive.UNKNOWN, 0, (), (0.0, 0.0, 1.0)),
                 _primitive(5, Primitive.SPHERE, SolidPrimitive.SPHERE, (0.02,), (0, 0, 1)))
    objects = to_collision_objects(msg)
    assert [o["id"] for o in objects] == ["geomodel_5"]


def test_order_follows_the_message_and_ids_are_the_stable_ids():
    msg = _array(_primitive(12, Primitive.SPHERE, SolidPrimitive.SPHERE, (0.02,), (0, 0, 1)),
                 _primitive(4, Primitive.CUBOID, SolidPrimitive.BOX, (0.1, 0.1, 0.1),
                            (0, 0, 1)))
    assert [o["id"] for o in to_collision_objects(msg)] == ["geomodel_12", "geomodel_4"]


def test_vanished_objects_are_removed_and_present_ones_not():
    msg = _array(_primitive(7, Primitive.CUBOID, SolidPrimitive.BOX, (0.1, 0.1, 0.1),
                            (0, 0, 1)),
                 _primitive(8, Primitive.UNKNOWN, 0, (), (0, 0, 1)))  # was a box: now none
    objects = to_collision_objects(msg, {"geomodel_7", "geomodel_99", "geomodel_8"})
    assert [(o["id"], o["operation"]) for o in objects] == [
        ("geomodel_7", "add"), ("geomodel_8", "remove"), ("geomodel_99", "remove")]
    assert objects[1] == {"id": "geomodel_8", "header": HEADER, "operation": "remove"}


def test_empty_message_removes_everything_and_adds_nothing():
    assert to_collision_objects(_array()) == []
    assert [o["operation"] for o in to_collision_objects(_array(), ["geomodel_1"])] == \
        ["remove"]


def test_example_node_receives_and_converts_over_dds():
    ctx = Context()
    rclpy.init(args=[], context=ctx)
    received: list[list[dict]] = []
    cond = threading.Condition()

    def on_objects(objects):
        with cond:
            received.append(objects)
            cond.notify_all()

    topic = "/planner_example_test/objects"
    example = PlannerExample(topic, on_objects=on_objects, context=ctx)
    publisher_node = Node("planner_example_publisher", context=ctx)
    pub = publisher_node.create_publisher(
        PrimitiveArray, topic, QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE))
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(example)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    box = _primitive(7, Primitive.CUBOID, SolidPrimitive.BOX, (0.1, 0.2, 0.3), (0, 0, 1))
    try:
        deadline = time.monotonic() + TIMEOUT
        while pub.get_subscription_count() == 0:  # discovery (no fixed sleep)
            assert time.monotonic() < deadline, "the example node was not discovered"
            time.sleep(0.01)
        pub.publish(_array(box))
        with cond:
            assert cond.wait_for(lambda: len(received) == 1, TIMEOUT), "nothing received"
        pub.publish(_array())  # the box is gone
        with cond:
            assert cond.wait_for(lambda: len(received) == 2, TIMEOUT), "second not received"
    finally:
        executor.shutdown(timeout_sec=5.0)
        example.destroy_node()
        publisher_node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    assert [(o["id"], o["operation"]) for o in received[0]] == [("geomodel_7", "add")]
    assert [(o["id"], o["operation"]) for o in received[1]] == [("geomodel_7", "remove")]
