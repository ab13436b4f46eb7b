"""``make demo``: the paper's three desk scenes through the ROS 2 node, like a user does it.

1. Render the scenes into a rosbag2 (MCAP) of PointCloud2 frames (``geomodel synth --bag``).
2. Start the ``modeler`` node as its own process (the installed console script, with
   ``--params-file config/modeler.yaml``).
3. Replay the bag into it over DDS (``geomodel play``, loopback only) and record what the
   node publishes.
4. Print, per scene, the detected objects next to the ground truth (Figure 9 style), the
   per-frame latency and the typed objects of ``/modeler/objects`` (id, type, MoveIt shape
   and dimensions in mm, position); write pictures (segments, reconstruction, overlay) to
   ``demo_out/<scene>/``.

Exits non-zero when the node produced nothing (markers or typed objects missing for a
frame).
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

from geomodel_ros.tools.paths import FASTDDS_LARGE_DATA, REPO
from typing import Sequence

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # before rclpy starts DDS
# ~8 MB clouds between processes: Fast DDS over shared memory with large segments (the
# default transports lose such messages on loopback). Nothing leaves the host.
os.environ.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(FASTDDS_LARGE_DATA))

import numpy as np  # noqa: E402

from msg_adapters.header import stamp_ns  # noqa: E402
from msg_adapters.markers import marker_array_frame  # noqa: E402

__all__ = ["run_demo", "main"]

ROOT = REPO
TOPIC = "/camera/depth/points"
OBJECTS_TOPIC = "/modeler/objects"
#: Names of geomodel_msgs/Primitive's ``type`` and shape_msgs/SolidPrimitive's ``type``.
OBJECT_TYPES = ("PLANE", "CUBOID", "CYLINDER", "CONE", "SPHERE", "FRUSTUM", "UNKNOWN")
SHAPE_TYPES = ("BOX", "SPHERE", "CYLINDER", "CONE")


def _node_command(params_file: Path) -> list[str]:
    """Return the installed ``modeler`` console script (as ``ros2 run`` would start it)."""
    script = Path(sys.prefix) / "lib" / "geomodel_ros" / "modeler"
    exe = [str(script)] if script.exists() else [sys.executable, "-m", "geomodel_ros.ros.node"]
    return exe + ["--ros-args", "--params-file", str(params_file), "-r", f"points:={TOPIC}",
                  "-p", "qos_reliability:=reliable", "-p", "qos_depth:=10"]


class _Recorder:
    """Subscribes to the node's outputs and to the replayed input; keeps them by stamp."""

    def __init__(self, context) -> None:
        from rclpy.node import Node
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        from msg_adapters.interfaces import MarkerArray, PointCloud2
        from msg_adapters.objects import PrimitiveArray

        self.node = Node("geomodel_demo_recorder", context=context)
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.lock = threading.Lock()
        self.inputs: dict[int, float] = {}
        self.markers: dict[int, tuple[float, object]] = {}
        self.segments: dict[int, object] = {}
        self.objects: dict[int, object] = {}
        self.node.create_subscription(PointCloud2, TOPIC, self._on_input, qos)
        self.node.create_subscription(MarkerArray, "/modeler/primitives", self._on_markers, qos)
        self.node.create_subscription(PointCloud2, "/modeler/segments", self._on_segments, qos)
        self.node.create_subscription(PrimitiveArray, OBJECTS_TOPIC, self._on_objects, qos)

    def _on_input(self, msg) -> None:
        with self.lock:
            self.inputs[stamp_ns(msg)] = time.monotonic()

    def _on_markers(self, msg) -> None:
        frame = marker_array_frame(msg)
        if frame is not None:
            with self.lock:
                self.markers[frame.stamp_ns] = (time.monotonic(), msg)

    def _on_segments(self, msg) -> None:
        with self.lock:
            self.segments[stamp_ns(msg)] = msg

    def _on_objects(self, msg) -> None:
        with self.lock:
            self.objects[stamp_ns(msg)] = msg

    def complete(self, frames: int) -> bool:
        """Whether markers, typed objects and segments arrived for ``frames`` frames.

        Hold the lock. The node publishes a frame's segments cloud after its markers and
        objects, so a frame is complete only once that has arrived too (the pictures use it).
        """
        return min(len(self.markers), len(self.objects), len(self.segments)) >= frames


def _match(truth: list[dict], detected) -> list[tuple[dict, object]]:
    """Pair each ground-truth object with the nearest detected one of the same type."""
    free = list(detected)
    pairs = []
    for gt in truth:
        c = np.asarray(gt["center"])
        same = [p for p in free if p.type == gt["type"]]
        best = min(same, key=lambda p: float(np.linalg.norm(p.center - c)), default=None)
        if best is not None and np.linalg.norm(best.center - c) < 0.05:
            free.remove(best)
            pairs.append((gt, best))
        else:
            pairs.append((gt, None))
    return pairs


def _table(truth: list[dict], detected) -> tuple[str, int]:
    from geomodel_ros.tools.evaluation import dimension_errors
    from geomodel_ros.tools.synth import GroundTruthObject

    lines = [f"  {'object':<10} {'true size (mm)':<34} {'modeled (mm)':<34} {'error (mm)':<24}"]
    found = 0
    for gt, est in _match(truth, detected):
        g = GroundTruthObject(gt["id"], gt["type"], np.asarray(gt["center"]),
                              np.asarray(gt["rotation"]), gt["dimensions"])
        true = ", ".join(f"{k[0].upper()}={v * 1000:.2f}" for k, v in gt["dimensions"].items())
        if est is None:
            lines.append(f"  {gt['type']:<10} {true:<34} {'not found':<34}")
            continue
        found += 1
        errs = dimension_errors(est, g)
        est_s = ", ".join(f"{e.name[0].upper()}={e.estimate * 1000:.2f}" for e in errs)
        true_s = ", ".join(f"{e.name[0].upper()}={e.true * 1000:.2f}" for e in errs)
        err_s = ", ".join(f"{e.error * 1000:+.2f}" for e in errs)
        lines.append(f"  {gt['type']:<10} {true_s:<34} {est_s:<34} {err_s:<24}")
    return "\n".join(lines), found


def _objects_table(msg) -> str:
    """One row per typed object: id, type, MoveIt shape with dimensions [mm], position [m]."""
    from shape_msgs.msg import SolidPrimitive

    from msg_adapters.objects import PrimitiveMsg

    types = {getattr(PrimitiveMsg, n): n.lower() for n in OBJECT_TYPES}
    shapes = {getattr(SolidPrimitive, n): n for n in SHAPE_TYPES}
    lines = [f"  {'id':>4}  {'type':<9} {'MoveIt shape':<12} {'dimensions (mm)':<24} "
             f"{'position (m)':<26}"]
    for p in sorted(msg.primitives, key=lambda q: q.id):
        dims = " x ".join(f"{d * 1000:.1f}" for d in p.shape.dimensions) or "-"
        pos = p.pose.position
        lines.append(f"  {p.id:>4}  {types.get(p.type, str(p.type)):<9} "
                     f"{shapes.get(p.shape.type, '-'):<12} {dims:<24} "
                     f"({pos.x:+.3f}, {pos.y:+.3f}, {pos.z:+.3f})")
    return "\n".join(lines)


def _wait_until_ready(recorder: _Recorder, node_proc: subprocess.Popen,
                      timeout_s: float = 60.0) -> bool:
    """Wait until the node is up; False if it is not after ``timeout_s`` or has exited.

    Up means: it subscribed to the input (besides the recorder) and its outputs were
    discovered.
    """
    ready = time.monotonic() + timeout_s
    while time.monotonic() < ready and node_proc.poll() is None:
        if recorder.node.count_subscribers(TOPIC) >= 2 and \
                recorder.node.count_publishers("/modeler/primitives") >= 1:
            return True
        time.sleep(0.05)
    return False


def _replay(bag: Path, truth: dict, rate: float, context, recorder: _Recorder,
            node_proc: subprocess.Popen, timeout_s: float) -> None:
    """Play the bag into the node until every frame has a result (at most three times)."""
    from geomodel_ros.ros.bags import play

    # DDS can lose the first frames while a new publisher and the node's reader
    # match; frames without a result are replayed (at most three times in all).
    for attempt in range(3):
        print(f"[demo] replaying {truth['frames']} frames at {rate} Hz over DDS "
              f"(loopback){' again' if attempt else ''} ...", flush=True)
        play(bag, rate=rate, context=context, wait_timeout=60.0, min_subscribers=2)
        deadline = time.monotonic() + min(timeout_s, 15.0 + 3.0 * truth["frames"])
        while time.monotonic() < deadline and node_proc.poll() is None:
            with recorder.lock:
                if recorder.complete(truth["frames"]):
                    break
            time.sleep(0.05)
        with recorder.lock:
            if recorder.complete(truth["frames"]) or node_proc.poll() is not None:
                return


def _pictures(segments_msg, detected, scene: dict, out: Path) -> None:
    from geomodel_ros.tools.render import render_figures
    from msg_adapters.pointcloud2 import cloud_to_fields, cloud_to_xyz_and_mask

    pts, _ = cloud_to_xyz_and_mask(segments_msg, skip_nans=False)
    ids = cloud_to_fields(segments_msg, ["object_id"])["object_id"]
    files = render_figures(pts, np.asarray(ids).astype(np.int64).ravel(), detected,
                           out / scene["name"], title_prefix=f"{scene['name']}: ",
                           intrinsics=scene.get("intrinsics"))
    print(f"  pictures: {', '.join(str(f) for f in files)}\n", flush=True)


def _report_scene(scene: dict, recorded: tuple[dict, dict, dict, dict], out: Path,
                  pictures: bool) -> int:
    """Print one scene's tables (and write its pictures); objects found."""
    from msg_adapters.markers import markers_to_primitives

    markers, inputs, segments, objects = recorded
    stamps = [s for s in scene["stamps_ns"] if s in markers]
    lat = [1000.0 * (markers[s][0] - inputs[s]) for s in stamps if s in inputs]
    print(f"== {scene['name']}: {len(stamps)}/{len(scene['stamps_ns'])} frames modeled"
          + (f", latency input -> primitives median {statistics.median(lat):.0f} ms "
             f"(max {max(lat):.0f} ms)" if lat else ""))
    if not stamps:
        return 0
    last = stamps[-1]
    detected = markers_to_primitives(markers[last][1])
    table, found = _table(scene["objects"], detected)
    print(table)
    print(f"  {found}/{len(scene['objects'])} objects found with the right type; "
          f"{len(detected)} primitives published\n")
    typed = [s for s in scene["stamps_ns"] if s in objects]
    print(f"  typed objects on {OBJECTS_TOPIC}: {len(typed)}/{len(scene['stamps_ns'])} "
          "frames" + (f", last frame {len(objects[typed[-1]].primitives)} objects" if typed
                      else ""))
    if typed:
        print(_objects_table(objects[typed[-1]]) + "\n")
    if pictures and last in segments:
        _pictures(segments[last], detected, scene, out)
    return found


def _stop_node(node_proc: subprocess.Popen, out: Path) -> None:
    """SIGINT the node (escalate after 10 s) and write its output to ``out/node.log``."""
    if node_proc.poll() is None:
        node_proc.send_signal(signal.SIGINT)
        try:
            node_proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            node_proc.kill()
    log = node_proc.stdout.read() if node_proc.stdout else ""
    (out / "node.log").write_text(log)


def _render_bag(out: Path, scenes: Sequence[str], frames: int, rate: float) -> tuple[Path, dict]:
    """Write the scenes' bag under ``out``; its path and ground truth."""
    import json
    import shutil

    from geomodel_ros.ros.bags import ground_truth_path, write_synth_bag

    bag = out / "scenes_bag"
    if bag.exists():
        shutil.rmtree(bag)
    out.mkdir(parents=True, exist_ok=True)
    print(f"[demo] rendering {', '.join(scenes)} ({frames} frames each) into {bag} ...",
          flush=True)
    write_synth_bag(bag, list(scenes), frames=frames, rate=rate, topic=TOPIC)
    return bag, json.loads(ground_truth_path(bag).read_text())


def _start_node(domain: int) -> subprocess.Popen:
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
           "ROS_DOMAIN_ID": str(domain)}
    cmd = _node_command(ROOT / "config" / "modeler.yaml")
    shown = " ".join(Path(c).name if i == 0 else c for i, c in enumerate(cmd))
    print(f"[demo] starting the node: {shown}", flush=True)
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)


def run_demo(out_dir: str | Path = "demo_out", scenes: Sequence[str] = ("scene1", "scene2",
             "scene3"), frames: int = 2, rate: float = 1.0, pictures: bool = True,
             timeout_s: float = 120.0) -> int:
    """Run the demo; returns the process exit code (0 when every frame was modeled)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    out = Path(out_dir)
    t0 = time.monotonic()
    bag, truth = _render_bag(out, scenes, frames, rate)
    domain = int(os.environ.get("ROS_DOMAIN_ID", 1 + os.getpid() % 100))
    node_proc = _start_node(domain)
    context = Context()
    rclpy.init(args=[], context=context, domain_id=domain)
    recorder = _Recorder(context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(recorder.node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        if not _wait_until_ready(recorder, node_proc):
            print("[demo] the node did not come up (see demo_out/node.log)", flush=True)
            return 1
        _replay(bag, truth, rate, context, recorder, node_proc, timeout_s)
        with recorder.lock:
            recorded = (dict(recorder.markers), dict(recorder.inputs), dict(recorder.segments),
                        dict(recorder.objects))
        print(f"[demo] the node published results for {len(recorded[0])} of {truth['frames']} "
              f"frames, typed objects for {len(recorded[3])}\n", flush=True)
        all_found = sum(_report_scene(scene, recorded, out, pictures)
                        for scene in truth["scenes"])
        all_total = sum(len(scene["objects"]) for scene in truth["scenes"]
                        if any(s in recorded[0] for s in scene["stamps_ns"]))
        print(f"[demo] {all_found}/{all_total} ground-truth objects found; "
              f"done in {time.monotonic() - t0:.0f} s", flush=True)
        complete = all(len(r) == truth["frames"] for r in (recorded[0], recorded[3]))
        return 0 if truth["frames"] and complete else 1
    finally:
        executor.shutdown(timeout_sec=5.0)
        spinner.join(timeout=5.0)
        recorder.node.destroy_node()
        rclpy.try_shutdown(context=context)
        _stop_node(node_proc, out)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="geomodel demo", description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="demo_out")
    ap.add_argument("--scenes", nargs="+", default=["scene1", "scene2", "scene3"])
    ap.add_argument("--frames", type=int, default=2)
    ap.add_argument("--rate", type=float, default=1.0)
    ap.add_argument("--no-pictures", action="store_true")
    args = ap.parse_args(argv)
    return run_demo(args.out, args.scenes, args.frames, args.rate, not args.no_pictures)


if __name__ == "__main__":
    sys.exit(main())
