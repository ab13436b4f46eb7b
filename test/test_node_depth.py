"""The ``modeler`` node with depth-image input and with the adaptive input QoS.

Real rclpy pub/sub in one process (a private Context per test), like test_node.py: a peer
node publishes depth images and CameraInfo as a depth driver does; the reference is the
same rendered scene as an organized PointCloud2 through :func:`process_cloud`, which is
what the node does with ``input: points`` (tested in test_node.py).
"""

from __future__ import annotations

import threading

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import Header

from geomodel_msgs.msg import PrimitiveArray

from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.ros.node import ModelerNode
from geomodel_ros.ros.processing import process_cloud
from geomodel_ros.tools.synth import render_scene
from msg_adapters.depth_image import CameraModel, camera_info, depth_image
from msg_adapters.pointcloud2 import xyz_to_cloud
from ros_helpers import FRAME, RELIABLE, TIMEOUT, wait_until
from test_node import Collector, CoreProbe

SCENE = "scene2"  # standing and lying cylinder, two spheres, cone, desk: 1104 x 624
BEST_EFFORT = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)


class DepthHarness:
    """The node with ``input: depth`` + a peer publishing images and CameraInfo."""

    def __init__(self, context, core, **overrides) -> None:
        values = {"input": "depth", "qos_reliability": "reliable", "qos_depth": 5,
                  **overrides}
        self.node = ModelerNode(
            context=context, model_scene=core,
            cli_args=["--ros-args", "-r", "depth/image_raw:=/cam/depth/image_rect_raw",
                      "-r", "depth/camera_info:=/cam/depth/camera_info"],
            parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])
        self.peer = Node("driver", context=context)
        self.images = self.peer.create_publisher(Image, "/cam/depth/image_rect_raw", RELIABLE)
        self.infos = self.peer.create_publisher(CameraInfo, "/cam/depth/camera_info", RELIABLE)
        self.objects = Collector(self.peer, PrimitiveArray, "/modeler/objects")
        self.executor = SingleThreadedExecutor(context=context)
        for n in (self.node, self.peer):
            self.executor.add_node(n)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()
        wait_until(lambda: self.images.get_subscription_count() >= 1
                   and self.infos.get_subscription_count() >= 1
                   and self.objects.sub.get_publisher_count() >= 1, "pub/sub to match")

    def send_info(self, info: CameraInfo) -> None:
        self.infos.publish(info)
        wait_until(lambda: self.node._camera_info is not None, "the CameraInfo to arrive")

    def send_image(self, image: Image) -> None:
        before = self.node.stats().received
        self.images.publish(image)
        wait_until(lambda: self.node.stats().received > before, "the image to arrive")

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=10.0)
        self.thread.join(10.0)
        self.node.destroy_node()
        self.peer.destroy_node()


@pytest.fixture
def harness(context):
    made = []

    def make(core=None, **overrides):
        made.append(DepthHarness(context, core or CoreProbe(model_scene), **overrides))
        return made[-1]

    yield make
    for h in made:
        h.close()


def _header(sec: int) -> Header:
    return Header(stamp=Time(sec=sec, nanosec=17), frame_id=FRAME)


@pytest.fixture(scope="module")
def scene():
    rendered = render_scene(SCENE)
    reference = process_cloud(xyz_to_cloud(rendered.organized, _header(1)), ModelingParams())
    return rendered, reference.result.objects


def _objects(msg: PrimitiveArray) -> list[tuple[int, np.ndarray, dict[str, float]]]:
    """(type, centre [m], dimensions by name [m]) of each published object."""
    return [(int(p.type), np.array([p.pose.position.x, p.pose.position.y, p.pose.position.z]),
             dict(zip(p.dimension_names, p.dimensions))) for p in msg.primitives]


@pytest.mark.parametrize("encoding, tol", [
    # float32 metres: the same float32 depth as the cloud's z; x and y are recomputed from
    # it in float64 (the cloud's are float32), so points agree to float32 rounding.
    ("32FC1", 1e-5),
    # whole millimetres: every point moves by <= 0.5 mm along its ray (0.58 mm at the
    # image border, |u - cx| / fx <= 0.6); centres and sizes are fits over thousands of
    # points and move less (0.2 mm measured), but one pixel's segment membership may
    # change at an edge: 1 mm is the quantisation step.
    ("16UC1", 1e-3),
])
def test_depth_image_gives_the_objects_of_the_same_scene_as_a_cloud(harness, scene, encoding,
                                                                      tol):
    rendered, reference = scene
    core = CoreProbe(model_scene)
    h = harness(core)
    h.send_info(camera_info(CameraModel(**rendered.intrinsics), _header(0)))
    h.send_image(depth_image(rendered.organized[..., 2], _header(1700000000), encoding=encoding))
    msg = h.objects.wait()

    assert msg.header.frame_id == FRAME  # the image's header, not the CameraInfo's
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1700000000, 17)
    assert core.calls[-1]["organized_shape"] == (624, 1104)
    assert core.calls[-1]["n"] == 624 * 1104
    got = _objects(msg)
    assert len(got) == len(reference) == 6
    # the scene's ground truth: desk plane, 2 cylinders, cone, 2 spheres
    assert sorted(t for t, *_ in got) == [0, 2, 2, 3, 4, 4]
    for p in reference:
        centre = np.asarray(p.center)
        _, at, dimensions = min(got, key=lambda r: np.linalg.norm(r[1] - centre))
        assert np.linalg.norm(at - centre) <= tol, p.type
        assert dimensions.keys() == p.dimensions.keys()
        for name, value in p.dimensions.items():
            assert dimensions[name] == pytest.approx(value, abs=tol), (p.type, name)
    # The objects go out before the frame's clouds: processed counts the whole frame.
    wait_until(lambda: h.node.stats().processed == 1, "the frame to be processed")
    stats = h.node.stats()
    assert (stats.received, stats.processed, stats.failed) == (1, 1, 0)


def _tiny_image(sec: int, *, encoding: str = "16UC1", shape=(120, 160)) -> Image:
    depth = np.full(shape, 0.8)
    return depth_image(depth, _header(sec), encoding=encoding)


TINY = CameraModel(fx=150.0, fy=150.0, cx=79.5, cy=59.5, width=160, height=120)


def test_frames_without_camera_info_or_of_the_wrong_size_or_encoding_are_dropped(harness,
                                                                                   capfd):
    core = CoreProbe(model_scene)
    h = harness(core)
    h.send_image(_tiny_image(1))  # no CameraInfo yet
    wait_until(lambda: h.node.stats().failed == 1, "the first image to be dropped")
    h.send_info(camera_info(TINY, _header(0)))
    h.send_image(_tiny_image(2, shape=(240, 320)))  # CameraInfo is 160 x 120
    wait_until(lambda: h.node.stats().failed == 2, "the mismatched image to be dropped")
    bad = _tiny_image(3)
    bad.encoding = "rgb8"
    h.send_image(bad)
    wait_until(lambda: h.node.stats().failed == 3, "the rgb8 image to be dropped")
    assert core.calls == []  # nothing malformed reached the core
    h.send_image(_tiny_image(4, encoding="32FC1"))  # a good frame is modeled
    msg = h.objects.wait()
    assert msg.header.stamp.sec == 4
    assert core.calls[-1]["organized_shape"] == (120, 160)
    wait_until(lambda: h.node.stats().processed == 1, "the good frame to be processed")
    stats = h.node.stats()
    assert (stats.received, stats.processed, stats.failed) == (4, 1, 3)
    err = capfd.readouterr().err
    assert "no CameraInfo received yet on '/cam/depth/camera_info'" in err
    assert "depth image is 320 x 240 but its CameraInfo is 160 x 120" in err
    # the rgb8 image's warning comes from the same place within WARN_THROTTLE_S: throttled
    assert err.count("skipping malformed depth image") == 1


def test_auto_reliability_follows_the_publishers(context):
    """Best effort without publishers; reliable when all are; best effort with a mixed set."""
    node = ModelerNode(context=context, model_scene=CoreProbe(model_scene),
                       cli_args=["--ros-args", "-r", "points:=/auto/points"])
    peer = Node("camera", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        assert node.options.qos_reliability == "auto"
        assert node.input_reliability == {"/auto/points": "best_effort"}
        reliable = peer.create_publisher(PointCloud2, "/auto/points", RELIABLE)
        wait_until(lambda: node.input_reliability["/auto/points"] == "reliable",
                   "the subscription to become reliable")
        # a reliable subscription matches the reliable publisher: a frame gets through
        wait_until(lambda: reliable.get_subscription_count() == 1, "reliable match")
        reliable.publish(xyz_to_cloud(np.full((4, 5, 3), np.nan), _header(5)))
        wait_until(lambda: node.stats().received == 1, "a frame over the reliable match")
        # a best-effort publisher would not match a reliable subscription: back to best effort
        sensor = peer.create_publisher(PointCloud2, "/auto/points", BEST_EFFORT)
        wait_until(lambda: node.input_reliability["/auto/points"] == "best_effort",
                   "the subscription to fall back to best effort")
        wait_until(lambda: sensor.get_subscription_count() == 1, "best-effort match")
        sensor.publish(xyz_to_cloud(np.full((4, 5, 3), np.nan), _header(6)))
        wait_until(lambda: node.stats().received == 2, "a frame from the best-effort publisher")
    finally:
        executor.shutdown(timeout_sec=TIMEOUT)
        thread.join(TIMEOUT)
        node.destroy_node()
        peer.destroy_node()


def test_fixed_reliability_does_not_follow_the_publishers(context):
    node = ModelerNode(context=context, model_scene=CoreProbe(model_scene),
                       cli_args=["--ros-args", "-r", "points:=/fixed/points"],
                       parameter_overrides=[Parameter("qos_reliability", value="best_effort")])
    peer = Node("camera", context=context)
    try:
        peer.create_publisher(PointCloud2, "/fixed/points", RELIABLE)
        wait_until(lambda: len(node.get_publishers_info_by_topic("/fixed/points")) == 1,
                   "the publisher to be discovered")
        node._update_inputs()  # what the auto mode's timer would do
        assert node.input_reliability == {"/fixed/points": "best_effort"}
        assert node._input_qos_timer is None
    finally:
        node.destroy_node()
        peer.destroy_node()
