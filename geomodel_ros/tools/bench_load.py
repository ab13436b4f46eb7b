"""Sustained-load benchmark of the ``modeler`` node running as its own process.

Run as::

    python -m geomodel_ros.tools.bench_load --minutes 10 --cloud paper          # 15 Hz
    python -m geomodel_ros.tools.bench_load --minutes 10 --cloud kinect         # 30 Hz

The node is started as a separate process (``sys.executable -m geomodel_ros.ros.node``), and
this process publishes clouds to it faster than it can model them, for ``--minutes``:

* ``paper``: the paper's Scene 3 (``render_scene("scene3")``, 624 x 1104 organized,
  ~370k valid points) at 15 Hz with the default parameters;
* ``kinect``: osd_learn scenes (640 x 480 Kinect frames, :func:`geomodel_ros.tools.io.load_osd`
  from :func:`geomodel_ros.tools.benchmark.data_dir`), cycled, at 30 Hz with
  ``config/kinect.yaml``.

With ``--input depth`` the same frames go out as 16UC1 depth images [mm] with their
CameraInfo (the osd_learn frames' pinhole model,
:data:`geomodel_ros.tools.bench_node.OSD_CAMERA`;
the rendered scene's own), and the node subscribes them (``input: depth``): messages 6x
smaller than the clouds.

It subscribes to every output (like RViz) and reports:

* frames published / received by the node / processed / dropped (newest frame wins) /
  failed, from the node's ``/diagnostics``; lost in transport = published - received;
* processed rate [Hz];
* latency from the input's stamp (wall clock at publish) to the MarkerArray's arrival:
  median, p95, max [ms], and p95 over the single-frame processing time (the node's
  per-frame work on the same clouds, measured in this process before the load starts);
* the node process's RSS (``/proc/<pid>/status`` VmRSS, sampled at 1 Hz; with ``--workers``
  N > 1 summed over its worker processes) after warm-up
  and at the end (medians of one-minute windows), its growth, and the maximum of each
  half of the run [MiB];
* crashes (the node process exiting during the run) and malformed outputs (a marker with
  a non-finite pose or a non-positive scale, or a header other than the input's).

Every process keeps DDS discovery on loopback (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``);
a private ``ROS_DOMAIN_ID`` is used unless one is set.  Exit status: 0 when the node
survived and every output was well-formed, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from geomodel_ros.tools.paths import FASTDDS_LARGE_DATA, REPO

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # before rclpy starts DDS
os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
# Several-MB clouds between processes: Fast DDS over shared memory with large segments
# (inherited by the node process too); see config/fastdds_large_data.xml.
os.environ.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(FASTDDS_LARGE_DATA))

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data  # noqa: E402

from msg_adapters.diagnostics import read_status_values  # noqa: E402
from msg_adapters.header import NS_PER_S, StampedFrame, make_header, set_stamp  # noqa: E402
from msg_adapters.depth_image import CameraModel, camera_info, depth_image  # noqa: E402
from msg_adapters.interfaces import (CameraInfo, DiagnosticArray, Image, MarkerArray,  # noqa: E402
                                     PointCloud2)
from msg_adapters.markers import marker_array_frame, marker_array_problem  # noqa: E402
from msg_adapters.pointcloud2 import cloud_size, cloud_to_xyz, xyz_to_cloud  # noqa: E402

__all__ = ["main"]

FRAME = "camera_optical"
TOPIC = "/bench_load/points"
DEPTH_TOPIC = "/bench_load/depth"
INFO_TOPIC = "/bench_load/camera_info"
DEFAULT_RATE = {"paper": 15.0, "kinect": 30.0}
_RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


def _organized(kind: str, count: int) -> tuple[list[np.ndarray], CameraModel]:
    """Return the frames' (H, W, 3) organized points [m] and their camera."""
    if kind == "paper":
        from geomodel_ros.tools.synth import render_scene

        rendered = render_scene("scene3")
        return [rendered.organized], CameraModel(**rendered.intrinsics)
    from geomodel_ros.tools.benchmark import data_dir
    from geomodel_ros.tools.bench_node import OSD_CAMERA
    from geomodel_ros.tools.io import load_osd

    folder = data_dir() / "osd_learn"
    return [load_osd(folder / f"learn{k}.pcd")[0].reshape(OSD_CAMERA.height, OSD_CAMERA.width, 3)
            for k in range(count)], OSD_CAMERA


def _depth_messages(frames: list[np.ndarray], camera: CameraModel
                    ) -> list[tuple[Image, CameraInfo]]:
    """Return the frames as 16UC1 depth images [mm] with their CameraInfo."""
    return [(depth_image(points[..., 2], make_header(FRAME), encoding="16UC1"),
             camera_info(camera, make_header(FRAME))) for points in frames]


def _single_frame_s(clouds: list[PointCloud2], params_file: str | None, repeats: int = 3
                    ) -> float:
    """Measure the median time [s] of the node's per-frame work on these clouds.

    The work is ``process_cloud`` (conversion, segmentation, modeling, output messages),
    measured here, one frame at a time, before the load starts.
    """
    from geomodel_ros.ros.processing import process_cloud

    from geomodel_ros.core.params import ModelingParams, load_params_file

    params = load_params_file(params_file) if params_file else ModelingParams()
    process_cloud(clouds[0], params)  # warm-up (imports, caches)
    times = []
    for msg in clouds:
        for _ in range(repeats):
            t0 = time.perf_counter()
            process_cloud(msg, params)
            times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _rss_mib(pid: int) -> float:
    """VmRSS of process ``pid`` and of all its descendants [MiB] (NaN once it is gone).

    The node's worker processes (``workers`` > 1) and their fork server are its
    descendants; pages they share are counted once per process (an upper bound).
    """
    own = _own_rss_mib(pid)
    return own + sum(_rss_mib(child) for child in _children(pid)) if own == own else own


def _own_rss_mib(pid: int) -> float:
    """VmRSS of process ``pid`` alone [MiB] (NaN once it is gone)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return math.nan


def _children(pid: int) -> list[int]:
    """Process ids of ``pid``'s children (of every thread), [] once it is gone."""
    out: list[int] = []
    try:
        for task in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{task}/children") as f:
                out += [int(c) for c in f.read().split()]
    except OSError:
        pass
    return out


class _Recorder:
    """Peer node: publishes the clouds, records markers and the node's diagnostics."""

    def __init__(self, context: Context, reliable: bool, depth: bool = False) -> None:
        self.node = Node("bench_load", context=context)
        qos_in = _RELIABLE if reliable else qos_profile_sensor_data
        if depth:  # a camera driver's pair: the image and its CameraInfo, same QoS
            self.pub = self.node.create_publisher(Image, DEPTH_TOPIC, qos_in)
            self.info_pub = self.node.create_publisher(CameraInfo, INFO_TOPIC, qos_in)
        else:
            self.pub = self.node.create_publisher(PointCloud2, TOPIC, qos_in)
            self.info_pub = None
        self.lock = threading.Lock()
        self.latencies: list[tuple[float, float]] = []  # (arrival, latency) [s]
        self.malformed: list[str] = []
        self.diagnostics: dict[str, str] = {}
        self.node.create_subscription(MarkerArray, "/modeler/primitives", self._on_markers,
                                      _RELIABLE)
        for topic in ("/modeler/segments", "/modeler/reconstruction"):  # like RViz
            self.node.create_subscription(PointCloud2, topic, lambda _: None, _RELIABLE)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)

    def _on_markers(self, msg: MarkerArray) -> None:
        now = time.time()
        frame = marker_array_frame(msg)
        if frame is None:
            with self.lock:
                self.malformed.append("empty MarkerArray")
            return
        why = marker_array_problem(msg, StampedFrame(FRAME, frame.stamp_ns))
        with self.lock:
            self.latencies.append((now, now - frame.stamp_ns / NS_PER_S))
            if why:
                self.malformed.append(why)

    def _on_diag(self, msg: DiagnosticArray) -> None:
        values = read_status_values(msg, "/modeler")
        if values is not None:
            with self.lock:
                self.diagnostics = values


def _wait(predicate, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def _stop(proc: subprocess.Popen) -> int:
    """SIGINT (as Ctrl-C / ros2 launch do), then escalate; the exit status."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            return proc.wait(15.0)
        except subprocess.TimeoutExpired:
            proc.terminate()
            try:
                return proc.wait(5.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                return proc.wait()
    return int(proc.returncode)


@dataclass
class _LoadRun:
    """What the publishing loop saw."""

    published: int = 0
    published_warm: int = 0
    elapsed: float = 0.0
    crashed_at: float | None = None
    rss_series: list[tuple[float, float]] = field(default_factory=list)  # (s, MiB), 1 Hz


def _start_node(args: argparse.Namespace, params: str | None
                ) -> tuple[subprocess.Popen, list[str], str]:
    """Start the node process; its handle, command line and log file name."""
    inputs = ["-p", "input:=depth", "-r", f"depth/image_raw:={DEPTH_TOPIC}", "-r",
              f"depth/camera_info:={INFO_TOPIC}"] if args.input == "depth" else \
        ["-r", f"points:={TOPIC}"]
    cmd = [sys.executable, "-m", "geomodel_ros.ros.node", "--ros-args", *inputs,
           "-p", f"qos_reliability:={'reliable' if args.reliable else 'best_effort'}"]
    if params:
        cmd += ["--params-file", params]
    if args.workers is not None:
        cmd += ["-p", f"workers:={args.workers}"]
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONPATH=os.pathsep.join(filter(None, [str(REPO),
                                                        os.environ.get("PYTHONPATH")])))
    log = tempfile.NamedTemporaryFile("w+", prefix="bench_load_node_", suffix=".log",
                                      delete=False)
    proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT, cwd=REPO)
    return proc, cmd, log.name


def _publish_load(rec: _Recorder, proc: subprocess.Popen, clouds: list,
                  rate: float, args: argparse.Namespace) -> _LoadRun:
    """Publish the clouds (or (image, CameraInfo) pairs) at ``rate`` for ``args.minutes``.

    The node's RSS is sampled at 1 Hz.
    """
    period = 1.0 / rate
    start = time.monotonic()
    end = start + 60.0 * args.minutes
    out = _LoadRun()
    next_rss = start
    tick = threading.Event()
    while (now := time.monotonic()) < end:
        if proc.poll() is not None:
            out.crashed_at = now - start
            break
        msg = clouds[out.published % len(clouds)]
        t = time.time()
        stamp = int(t) * NS_PER_S + int((t % 1.0) * 1e9)
        if rec.info_pub is not None:  # (image, CameraInfo): the CameraInfo first
            msg, info = msg
            set_stamp(info, stamp)
            rec.info_pub.publish(info)
        set_stamp(msg, stamp)
        rec.pub.publish(msg)
        out.published += 1
        if now >= next_rss:
            out.rss_series.append((now - start, _rss_mib(proc.pid)))
            next_rss = now + 1.0
            if not out.published_warm and now - start >= args.warmup:
                out.published_warm = out.published
        tick.wait(max(0.0, start + out.published * period - time.monotonic()))  # pacing
    out.elapsed = time.monotonic() - start
    return out


def _drain(rec: _Recorder, proc: subprocess.Popen) -> None:
    """Wait for the node's last diagnostics (1 Hz) after the input stopped."""
    with rec.lock:
        seen = dict(rec.diagnostics)
    _wait(lambda: proc.poll() is not None or rec.diagnostics.get("frames_received") !=
          seen.get("frames_received"), 5.0)
    _wait(lambda: proc.poll() is not None or (
        rec.diagnostics.get("frames_processed") is not None
        and int(rec.diagnostics["frames_received"]) == int(rec.diagnostics["frames_processed"])
        + int(rec.diagnostics["frames_dropped"]) + int(rec.diagnostics["frames_failed"])),
        30.0)
    _wait(lambda: proc.poll() is not None, 2.5)  # one more diagnostics period


def _run_under_load(args: argparse.Namespace, proc: subprocess.Popen, log_name: str,
                    clouds: list, rate: float) -> tuple[_LoadRun, int, _Recorder]:
    """Peer node up, load published, node drained and stopped; its exit status."""
    context = Context()
    rclpy.init(args=[], context=context)
    rec = _Recorder(context, args.reliable, depth=args.input == "depth")
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(rec.node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        if not _wait(lambda: rec.pub.get_subscription_count() >= 1
                     and (rec.info_pub is None or rec.info_pub.get_subscription_count() >= 1)
                     and rec.node.count_publishers("/modeler/primitives") >= 1
                     or proc.poll() is not None, 60.0) or proc.poll() is not None:
            raise RuntimeError(f"the node did not come up (exit status {proc.poll()}); "
                               f"see {log_name}")
        if rec.info_pub is not None:  # a driver's CameraInfo is out before its first image
            for _ in range(10):  # best effort, and the node's reader may match a bit later
                rec.info_pub.publish(clouds[0][1])
                time.sleep(0.1)
        load = _publish_load(rec, proc, clouds, rate, args)
        _drain(rec, proc)
    finally:
        exit_status = _stop(proc)
        executor.shutdown(timeout_sec=5.0)
        spinner.join(5.0)
        rec.node.destroy_node()
        rclpy.try_shutdown(context=context)
    return load, exit_status, rec


def run(args: argparse.Namespace) -> dict:
    """Run the load and return the report (see the module docstring)."""
    rate = args.rate or DEFAULT_RATE[args.cloud]
    frames, camera = _organized(args.cloud, args.kinect_scenes)
    clouds = [xyz_to_cloud(points, make_header(FRAME)) for points in frames]  # stamps: at publish
    valid = int(np.count_nonzero(np.isfinite(cloud_to_xyz(clouds[0], keep_organized=True)[..., 0])))
    params = args.params or (str(REPO / "config" / "kinect.yaml")
                             if args.cloud == "kinect" else None)
    single_s = _single_frame_s(clouds, params)
    size = cloud_size(clouds[0])
    messages = _depth_messages(frames, camera) if args.input == "depth" else clouds
    nbytes = len(messages[0][0].data) if args.input == "depth" else size.nbytes
    proc, cmd, log_name = _start_node(args, params)
    print(f"{args.cloud}: {size.height} x {size.width} ({valid} valid points, "
          f"{args.input} input, {nbytes / 1e6:.2f} MB per message, {len(clouds)} distinct) at "
          f"{rate:g} Hz for {args.minutes:g} min; node log {log_name}", flush=True)
    load, exit_status, rec = _run_under_load(args, proc, log_name, messages, rate)
    report: dict = {"cloud": args.cloud, "input": args.input, "message_mb": nbytes / 1e6,
                    "rate_hz": rate, "minutes": args.minutes,
                    "workers": args.workers or 1,
                    "points": valid, "command": cmd, "single_frame_ms": 1000.0 * single_s}
    with rec.lock:
        diag = dict(rec.diagnostics)
        arrivals = list(rec.latencies)
        malformed = list(rec.malformed)
    report.update(_frame_counts(diag, load, len(arrivals)))
    report.update(_latency_report(arrivals, single_s))
    report.update({
        "rss_mib": _rss_summary(load.rss_series, args.warmup, load.elapsed),
        "published_during_warmup": load.published_warm,
        "crashed": load.crashed_at is not None,
        "crashed_after_s": load.crashed_at,
        "node_exit_status": exit_status,
        "malformed_outputs": len(malformed),
        "malformed_examples": malformed[:5],
        "node_log": log_name,
    })
    return report


def _frame_counts(diag: dict[str, str], load: _LoadRun, marker_arrays: int) -> dict:
    received = int(diag.get("frames_received", -1))
    return {
        "duration_s": load.elapsed,
        "published": load.published,
        "received": received,
        "processed": int(diag.get("frames_processed", -1)),
        "dropped": int(diag.get("frames_dropped", -1)),
        "failed": int(diag.get("frames_failed", -1)),
        "lost_in_transport": load.published - received if received >= 0 else None,
        "marker_arrays": marker_arrays,
        "processed_rate_hz": marker_arrays / load.elapsed if load.elapsed > 0 else math.nan,
    }


def _latency_report(arrivals: list[tuple[float, float]], single_s: float) -> dict:
    lat_ms = 1000.0 * np.array([lat for _, lat in arrivals]) if arrivals else np.array([])
    return {
        "latency_ms": {"median": float(np.median(lat_ms)) if lat_ms.size else math.nan,
                       "p95": float(np.percentile(lat_ms, 95)) if lat_ms.size else math.nan,
                       "max": float(lat_ms.max()) if lat_ms.size else math.nan},
        "latency_ms_first_last_third": _thirds(lat_ms),
        "latency_p95_over_single_frame": float(np.percentile(lat_ms, 95)) / (1000.0 * single_s)
        if lat_ms.size else math.nan,
    }


def _rss_summary(series: list[tuple[float, float]], warmup: float, elapsed: float,
                 window: float = 60.0) -> dict:
    """Summarize the node's RSS [MiB] over the run.

    After warm-up and at the end, each the median of a ``window`` of 1 Hz samples (single
    samples swing by tens of MiB with the allocator's high-water marks), their growth [%],
    and the maximum of each half of the run (a leak raises the second).
    """
    t = np.array([s for s, _ in series])
    v = np.array([m for _, m in series])
    ok = np.isfinite(v)
    warm = v[ok & (t >= warmup) & (t < warmup + window)]
    end = v[ok & (t >= elapsed - window)]
    half = elapsed / 2.0
    first, second = v[ok & (t >= warmup) & (t < half)], v[ok & (t >= half)]
    warm_m = float(np.median(warm)) if warm.size else math.nan
    end_m = float(np.median(end)) if end.size else math.nan
    return {"after_warmup": warm_m, "end": end_m,
            "growth_pct": 100.0 * (end_m / warm_m - 1.0) if warm_m > 0 else math.nan,
            "max": float(v[ok].max()) if ok.any() else math.nan,
            "max_first_half": float(first.max()) if first.size else math.nan,
            "max_second_half": float(second.max()) if second.size else math.nan,
            "window_s": window, "samples": int(ok.sum())}


def _thirds(lat_ms: np.ndarray) -> list[float]:
    k = len(lat_ms) // 3
    if k == 0:
        return [math.nan, math.nan]
    return [float(np.median(lat_ms[:k])), float(np.median(lat_ms[-k:]))]


def _print(r: dict) -> None:
    lat, rss = r["latency_ms"], r["rss_mib"]
    print(f"\n{r['cloud']} ({r.get('input', 'points')} input) at {r['rate_hz']:g} Hz for "
          f"{r['duration_s']:.0f} s, "
          f"{r.get('workers', 1)} worker(s) "
          f"({r['points']} valid points per frame)")
    print(f"  frames: published {r['published']}, received {r['received']} (lost in transport "
          f"{r['lost_in_transport']}), processed {r['processed']}, dropped {r['dropped']}, "
          f"failed {r['failed']}")
    print(f"  processed rate {r['processed_rate_hz']:.2f} Hz ({r['marker_arrays']} MarkerArrays)")
    print(f"  latency stamp -> MarkerArray [ms]: median {lat['median']:.0f}, p95 "
          f"{lat['p95']:.0f}, max {lat['max']:.0f}; median first/last third "
          f"{r['latency_ms_first_last_third'][0]:.0f}/{r['latency_ms_first_last_third'][1]:.0f}")
    print(f"  single-frame processing (before the load, median) {r['single_frame_ms']:.0f} ms; "
          f"latency p95 / single frame = {r['latency_p95_over_single_frame']:.2f} "
          f"(target <= 1.5)")
    print(f"  node RSS [MiB] (medians of {rss['window_s']:.0f} s windows): after warm-up "
          f"{rss['after_warmup']:.0f}, end {rss['end']:.0f} ({rss['growth_pct']:+.1f} %); max "
          f"first / second half {rss['max_first_half']:.0f} / {rss['max_second_half']:.0f}")
    print(f"  crashes: {'YES after %.0f s' % r['crashed_after_s'] if r['crashed'] else 'none'} "
          f"(exit status on SIGINT {r['node_exit_status']}); malformed outputs "
          f"{r['malformed_outputs']} {r['malformed_examples'] or ''}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m geomodel_ros.tools.bench_load",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--cloud", choices=("paper", "kinect"), default="paper")
    parser.add_argument("--input", choices=("points", "depth"), default="points",
                        help="send PointCloud2 clouds (default) or 16UC1 depth images with "
                             "their CameraInfo (the node's input: depth)")
    parser.add_argument("--rate", type=float, help="publish rate [Hz] (paper 15, kinect 30)")
    parser.add_argument("--params", help="params file for the node (kinect: "
                        "config/kinect.yaml by default)")
    parser.add_argument("--reliable", action="store_true",
                        help="reliable input QoS (default: best effort, like a camera)")
    parser.add_argument("--warmup", type=float, default=60.0,
                        help="seconds before the reference RSS is taken")
    parser.add_argument("--kinect-scenes", type=int, default=8,
                        help="osd_learn scenes cycled through (kinect)")
    parser.add_argument("--workers", type=int,
                        help="the node's workers parameter (frames modeled at once; default: "
                             "the node's default, 1)")
    parser.add_argument("--json", help="write the report here")
    args = parser.parse_args(argv)
    if args.minutes <= 0 or (args.rate is not None and args.rate <= 0):
        parser.error("--minutes and --rate must be > 0")
    if not 1 <= args.kinect_scenes <= 45:
        parser.error("--kinect-scenes must be in [1, 45]")
    report = run(args)
    _print(report)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2, default=float))
    ok = not report["crashed"] and report["malformed_outputs"] == 0 and report["failed"] == 0
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
