"""``~/objects`` on the wire: a subscriber in another process gets the scene's typed objects.

The node runs in this process (private Context); a separate Python process subscribes to
``/modeler/objects`` with the generated ``geomodel_msgs`` types and prints the first message
as JSON.  The objects are checked against the rendered scene's ground truth, read through
MoveIt's SolidPrimitive conventions (BOX [x, y, z], CYLINDER / CONE [height, radius],
SPHERE [radius]).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2

from geomodel_ros.ros.node import ModelerNode
from geomodel_ros.tools.synth import render_scene
from ros_helpers import FRAME, RELIABLE, TIMEOUT, scene_cloud, wait_until

REPO = Path(__file__).resolve().parents[1]

#: The subscriber process: prints the first PrimitiveArray as one JSON line, then exits.
SUBSCRIBER = r"""
import json, sys, time
import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from geomodel_msgs.msg import PrimitiveArray

rclpy.init()
node = Node("objects_listener")
got = []

def on_msg(msg):
    got.append({
        "frame_id": msg.header.frame_id,
        "stamp": [msg.header.stamp.sec, msg.header.stamp.nanosec],
        "objects": [{
            "id": p.id, "type": p.type, "shape_type": p.shape.type,
            "shape": list(p.shape.dimensions),
            "position": [p.pose.position.x, p.pose.position.y, p.pose.position.z],
            "orientation": [p.pose.orientation.x, p.pose.orientation.y,
                            p.pose.orientation.z, p.pose.orientation.w],
            "dimensions": dict(zip(p.dimension_names, p.dimensions)),
        } for p in msg.primitives],
        "supports": [{"id": s.id, "plane": list(s.plane.coef)} for s in msg.support_surfaces]})

node.create_subscription(PrimitiveArray, "/modeler/objects", on_msg,
                         QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
deadline = time.monotonic() + float(sys.argv[1])
while not got and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.1)
print(json.dumps(got[0]) if got else "NONE", flush=True)
node.destroy_node()
rclpy.shutdown()
"""

#: SolidPrimitive type constants (shape_msgs): BOX, SPHERE, CYLINDER, CONE.
BOX, SPHERE, CYLINDER, CONE = 1, 2, 3, 4
#: Primitive.msg type constants.
TYPES = {"plane": 0, "cuboid": 1, "cylinder": 2, "cone": 3, "sphere": 4, "frustum": 5}


def _moveit_size_mm(obj: dict) -> dict[str, float]:
    """Return the object's size [mm] from its SolidPrimitive alone (MoveIt's conventions)."""
    d = 1000.0 * np.array(obj["shape"])
    if obj["shape_type"] == BOX and obj["type"] == TYPES["plane"]:
        assert d[2] == 0.0
        return {"length": d[0], "width": d[1]}
    if obj["shape_type"] == BOX:
        return {"length": d[0], "width": d[1], "height": d[2]}
    if obj["shape_type"] in (CYLINDER, CONE):
        return {"height": d[0], "radius": d[1]}
    assert obj["shape_type"] == SPHERE
    return {"radius": d[0]}


@pytest.fixture
def node_and_peer(context):
    node = ModelerNode(context=context, cli_args=["--ros-args", "-r", "points:=/test/points"],
                       parameter_overrides=[Parameter("qos_reliability", value="reliable")])
    peer = Node("peer", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(peer)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    yield node, peer
    executor.shutdown(timeout_sec=10.0)
    thread.join(10.0)
    node.destroy_node()
    peer.destroy_node()


def test_objects_reach_another_process_with_the_scenes_types_and_sizes(node_and_peer):
    node, peer = node_and_peer
    pub = peer.create_publisher(PointCloud2, "/test/points", RELIABLE)
    listener = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, str(3 * TIMEOUT)],
                                cwd=REPO, env=dict(os.environ), stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
    try:
        wait_until(lambda: node._pub_objects.get_subscription_count() >= 1
                   and pub.get_subscription_count() >= 1, "the listener process to match")
        pub.publish(scene_cloud("scene3", sec=1700000000, nanosec=123456789))
        out, err = listener.communicate(timeout=4 * TIMEOUT)
    finally:
        if listener.poll() is None:
            listener.kill()
            listener.wait()
    line = out.strip().splitlines()[-1] if out.strip() else ""
    assert line and line != "NONE", f"no objects received by the listener:\n{err}"
    got = json.loads(line)
    assert got["frame_id"] == FRAME and got["stamp"] == [1700000000, 123456789]
    assert len({o["id"] for o in got["objects"]}) == len(got["objects"])  # unique ids

    for gt in render_scene("scene3").objects:
        near = [o for o in got["objects"] if o["type"] == TYPES[gt.type]
                and np.linalg.norm(np.array(o["position"]) - gt.center) < 0.01]
        assert len(near) == 1, f"no {gt.type} near {gt.center}"
        (obj,) = near
        assert np.linalg.norm(obj["orientation"]) == pytest.approx(1.0, abs=1e-9)
        assert obj["orientation"][3] >= 0.0
        got_mm = _moveit_size_mm(obj)
        want = {k: 1000.0 * v for k, v in gt.dimensions.items()}
        tol = 10.0 if gt.type == "plane" else 4.0  # as for the markers (test_node)
        if gt.type == "cuboid":  # the modeler may name the box's axes differently
            assert sorted(got_mm.values()) == pytest.approx(sorted(want.values()), abs=tol)
        else:
            assert got_mm == pytest.approx(want, abs=tol), gt.type
        # the full dimensions agree with the shape
        assert {k: 1000.0 * v for k, v in obj["dimensions"].items()} == pytest.approx(
            got_mm, abs=1e-9)

    # the desk is the support surface: a PLANE of the message, its equation facing the sensor
    (desk,) = [gt for gt in render_scene("scene3").objects if gt.type == "plane"]
    (support,) = got["supports"]
    (plane,) = [o for o in got["objects"] if o["id"] == support["id"]]
    assert plane["type"] == TYPES["plane"]
    a, b, c, d = support["plane"]
    assert abs(np.dot([a, b, c], desk.rotation[:, 2])) == pytest.approx(1.0, abs=0.01)
    assert d > 0  # the sensor (origin) is on the normal's side
    assert np.dot([a, b, c], desk.center) + d == pytest.approx(0.0, abs=0.005)


# --- frustums -------------------------------------------------------------------------------

#: A cup standing on its smaller end: base (rim) radius 45 mm, bottom 30 mm, 90 mm tall; z
#: from the base towards the top (down).
CUP_DIMS = {"radius": 0.045, "top_radius": 0.03, "height": 0.09}


def test_a_frustum_travels_as_its_enclosing_cylinder_with_its_full_dimensions():
    from geomodel_ros.core.primitives import Primitive
    from msg_adapters.objects import PrimitiveMsg, objects_to_primitives, primitives_to_objects
    from std_msgs.msg import Header

    down = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # 180 deg about x
    cup = Primitive(4, "frustum", np.array([0.1, -0.05, 0.7]), down, dict(CUP_DIMS), 2500,
                    0.001, reason="frustum verified")
    msg = primitives_to_objects([cup], Header(frame_id=FRAME))
    (m,) = msg.primitives
    assert m.type == PrimitiveMsg.FRUSTUM == 5
    # MoveIt: CYLINDER [height, radius] with the base's (larger) radius encloses the cup.
    assert m.shape.type == CYLINDER and list(m.shape.dimensions) == [0.09, 0.045]
    assert dict(zip(m.dimension_names, m.dimensions)) == CUP_DIMS
    assert list(m.dimension_names) == ["radius", "top_radius", "height"]
    # 180 deg about x: quaternion (1, 0, 0, 0)
    q = m.pose.orientation
    assert (q.x, q.y, q.z, q.w) == pytest.approx((1.0, 0.0, 0.0, 0.0), abs=1e-12)
    (back,) = objects_to_primitives(msg)
    assert back.type == "frustum" and back.dimensions == CUP_DIMS
    np.testing.assert_allclose(back.center, cup.center, atol=1e-12)
    np.testing.assert_allclose(back.rotation, down, atol=1e-12)


def test_a_rendered_cup_reaches_another_process_as_a_frustum(node_and_peer):
    from dataclasses import replace

    from builtin_interfaces.msg import Time
    from std_msgs.msg import Header

    from geomodel_ros.tools.synth import (DESK_CENTER, DESK_NORMAL, PAPER_CAMERA, Frustum,
                                          Rectangle, desk_frame)
    from msg_adapters.pointcloud2 import xyz_to_cloud

    frame = desk_frame()
    down = frame @ np.diag([1.0, -1.0, -1.0])  # z into the desk: the rim is the base
    cup = Frustum(**CUP_DIMS, base_cap=False, center=DESK_CENTER, rotation=down)
    lowest = -cup.support(-DESK_NORMAL) - DESK_CENTER @ DESK_NORMAL
    cup = replace(cup, center=cup.center - lowest * DESK_NORMAL)
    organized, _ = PAPER_CAMERA.scaled(0.5).render(
        [Rectangle(0.4, 0.4, center=DESK_CENTER, rotation=frame), cup])
    cloud = xyz_to_cloud(organized, Header(stamp=Time(sec=7, nanosec=0), frame_id=FRAME))

    node, peer = node_and_peer
    pub = peer.create_publisher(PointCloud2, "/test/points", RELIABLE)
    listener = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, str(3 * TIMEOUT)],
                                cwd=REPO, env=dict(os.environ), stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
    try:
        wait_until(lambda: node._pub_objects.get_subscription_count() >= 1
                   and pub.get_subscription_count() >= 1, "the listener process to match")
        pub.publish(cloud)
        out, err = listener.communicate(timeout=4 * TIMEOUT)
    finally:
        if listener.poll() is None:
            listener.kill()
            listener.wait()
    line = out.strip().splitlines()[-1] if out.strip() else ""
    assert line and line != "NONE", f"no objects received by the listener:\n{err}"
    got = json.loads(line)
    (obj,) = [o for o in got["objects"] if o["type"] == 5]  # FRUSTUM
    assert obj["shape_type"] == CYLINDER
    assert obj["shape"] == pytest.approx([0.09, 0.045], abs=0.3e-3)
    assert obj["dimensions"] == pytest.approx(CUP_DIMS, abs=0.3e-3)
    assert np.linalg.norm(np.array(obj["position"]) - cup.center) < 0.3e-3
