"""Unorganized clouds in a robot's frame, modeled from the sensor's pose (tf2's transform).

An unorganized cloud (filtered, cropped, voxelised) carries no pixel grid to recover its
camera from (``test_viewpoint.py``): a rendered clutter frame's returns are moved into a
robot's base frame by that file's rigid transform, and the pose of the camera's optical
frame in the base frame is handed over as tf2 gives it (translation and an (x, y, z, w)
quaternion). Modeled with it, the cloud must give the objects of the camera frame's
cloud, moved; without it, the ranges are taken from the base's origin. The node looks the
pose up for every frame not in ``sensor_frame`` (here from a stand-in for
``tf2_ros.Buffer``), skips frames whose transform is unknown and keeps running.
"""

from __future__ import annotations

import importlib.util
import json
import threading

import numpy as np
import pytest
from geometry_msgs.msg import TransformStamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import PointCloud2

from geomodel_msgs.msg import PrimitiveArray
from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import ModelingParams, ParameterError
from geomodel_ros.core.viewpoint import SensorPose, grid_sensor_pose
from geomodel_ros.ros.node import ModelerNode
from geomodel_ros.tools.synth.clutter import KINECT_NOISE, render_clutter
from msg_adapters.header import make_header
from msg_adapters.pointcloud2 import xyz_to_cloud
from ros_helpers import RELIABLE, TIMEOUT, wait_until
from test_viewpoint import CAMERA_IN_BASE, OPTICAL_IN_BASE, _to_base

SENSOR_FRAME = "camera_optical"


def _quaternion() -> np.ndarray:
    """(x, y, z, w) of OPTICAL_IN_BASE."""
    return Rotation.from_matrix(OPTICAL_IN_BASE).as_quat()


@pytest.fixture(scope="module")
def frame():
    """Return the frame's returns (unorganized, camera frame) and their model."""
    scene = render_clutter(5, KINECT_NOISE)
    pts = scene.organized.reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    return pts, model_scene(pts, ModelingParams())


def test_a_transform_gives_the_pose_the_grid_gives():
    # A quarter turn about z: the sensor's x axis is the cloud's y axis.
    half = np.sqrt(0.5)
    pose = SensorPose.from_transform((1.0, 2.0, 3.0), (0.0, 0.0, half, half))
    np.testing.assert_allclose(pose.to_input(np.array([[1.0, 0.0, 0.0]])), [[1.0, 3.0, 3.0]],
                               atol=1e-12)
    np.testing.assert_allclose(pose.to_sensor(np.array([[1.0, 2.0, 3.0]])), [[0.0, 0.0, 0.0]],
                               atol=1e-12)
    # The same camera as the one the moved organized frame's grid gives (an independent
    # fit); a quaternion of any length stands for its rotation.
    scene = render_clutter(5, KINECT_NOISE)
    moved = _to_base(scene.organized.reshape(-1, 3))
    grid = grid_sensor_pose(moved, scene.organized.shape[:2])
    for scale in (1.0, 3.0, 1e200, 1e-200):
        pose = SensorPose.from_transform(CAMERA_IN_BASE, scale * _quaternion())
        np.testing.assert_allclose(pose.rotation, grid.rotation, atol=1e-9)
        np.testing.assert_allclose(pose.center, grid.center, atol=1e-9)
    assert pose.to_dict()["reprojection_rms_px"] is None


@pytest.mark.parametrize("translation, quaternion", [
    ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0)),
    ((np.nan, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
    ((0.0, 0.0, 0.0), (0.0, np.inf, 0.0, 1.0)),
    ((0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
    ((0.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    ((1e300, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
])
def test_a_transform_that_is_no_pose_is_refused(translation, quaternion):
    with pytest.raises(ValueError):
        SensorPose.from_transform(translation, quaternion)


def test_an_unorganized_cloud_is_modeled_from_its_sensor(frame):
    pts, (labels, own) = frame
    pose = SensorPose.from_transform(CAMERA_IN_BASE, _quaternion())
    moved_labels, moved = model_scene(_to_base(pts), ModelingParams(), sensor=pose)
    assert moved.sensor is pose
    assert np.mean(moved_labels == labels) > 0.999
    assert [(o.id, o.type) for o in moved.objects] == [(o.id, o.type) for o in own.objects]
    for a, b in zip(own.objects, moved.objects):
        np.testing.assert_allclose(_to_base(a.center[None])[0], b.center, atol=1e-3)
        np.testing.assert_allclose(OPTICAL_IN_BASE @ a.rotation, b.rotation, atol=1e-3)
    assert moved.noise.depth == pytest.approx(own.noise.depth, rel=1e-6)
    # Without it the base's origin is taken for the sensor: the ranges the noise is
    # measured at are about 1.3 m instead of 0.6 m, and the objects are others.
    _, as_given = model_scene(_to_base(pts), ModelingParams())
    assert as_given.sensor is None
    assert abs(as_given.noise.depth - own.noise.depth) > 0.3


class _Transforms:
    """A stand-in for ``tf2_ros.Buffer``: known transforms, every lookup recorded."""

    def __init__(self, known: dict[tuple[str, str], tuple]) -> None:
        self.known = known
        self.calls: list[tuple[str, str, int, float]] = []

    def lookup_transform(self, target_frame, source_frame, time, timeout=None):
        self.calls.append((target_frame, source_frame, time.nanoseconds,
                           timeout.nanoseconds * 1e-9))
        if (target_frame, source_frame) not in self.known:
            raise LookupError(f'"{target_frame}" passed to lookupTransform does not exist')
        (tx, ty, tz), (qx, qy, qz, qw) = self.known[(target_frame, source_frame)]
        out = TransformStamped()
        out.header.frame_id, out.child_frame_id = target_frame, source_frame
        t, q = out.transform.translation, out.transform.rotation
        t.x, t.y, t.z = float(tx), float(ty), float(tz)
        q.x, q.y, q.z, q.w = float(qx), float(qy), float(qz), float(qw)
        return out


def test_the_node_models_an_unorganized_cloud_from_its_sensor_frame(context, frame):
    pts, (_, own) = frame
    transforms = _Transforms({("base_link", SENSOR_FRAME): (CAMERA_IN_BASE, _quaternion())})
    node = ModelerNode(context=context, transforms=transforms,
                       cli_args=["--ros-args", "-r", "points:=/test/points"],
                       parameter_overrides=[Parameter("sensor_frame", value=SENSOR_FRAME),
                                            Parameter("qos_reliability", value="reliable")])
    peer = Node("peer", context=context)
    received: list[PrimitiveArray] = []
    peer.create_subscription(PrimitiveArray, "/modeler/objects", received.append, RELIABLE)
    pub = peer.create_publisher(PointCloud2, "/test/points", RELIABLE)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(peer)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        wait_until(lambda: pub.get_subscription_count() >= 1, "the node to subscribe")

        def send(frame_id: str, points: np.ndarray, stamp_ns: int) -> None:
            before = node.stats()
            pub.publish(xyz_to_cloud(points.astype(np.float32), make_header(frame_id,
                                                                             stamp_ns)))
            wait_until(lambda: node.stats().processed + node.stats().failed
                       > before.processed + before.failed, "the frame to be handled")

        send("base_link", _to_base(pts), 7_000_000_123)
        assert transforms.calls == [("base_link", SENSOR_FRAME, 7_000_000_123, 0.2)]
        wait_until(lambda: len(received) == 1, "the objects")
        out = received[0]
        assert out.header.frame_id == "base_link"
        assert sorted(p.type for p in out.primitives) == sorted(
            _type_code(o) for o in own.objects)
        # The desk (the largest object) where the camera frame's desk lies in the base.
        desk = max(out.primitives, key=lambda p: p.point_count)
        own_desk = max(own.objects, key=lambda o: o.point_count)
        position = desk.pose.position
        np.testing.assert_allclose([position.x, position.y, position.z],
                                   _to_base(own_desk.center[None])[0], atol=2e-3)
        # No transform known for this frame: skipped (failed), nothing published.
        send("odom", _to_base(pts), 8_000_000_000)
        assert node.stats().failed == 1 and node.stats().processed == 1
        # A cloud in the sensor's own frame needs no lookup.
        send(SENSOR_FRAME, pts[::4], 9_000_000_000)
        assert len(transforms.calls) == 2
        assert node.stats().processed == 2
        wait_until(lambda: len(received) == 2, "the objects of the third frame")
    finally:
        executor.shutdown(timeout_sec=TIMEOUT)
        spinner.join(TIMEOUT)
        node.destroy_node()
        peer.destroy_node()


def _type_code(prim) -> int:
    """Return the geomodel_msgs/Primitive type constant of a core primitive."""
    from geomodel_msgs.msg import Primitive as PrimitiveMsg

    return getattr(PrimitiveMsg, prim.type.value.upper())


def test_a_sensor_frame_without_tf2_is_a_clear_error(context):
    overrides = [Parameter("sensor_frame", value=SENSOR_FRAME)]
    if importlib.util.find_spec("tf2_ros") is None:
        with pytest.raises(ParameterError, match="tf2_ros"):
            ModelerNode(context=context, parameter_overrides=overrides)
    else:  # a full ROS install: the node makes its own buffer and listener
        node = ModelerNode(context=context, parameter_overrides=overrides)
        assert node._transforms is not None
        node.destroy_node()
    # Without sensor_frame nothing of tf2 is needed.
    node = ModelerNode(context=context)
    assert node._transforms is None
    node.destroy_node()


def test_the_command_line_models_a_moved_cloud_from_its_sensor_pose(frame, tmp_path, capsys):
    from geomodel_ros.core.modeling import model_objects
    from geomodel_ros.tools.cli import main

    pts, (labels, own) = frame
    cloud, out = tmp_path / "moved.npy", tmp_path / "out.json"
    np.save(cloud, _to_base(pts))
    pose = [*CAMERA_IN_BASE, *_quaternion()]
    assert main(["model", str(cloud), "--json", str(out), "--sensor-pose",
                 *map(str, pose)]) == 0
    got = json.loads(out.read_text())
    np.testing.assert_allclose(got["sensor"]["center"], CAMERA_IN_BASE, atol=1e-12)
    assert [o["type"] for o in got["objects"]] == [o.type.value for o in own.objects]
    for a, b in zip(own.objects, got["objects"]):
        np.testing.assert_allclose(b["center"], _to_base(a.center[None])[0], atol=1e-3)
    # With the labels given: the camera frame's objects of those labels, moved.
    np.save(tmp_path / "labels.npy", labels)
    assert main(["model", str(cloud), "--json", str(out), "--labels",
                 str(tmp_path / "labels.npy"), "--sensor-pose", *map(str, pose)]) == 0
    got = json.loads(out.read_text())
    expected = model_objects(pts, labels, ModelingParams())
    assert [o["type"] for o in got["objects"]] == [o.type.value for o in expected.objects]
    for a, b in zip(expected.objects, got["objects"]):
        np.testing.assert_allclose(b["center"], _to_base(a.center[None])[0], atol=1e-3)
    capsys.readouterr()
    # A quaternion of length zero is no rotation: a clear error, nothing written.
    out.unlink()
    assert main(["model", str(cloud), "--json", str(out), "--sensor-pose",
                 "0", "0", "0", "0", "0", "0", "0"]) == 2
    assert "--sensor-pose" in capsys.readouterr().err
    assert not out.exists()


def test_the_bag_tool_models_moved_clouds_from_the_sensor_pose(frame, tmp_path, capsys):
    from rclpy.serialization import deserialize_message

    from test_bags import read_bag, write_bag

    pts, (_, own) = frame
    bag, out = tmp_path / "moved", tmp_path / "out"
    write_bag(bag, {"/points": [xyz_to_cloud(_to_base(pts).astype(np.float32),
                                              make_header("base_link", 5))]})
    pose = [str(v) for v in (*CAMERA_IN_BASE, *_quaternion())]
    # A pose that is none: a clear error before anything is written.
    assert main_cli(["bag", str(bag), str(out), "--sensor-pose", *pose[:3], "0", "0", "0",
                     "0"]) == 2
    assert "--sensor-pose" in capsys.readouterr().err and not out.exists()
    assert main_cli(["bag", str(bag), str(out), "--sensor-pose", *pose]) == 0
    (raw,) = [r for _, r in read_bag(out)["/modeler/objects"]]
    got = deserialize_message(raw, PrimitiveArray)
    assert got.header.frame_id == "base_link"
    assert sorted(p.type for p in got.primitives) == sorted(_type_code(o) for o in own.objects)
    desk = max(got.primitives, key=lambda p: p.point_count)
    own_desk = max(own.objects, key=lambda o: o.point_count)
    position = desk.pose.position
    np.testing.assert_allclose([position.x, position.y, position.z],
                               _to_base(own_desk.center[None])[0], atol=2e-3)


def main_cli(argv: list[str]) -> int:
    """Run the ``geomodel`` command line."""
    from geomodel_ros.tools.cli import main

    return main(argv)
