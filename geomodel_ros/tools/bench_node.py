"""Benchmark of the ``modeler`` node: its own overhead and end-to-end latency.

Run as ``python -m geomodel_ros.tools.bench_node [--scene scene3] [--frames 20]``.

1. **Node overhead** (conversion in, markers and clouds out, publish) per frame: the node
   is given a stand-in for the scene modeling that returns a precomputed result of the real
   :func:`~geomodel_ros.core.modeling.model_scene` for the same scene, so only the node's own
   work is timed (stage times come from :meth:`ModelerNode.stats`).  The publish ->
   MarkerArray-received latency is also given for this case.
2. **End to end** with the real core: publish -> MarkerArray received.

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
from msg_adapters.interfaces import MarkerArray, PointCloud2  # noqa: E402
from msg_adapters.pointcloud2 import cloud_size, xyz_to_cloud  # noqa: E402

from geomodel_ros.core.fastmath import retain_freed_memory  # noqa: E402
from geomodel_ros.core.modeling import model_scene  # noqa: E402
from geomodel_ros.ros.node import ModelerNode  # noqa: E402
from geomodel_ros.ros.processing import SceneModeler  # noqa: E402
from geomodel_ros.core.params import ModelingParams  # noqa: E402
from geomodel_ros.tools.synth import SCENE_NAMES, render_scene  # noqa: E402

_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
_STAGES = (("convert_s", "convert in (PointCloud2 -> numpy)"),
           ("model_s", "core (model_scene)"),
           ("markers_s", "tracking + markers out"),
           ("objects_s", "typed objects out (~/objects)"),
           ("segments_s", "segments cloud out"),
           ("reconstruction_s", "reconstruction + cloud out"),
           ("publish_s", "publish"),
           ("total_s", "node total"))


class _Peer:
    """Publishes clouds and records when each output arrives."""

    def __init__(self, context: Context) -> None:
        self.node = Node("bench_peer", context=context)
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

    def publish_and_wait(self, msg: PointCloud2, timeout: float = 60.0) -> float:
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


def _run(cloud: PointCloud2, frames: int, core: SceneModeler, tracking: bool = True
         ) -> tuple[list[float], list[dict[str, float]]]:
    """Latencies [s] and node stage timings of ``frames`` frames through a fresh node."""
    domain = int(os.environ.get("ROS_DOMAIN_ID", 1 + os.getpid() % 100))
    context = Context()
    rclpy.init(args=[], context=context, domain_id=domain)
    node = ModelerNode(context=context, model_scene=core,
                       cli_args=["--ros-args", "-r", "points:=/bench/points"],
                       parameter_overrides=[Parameter("qos_reliability", value="reliable"),
                                            Parameter("diagnostics", value=False),
                                            Parameter("tracking", value=tracking)])
    peer = _Peer(context)
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
        peer.publish_and_wait(cloud)  # warm-up (imports, first allocations)
        latencies, timings = [], []
        for i in range(frames):
            latencies.append(peer.publish_and_wait(cloud))
            _wait(lambda: node.stats().processed >= i + 2, "the node's statistics")
            timings.append(node.stats().last_timing)
        return latencies, timings
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
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--tracking", choices=("on", "off"), default="on",
                        help="the node's tracking parameter (stable ids, per-id markers)")
    args = parser.parse_args(argv)
    if args.frames < 1:
        parser.error("--frames must be >= 1")
    retain_freed_memory()  # as the node's main does

    scene = render_scene(args.scene)
    cloud = xyz_to_cloud(scene.organized, make_header("camera_optical", 1 * NS_PER_S))
    h, w = scene.organized.shape[:2]
    rows = scene.organized.reshape(-1, 3).astype(np.float32).astype(np.float64)
    labels, result = model_scene(rows, ModelingParams(), organized_shape=(h, w))

    def precomputed(_points, _params, **_organized_shape):
        return labels, result

    print(f"scene {args.scene}: {h} x {w} organized cloud, {len(scene.points)} valid points, "
          f"{len(result.objects)} objects; {args.frames} frames; "
          f"{cloud_size(cloud).nbytes / 1e6:.1f} MB per input message")
    tracking = args.tracking == "on"
    lat_null, tim_null = _run(cloud, args.frames, precomputed, tracking)
    lat_real, tim_real = _run(cloud, args.frames, model_scene, tracking)

    print(f"\n  {'node overhead (core = precomputed result)':<44s} {'median ms':>9s} "
          f"{'p95 ms':>9s}")
    for key, name in _STAGES:
        if key != "model_s":
            print(_row(name, [t[key] for t in tim_null]))
    print(_row("publish -> MarkerArray received", lat_null))
    print(f"\n  {'end to end (real core)':<44s} {'median ms':>9s} {'p95 ms':>9s}")
    print(_row("core (model_scene)", [t["model_s"] for t in tim_real]))
    print(_row("node total (incl. core)", [t["total_s"] for t in tim_real]))
    print(_row("publish -> MarkerArray received", lat_real))
    return 0


if __name__ == "__main__":
    sys.exit(main())
