"""Delivery between processes: how many of the frames a driver sends reach the node.

Run as ``python -m geomodel_ros.tools.bench_delivery [--frames 20] [--rate 5]``.

Every set-up starts two fresh processes: the ``modeler`` node (its real input
subscription, with a stand-in core that returns no objects so that only delivery is
measured) and a "driver" that publishes ``--frames`` copies of one message at ``--rate``
Hz, once its publisher matched the node's subscription (and the node had time to adapt its
reliability: ``auto`` re-checks every 0.5 s).  The node counts the frames its
subscription delivered; the table prints delivered/sent per set-up:

* message: organized x/y/z PointCloud2 (12 bytes per pixel) or 16UC1 depth image (2 bytes
  per pixel, + CameraInfo), at 640 x 480 and 1280 x 720;
* the driver's publisher: reliable or best effort (keep last 10);
* the node's ``qos_reliability``: ``best_effort`` (the default before ``auto``) or
  ``auto`` (the default: follows the publisher);
* middleware: Fast DDS defaults; the large-data profile
  (``FASTRTPS_DEFAULT_PROFILES_FILE=config/fastdds_large_data.xml``) in both processes
  (``large_data``); or in the node's process only (``node_only``: the launch file's
  ``use_large_data_profile:=true`` with a driver started elsewhere with defaults).

Every process runs with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and the caller's
``ROS_DOMAIN_ID`` (or a private one); set-ups run one after the other.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import signal
import subprocess
import sys
import time
from typing import NamedTuple

import numpy as np

from geomodel_ros.tools.paths import FASTDDS_LARGE_DATA

#: Seconds the driver waits after matching before it publishes: > 2 polls of the node's
#: ``auto`` reliability check (0.5 s), so that the node subscribes as it finally will.
SETTLE_S = 1.5
#: Seconds a reliable driver waits for the node to acknowledge the last frame.
ACK_TIMEOUT_S = 10.0
#: Seconds the node keeps listening after the driver is done (late fragments).
DRAIN_S = 1.0
#: Longest wait for discovery / a process [s].
TIMEOUT_S = 60.0
#: Distance of the synthetic wall the driver's frames show [m] (any valid depth would do).
WALL_M = 1.2
SIZES = {"640x480": (480, 640), "1280x720": (720, 1280)}
KINDS = ("cloud", "depth")


class Setup(NamedTuple):
    """One measured combination."""

    kind: str
    size: str
    publisher: str
    node: str
    profile: str


PROFILES = ("default", "large_data", "node_only")


def _env(domain: int, profile: bool) -> dict[str, str]:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain))
    env.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
    if profile:
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(FASTDDS_LARGE_DATA)
    return env


def _messages(kind: str, size: str):
    """Return the message the driver publishes (and the CameraInfo of a depth image)."""
    from msg_adapters.depth_image import CameraModel, camera_info, depth_image
    from msg_adapters.header import make_header
    from msg_adapters.pointcloud2 import xyz_to_cloud

    height, width = SIZES[size]
    header = make_header("camera_optical", 1)
    model = CameraModel(fx=0.8 * width, fy=0.8 * width, cx=(width - 1) / 2,
                        cy=(height - 1) / 2, width=width, height=height)
    depth = np.full((height, width), WALL_M)
    if kind == "depth":
        return depth_image(depth, header, encoding="16UC1"), camera_info(model, header)
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    xyz = np.stack([(u - model.cx) / model.fx * depth, (v - model.cy) / model.fy * depth,
                    depth], axis=-1)
    return xyz_to_cloud(xyz, header), None


def _payload_mb(kind: str, size: str) -> float:
    msg, _ = _messages(kind, size)
    return len(msg.data) / 1e6


# ------------------------------------------------------------------------------ roles
def _role_node(reliability: str, kind: str) -> int:
    """Run the node until SIGINT; print the frames its subscription delivered (JSON)."""
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.parameter import Parameter

    from geomodel_ros.core.primitives import ModelingResult
    from geomodel_ros.ros.node import ModelerNode

    def no_objects(points, _params, **_organized_shape):
        return np.full(len(points), -1, dtype=np.int64), ModelingResult(objects=[], timing={})

    rclpy.init()
    node = ModelerNode(model_scene=no_objects, cli_args=[
        "--ros-args", "-r", "points:=/bench/points", "-r", "depth/image_raw:=/bench/image",
        "-r", "depth/camera_info:=/bench/camera_info"], parameter_overrides=[
        Parameter("qos_reliability", value=reliability),
        Parameter("input", value="points" if kind == "cloud" else "depth"),
        Parameter("diagnostics", value=False), Parameter("publish_segments", value=False),
        Parameter("publish_reconstruction", value=False)])
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        stats = node.stats()
        print(json.dumps({"received": stats.received, "failed": stats.failed,
                          "reliability": node.input_reliability}), flush=True)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _role_driver(kind: str, size: str, reliability: str, frames: int, rate: float) -> int:
    """Publish ``frames`` messages once the node's subscription matched; print JSON."""
    import rclpy
    from rclpy.duration import Duration
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from msg_adapters.interfaces import CameraInfo, Image, PointCloud2

    msg, info = _messages(kind, size)
    policy = ReliabilityPolicy.RELIABLE if reliability == "reliable" else \
        ReliabilityPolicy.BEST_EFFORT
    qos = QoSProfile(depth=10, reliability=policy)
    rclpy.init()
    node = rclpy.create_node("bench_driver")
    try:
        if kind == "depth":
            pub = node.create_publisher(Image, "/bench/image", qos)
            info_pub = node.create_publisher(CameraInfo, "/bench/camera_info", qos)
        else:
            pub, info_pub = node.create_publisher(PointCloud2, "/bench/points", qos), None
        deadline = time.monotonic() + TIMEOUT_S
        while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
        time.sleep(SETTLE_S)
        for i in range(frames):
            if info_pub is not None:
                info_pub.publish(info)  # drivers send one with every image
            pub.publish(msg)
            time.sleep(1.0 / rate)
        acked = pub.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S)) \
            if reliability == "reliable" else True
        print(json.dumps({"sent": frames, "matched": pub.get_subscription_count(),
                          "acked": bool(acked)}), flush=True)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


# ------------------------------------------------------------------------ orchestration
def _last_json(text: str) -> dict:
    for line in reversed(text.strip().splitlines()):
        if line.startswith("{"):
            return json.loads(line)
    raise RuntimeError(f"no result in the output:\n{text[-2000:]}")


def measure(setup: Setup, frames: int, rate: float, domain: int) -> dict:
    """Run one set-up in two fresh processes; return sent/delivered and details."""
    env = _env(domain, setup.profile == "large_data")
    me = [sys.executable, "-m", "geomodel_ros.tools.bench_delivery"]
    node = subprocess.Popen(me + ["--role", "node", "--node-reliability", setup.node,
                                  "--kind", setup.kind],
                            env=_env(domain, setup.profile != "default"),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        driver = subprocess.run(
            me + ["--role", "driver", "--kind", setup.kind, "--size", setup.size,
                  "--publisher", setup.publisher, "--frames", str(frames), "--rate", str(rate)],
            env=env, capture_output=True, text=True, timeout=TIMEOUT_S + frames / rate + 30)
        sent = _last_json(driver.stdout)
        time.sleep(DRAIN_S)
    finally:
        node.send_signal(signal.SIGINT)
        out, err = node.communicate(timeout=TIMEOUT_S)
    got = _last_json(out)
    return {**setup._asdict(), "sent": sent["sent"], "delivered": got["received"],
            "matched": sent["matched"], "subscribed": list(got["reliability"].values())}


def _setups(args) -> list[Setup]:
    return [Setup(*s) for s in itertools.product(args.kind, args.size, args.publisher,
                                                 args.node, args.profile)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m geomodel_ros.tools.bench_delivery",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=20, help="frames per set-up")
    parser.add_argument("--rate", type=float, default=5.0, help="publishing rate [Hz]")
    parser.add_argument("--kind", nargs="+", choices=KINDS, default=list(KINDS))
    parser.add_argument("--size", nargs="+", choices=list(SIZES), default=list(SIZES))
    parser.add_argument("--publisher", nargs="+", choices=("reliable", "best_effort"),
                        default=["reliable", "best_effort"])
    parser.add_argument("--node", nargs="+", choices=("best_effort", "auto", "reliable"),
                        default=["best_effort", "auto"], help="the node's qos_reliability")
    parser.add_argument("--profile", nargs="+", choices=PROFILES,
                        default=["default", "large_data"])
    parser.add_argument("--json", help="also write the rows to this file")
    parser.add_argument("--role", choices=("bench", "node", "driver"), default="bench",
                        help=argparse.SUPPRESS)
    parser.add_argument("--node-reliability", default="auto", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.role == "node":
        return _role_node(args.node_reliability, args.kind[0])
    if args.role == "driver":
        return _role_driver(args.kind[0], args.size[0], args.publisher[0], args.frames,
                            args.rate)
    if args.frames < 1 or not args.rate > 0:
        parser.error("--frames must be >= 1 and --rate > 0")
    domain = int(os.environ.get("ROS_DOMAIN_ID", 1 + os.getpid() % 100))
    print(f"{args.frames} frames per set-up at {args.rate:g} Hz, one set-up at a time, "
          f"ROS_DOMAIN_ID {domain}, loopback only")
    print(f"{'message':<9s} {'size':<9s} {'MB':>5s}  {'driver':<11s} {'node':<11s} "
          f"{'middleware':<11s} {'subscribed':<12s} {'delivered/sent':>14s}")
    rows = []
    for setup in _setups(args):
        row = measure(setup, args.frames, args.rate, domain)
        rows.append(row)
        print(f"{setup.kind:<9s} {setup.size:<9s} {_payload_mb(setup.kind, setup.size):5.2f}  "
              f"{setup.publisher:<11s} {setup.node:<11s} "
              f"{setup.profile:<11s} "
              f"{'/'.join(r or '-' for r in row['subscribed']):<12s} "
              f"{row['delivered']:>6d}/{row['sent']:<7d}", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
