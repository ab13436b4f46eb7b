"""Benchmark of the ``modeler`` node: its own overhead and end-to-end latency.

Run as ``python -m geomodel_ros.tools.bench_node [--scene scene3 | --osd 20] [--frames 20]
[--input points depth] [--set NAME=VALUE ...]``; ``--osd N`` takes the real Kinect frame
``osd_learn/learnN`` (640 x 480; its depth image through the database's pinhole intrinsics,
which reproduce its cloud) instead of a rendered scene; ``--set`` gives the node a modeling
parameter (``--set decimation=2``).

1. **Node overhead** (conversion in, markers and clouds out, publish) per frame: the node
   is given a stand-in for the scene modeling that returns a precomputed result of the real
   :func:`~geomodel_ros.core.modeling.model_scene` for the same scene, so only the node's own
   work is timed (stage times come from :meth:`ModelerNode.stats`).  The publish ->
   MarkerArray-received latency is also given for this case.
2. **End to end** with the real core: publish -> MarkerArray received, and the node's
   own latency (input callback -> outputs published, ``FrameStats.last_latency_s``).

Both are measured per input (``--input``): the scene as an organized PointCloud2
(``input: points``) and as a 16UC1 depth image with its CameraInfo (``input: depth``;
the core then sees the millimetre-quantised cloud).

The node and a peer node (publisher + subscribers of all three outputs, like RViz) run in
one process, each on its own executor thread, over Fast DDS on loopback.  Each frame is
published after the previous one's markers arrived, so no frame is dropped.

DDS discovery is kept on loopback (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) and a
private domain is used unless ``ROS_DOMAIN_ID`` is set.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # before rclpy starts DDS

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from msg_adapters.header import NS_PER_S, make_header  # noqa: E402
from msg_adapters.depth_image import CameraModel, camera_info, depth_image  # noqa: E402
from msg_adapters.depth_image import depth_to_scene  # noqa: E402
from msg_adapters.interfaces import CameraInfo, Image, MarkerArray, PointCloud2  # noqa: E402
from msg_adapters.pointcloud2 import cloud_size, cloud_to_scene, xyz_to_cloud  # noqa: E402

from geomodel_ros.core.fastmath import retain_freed_memory  # noqa: E402
from geomodel_ros.core.modeling import model_scene  # noqa: E402
from geomodel_ros.ros.node import ModelerNode  # noqa: E402
from geomodel_ros.ros.processing import SceneModeler  # noqa: E402
from geomodel_ros.core.params import ModelingParams  # noqa: E402
from geomodel_ros.tools.cli import parameter_overrides  # noqa: E402
from geomodel_ros.tools.io import load_osd  # noqa: E402
from geomodel_ros.tools.paths import data_dir  # noqa: E402
from geomodel_ros.tools.synth import SCENE_NAMES, render_scene  # noqa: E402

#: Intrinsics [px] of the osd_learn frames: x / z and y / z of every pixel follow this
#: pinhole model to 2e-7 (least squares over learn20), so its depth image gives the cloud.
OSD_CAMERA = CameraModel(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480)
_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
_STAGES = (("convert_s", "convert in (message -> numpy)"),
           ("model_s", "core (model_scene)"),
           ("markers_s", "tracking + markers out"),
           ("objects_s", "typed objects out (~/objects)"),
           ("first_out_s", "publish objects + markers (before the clouds)"),
           ("segments_s", "segments cloud out"),
           ("reconstruction_s", "reconstruction + cloud out"),
           ("publish_s", "publish the clouds"),
           ("total_s", "node total"))


class _Peer:
    """Publishes clouds and records when each output arrives."""

    def __init__(self, context: Context, input_kind: str) -> None:
        self.node = Node("bench_peer", context=context)
        if input_kind == "depth":
            self.pub = self.node.create_publisher(Image, "/bench/image", _QOS)
            self.info_pub = self.node.create_publisher(CameraInfo, "/bench/camera_info", _QOS)
        else:
            self.pub = self.node.create_publisher(PointCloud2, "/bench/points", _QOS)
        self._cond = threading.Condition()
        self.marker_times: list[float] = []
        self.node.create_subscription(MarkerArray, "/modeler/primitives", self._on_markers, _QOS)
        # Subscribed like RViz would, so that the node really sends them.
        self.node.create_subscription(PointCloud2, "/modeler/segments", lambda _: None, _QOS)
        self.node.create_subscription(PointCloud2, "/modeler/reconstruction", lambda _: None,
                                      _QOS)

    def _on_markers(self, _: MarkerArray) -> None:
        with self._cond:
            self.marker_times.append(time.perf_counter())
            self._cond.notify_all()

    def publish_and_wait(self, msg: PointCloud2 | Image, timeout: float = 60.0) -> float:
        """Publish ``msg``; seconds until the next MarkerArray arrives."""
        with self._cond:
            n = len(self.marker_times)
        t0 = time.perf_counter()
        self.pub.publish(msg)
        with self._cond:
            if not self._cond.wait_for(lambda: len(self.marker_times) > n, timeout):
                raise RuntimeError(f"no MarkerArray within {timeout} s")
            return self.marker_times[n] - t0


def _wait(predicate, what: str, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out waiting for {what}")
        time.sleep(0.002)


def _run(msg: PointCloud2 | Image, info: CameraInfo | None, frames: int, core: SceneModeler,
         tracking: bool = True, overrides: dict[str, object] | None = None
         ) -> tuple[list[float], list[float], list[dict[str, float]]]:
    """Latencies [s] (publish -> markers; node callback -> published) and stage timings.

    ``frames`` frames of ``msg`` through a fresh node (``input: depth`` when ``info`` is
    given, after it was delivered) whose modeling parameters ``overrides`` sets.
    """
    domain = int(os.environ.get("ROS_DOMAIN_ID", 1 + os.getpid() % 100))
    context = Context()
    rclpy.init(args=[], context=context, domain_id=domain)
    node = ModelerNode(context=context, model_scene=core,
                       cli_args=["--ros-args", "-r", "points:=/bench/points",
                                 "-r", "depth/image_raw:=/bench/image",
                                 "-r", "depth/camera_info:=/bench/camera_info"],
                       parameter_overrides=[Parameter("qos_reliability", value="reliable"),
                                            Parameter("diagnostics", value=False),
                                            Parameter("tracking", value=tracking),
                                            Parameter("input", value="points" if info is None
                                                      else "depth"),
                                            *(Parameter(k, value=v)
                                              for k, v in (overrides or {}).items())])
    peer = _Peer(context, "points" if info is None else "depth")
    executors, threads = [], []
    for n in (node, peer.node):
        ex = SingleThreadedExecutor(context=context)
        ex.add_node(n)
        t = threading.Thread(target=ex.spin, daemon=True)
        t.start()
        executors.append(ex)
        threads.append(t)
    try:
        _wait(lambda: peer.pub.get_subscription_count() >= 1
              and peer.node.count_publishers("/modeler/primitives") >= 1, "discovery")
        if info is not None:
            peer.info_pub.publish(info)
            _wait(lambda: node._camera_info is not None, "the CameraInfo")
        peer.publish_and_wait(msg)  # warm-up (imports, first allocations)
        latencies, node_latencies, timings = [], [], []
        for i in range(frames):
            latencies.append(peer.publish_and_wait(msg))
            _wait(lambda: node.stats().processed >= i + 2, "the node's statistics")
            stats = node.stats()
            node_latencies.append(stats.last_latency_s)
            timings.append(stats.last_timing)
        return latencies, node_latencies, timings
    finally:
        for ex in executors:
            ex.shutdown(timeout_sec=5.0)
        for t in threads:  # spin loops must be done before their nodes go away
            t.join(timeout=5.0)
        node.destroy_node()
        peer.node.destroy_node()
        rclpy.try_shutdown(context=context)


def _row(name: str, values_s: list[float]) -> str:
    ms = 1000.0 * np.asarray(values_s)
    return f"  {name:<44s} {np.median(ms):9.1f} {np.percentile(ms, 95):9.1f}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m geomodel_ros.tools.bench_node",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="scene3", choices=SCENE_NAMES)
    parser.add_argument("--osd", type=int, default=None, metavar="N",
                        help="use the real Kinect frame osd_learn/learnN instead of --scene")
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--tracking", choices=("on", "off"), default="on",
                        help="the node's tracking parameter (stable ids, per-id markers)")
    parser.add_argument("--input", nargs="+", choices=("points", "depth"),
                        default=["points", "depth"],
                        help="inputs to measure (PointCloud2, 16UC1 depth image + CameraInfo)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="modeling parameter of the node (default: every one at its "
                             "default), e.g. --set decimation=2")
    args = parser.parse_args(argv)
    overrides = parameter_overrides(args.set)
    ModelingParams.from_mapping(overrides)  # a wrong name or value stops here, not in the node
    if args.frames < 1:
        parser.error("--frames must be >= 1")
    retain_freed_memory()  # as the node's main does

    name, organized, camera = _scene(args.scene, args.osd)
    header = make_header("camera_optical", 1 * NS_PER_S)
    inputs = {"points": (xyz_to_cloud(organized, header), None),
              "depth": (depth_image(organized[..., 2], header, encoding="16UC1"),
                        camera_info(camera, header))}
    h, w = organized.shape[:2]
    valid = int(np.count_nonzero(np.isfinite(organized).all(axis=2)))
    print(f"scene {name}: {h} x {w} organized, {valid} valid points; "
          f"{args.frames} frames; input messages: PointCloud2 "
          f"{cloud_size(inputs['points'][0]).nbytes / 1e6:.1f} MB, 16UC1 depth image "
          f"{len(inputs['depth'][0].data) / 1e6:.2f} MB")
    tracking = args.tracking == "on"
    for kind in args.input:
        msg, info = inputs[kind]
        _report(kind, msg, info, args.frames, tracking, overrides)
    return 0


def _scene(scene: str, osd: int | None) -> tuple[str, np.ndarray, CameraModel]:
    """Name, (H, W, 3) organized points [m] and camera of the frame to send."""
    if osd is None:
        rendered = render_scene(scene)
        return scene, rendered.organized, CameraModel(**rendered.intrinsics)
    points, _ = load_osd(data_dir() / "osd_learn" / f"learn{osd}.pcd")
    return f"osd_learn/learn{osd}", points.reshape(OSD_CAMERA.height, OSD_CAMERA.width, 3), \
        OSD_CAMERA


def _precomputed(msg: PointCloud2 | Image, info: CameraInfo | None,
                 overrides: dict[str, object]) -> SceneModeler:
    """Stand-in core returning the real core's result for the scene as the node reads it."""
    rows = cloud_to_scene(msg).points if info is None else depth_to_scene(msg, info).points
    labels, result = model_scene(rows, ModelingParams.from_mapping(overrides),
                                 organized_shape=(int(msg.height), int(msg.width)))

    def precomputed(_points, _params, **_organized_shape):
        return labels, result

    return precomputed


def _report(kind: str, msg: PointCloud2 | Image, info: CameraInfo | None, frames: int,
            tracking: bool, overrides: dict[str, object]) -> None:
    """Measure and print both tables for one input."""
    lat_null, node_null, tim_null = _run(msg, info, frames, _precomputed(msg, info, overrides),
                                         tracking, overrides)
    lat_real, node_real, tim_real = _run(msg, info, frames, model_scene, tracking, overrides)
    print(f"\n  input: {kind}")
    print(f"  {'node overhead (core = precomputed result)':<44s} {'median ms':>9s} "
          f"{'p95 ms':>9s}")
    for key, name in _STAGES:
        if key != "model_s":
            print(_row(name, [t[key] for t in tim_null]))
    print(_row("node callback -> outputs published", node_null))
    print(_row("publish -> MarkerArray received", lat_null))
    print(f"  {'end to end (real core)':<44s} {'median ms':>9s} {'p95 ms':>9s}")
    print(_row("core (model_scene)", [t["model_s"] for t in tim_real]))
    print(_row("node total (incl. core)", [t["total_s"] for t in tim_real]))
    print(_row("node callback -> outputs published", node_real))
    print(_row("publish -> MarkerArray received", lat_real))


if __name__ == "__main__":
    sys.exit(main())
