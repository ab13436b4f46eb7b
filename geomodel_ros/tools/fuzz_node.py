"""Fuzz the running ``modeler`` node with malformed PointCloud2 messages.

Run as::

    python -m geomodel_ros.tools.fuzz_node --cases 10000

The node is started as its own process (``python -m geomodel_ros.ros.node``, as
:mod:`geomodel_ros.tools.bench_load` does; DDS stays on loopback with
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and a private ``ROS_DOMAIN_ID`` unless one is
set).  Hypothesis draws ``--cases`` messages (:func:`messages`): field layouts with x, y or
z missing, wrong or unknown datatypes, ``count`` other than 1, repeated names, overlapping
offsets, offsets past ``point_step``; either byte order (also declared but not written);
``point_step`` / ``row_step`` lies; ``width * height`` not matching the data; truncated or
overlong data; empty clouds; huge dimensions claimed with a few bytes; and inside valid
layouts every cloud :func:`geomodel_ros.tools.fuzz.clouds` draws (NaN/inf patterns,
magnitudes 1e-6 .. 1e9 m, degenerate sets).  They are published at most ``--rate`` per
second.  Every ``--probe-every`` messages a valid small scene (``tiny_box``) is sent and
its MarkerArray awaited: the node is alive and still models correctly.

Reported (JSON): cases; node crashes (the process exited during the run; must be 0);
probes answered / sent (each answer checked: DELETEALL first, the probe's header, finite
poses, positive finite scales); non-finite or malformed outputs in any MarkerArray (must be
0); reconstruction clouds with non-finite points (must be 0); the node's frame counters
from ``/diagnostics`` (``failed`` is the exact number of clear errors: malformed messages
and core errors the node rejected with a reason); and its log: warning lines, error lines,
tracebacks (warnings are throttled to one per kind every 5 s, so they are fewer than the
failed frames).  ``malformed_messages`` counts the messages whose layout the input adapter
rejects (checked in this process); ``core_failures`` the well-formed messages the node did
not answer on which the core fails (replayed here through ``process_cloud``: the node
skipped them as ``modeling failed``), by exception.  Exit status 0
when nothing crashed, every probe was answered, every output was finite and well-formed
and the log holds no traceback.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Sequence

from geomodel_ros.tools.paths import FASTDDS_LARGE_DATA, REPO

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # before rclpy starts DDS
os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
os.environ.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(FASTDDS_LARGE_DATA))

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import seed as hypothesis_seed  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from geomodel_ros.tools import bench_load  # noqa: E402
from geomodel_ros.tools.fuzz import clouds  # noqa: E402
from msg_adapters.diagnostics import read_status_values  # noqa: E402
from msg_adapters.header import header_of, make_header, stamp_ns  # noqa: E402
from msg_adapters.interfaces import DiagnosticArray, MarkerArray, PointCloud2  # noqa: E402
from msg_adapters.malformed import ELEMENT_DTYPES, FieldSpec, pack_points, raw_cloud  # noqa: E402
from msg_adapters.markers import marker_array_frame, marker_array_problem  # noqa: E402
from msg_adapters.pointcloud2 import (PointCloud2Error, cloud_to_scene, cloud_to_xyz,  # noqa: E402
                                      xyz_to_cloud)  # noqa: E402

__all__ = ["messages", "run", "main"]

FRAME = "camera_optical"
TOPIC = "/fuzz_node/points"
#: Reliable with a deep history on both sides (the node's ``qos_depth``): a KEEP_LAST
#: history that fills while a busy reader is behind loses samples even when reliable.
QOS_DEPTH = 1000
_RELIABLE = QoSProfile(depth=QOS_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
#: Points per fuzzed message: enough for real geometry, small enough for tens of Hz.
MAX_POINTS = 400
#: Longest wait for a probe's answer [s] (the node may first finish a large valid frame).
PROBE_TIMEOUT_S = 60.0
#: Longest wait for the node to come up [s].
STARTUP_TIMEOUT_S = 60.0
#: Stamps of fuzzed messages start here [s]; probes count from 1 (never confused).
FUZZ_STAMP_BASE_S = 1_000_000
#: Largest value of the uint32 message fields (height, width, steps, offset, count).
UINT32_MAX = 2**32 - 1
MUTATIONS = ("none", "none", "drop_xyz", "rename", "wrong_datatype", "count",
             "duplicate_name", "overlap", "offset_past_step", "flip_endianness",
             "point_step_lie", "row_step_lie", "width_height_lie", "truncate", "extend",
             "huge_dims", "empty", "zero_point_step", "no_fields")
_FLOATS = (7, 8)  # PointField.FLOAT32, FLOAT64
_NON_FLOATS = (1, 2, 3, 4, 5, 6)  # INT8 .. UINT32
_UNKNOWN = (0, 9, 42, 255)


def _base_fields(draw: Any) -> tuple[list[FieldSpec], int]:
    """Draw a valid field table: x, y, z (float32 or float64, any order) and extras."""
    code = draw(st.sampled_from(_FLOATS))
    size = ELEMENT_DTYPES[code].itemsize
    names = draw(st.permutations(["x", "y", "z"]))
    extras = draw(st.lists(st.sampled_from([("intensity", 7, 1), ("rgb", 7, 1),
                                            ("ring", 4, 1), ("normal", 7, 3), ("_", 1, 4)]),
                           max_size=3))
    fields, offset = [], 0
    for name in names:
        fields.append(FieldSpec(name, offset, code))
        offset += size
    for name, c, count in extras:
        fields.append(FieldSpec(name, offset, c, count))
        offset += ELEMENT_DTYPES[c].itemsize * count
    return fields, offset + draw(st.sampled_from((0, 0, 1, 4, 16)))  # trailing padding


def _mutate_fields(draw: Any, fields: list[FieldSpec], step: int, how: str
                   ) -> tuple[list[FieldSpec], int]:
    """Spoil the field table (``how`` in MUTATIONS); the table and point_step."""
    xyz = [i for i, f in enumerate(fields) if f.name in "xyz"]
    i = draw(st.sampled_from(xyz))
    f = fields[i]
    if how == "drop_xyz":
        fields = fields[:i] + fields[i + 1:]
    elif how == "rename":
        fields[i] = f._replace(name=draw(st.sampled_from(("X", "", "x ", "yy", "_"))))
    elif how == "wrong_datatype":
        fields[i] = f._replace(datatype=draw(st.sampled_from(_NON_FLOATS + _UNKNOWN)))
    elif how == "count":
        fields[i] = f._replace(count=draw(st.sampled_from((0, 2, 3, UINT32_MAX))))
    elif how == "duplicate_name":
        fields.append(f._replace(offset=draw(st.integers(0, step))))
    elif how == "overlap":
        j = draw(st.sampled_from(xyz))
        fields[i] = f._replace(offset=fields[j].offset + draw(st.integers(0, 3)))
    elif how == "offset_past_step":
        fields[i] = f._replace(offset=draw(st.sampled_from((step, step - 1, step + 100,
                                                           UINT32_MAX))))
    elif how == "no_fields":
        fields = []
    elif how == "zero_point_step":
        step = 0
    return fields, step


@dataclass
class FuzzMessage:
    """One drawn message and what was done to it."""

    msg: PointCloud2
    mutation: str


@st.composite
def messages(draw: Any, max_points: int = MAX_POINTS) -> FuzzMessage:
    """Draw a PointCloud2 message, valid or malformed in one of :data:`MUTATIONS` ways."""
    points, organized = draw(clouds(max_points=max_points))
    how = draw(st.sampled_from(MUTATIONS))
    if how == "empty":
        points, organized = points[:0], None
    height, width = organized if organized else (1, len(points))
    fields, step = _base_fields(draw)
    big = draw(st.booleans())
    data = pack_points(points, fields, step, big_endian=big)
    row_pad = draw(st.sampled_from((0, 0, 8)))
    if row_pad and height:  # rows padded at their end (row_step > point_step * width)
        rows = np.frombuffer(data, np.uint8).reshape(height, width * step)
        data = np.pad(rows, ((0, 0), (0, row_pad))).tobytes()
    row_step = width * step + row_pad
    fields, step = _mutate_fields(draw, fields, step, how)
    if how == "flip_endianness":
        big = not big  # declared, not written
    elif how == "point_step_lie":
        step = max(0, step + draw(st.sampled_from((-4, -1, 1, 4, 1000))))
    elif how == "row_step_lie":
        row_step = draw(st.sampled_from((0, 1, max(0, row_step - 1), row_step + 1,
                                         UINT32_MAX)))
    elif how == "width_height_lie":
        height, width = draw(st.sampled_from(((height, width + 1), (height + 1, width),
                                              (width, height), (1, max(0, width - 1)))))
    elif how == "truncate":
        data = data[:draw(st.integers(0, max(0, len(data) - 1)))]
    elif how == "extend":
        data = data + bytes(draw(st.integers(1, 64)))
    elif how == "huge_dims":
        height, width = draw(st.sampled_from(((UINT32_MAX, UINT32_MAX), (1, 2**31),
                                              (2**16, 2**16), (2**20, 1))))
        row_step = draw(st.sampled_from((width * step, row_step)))
        row_step = min(row_step, UINT32_MAX)
    msg = raw_cloud(make_header(FRAME), fields, height=height, width=width,
                    point_step=min(step, UINT32_MAX), row_step=row_step, data=data,
                    big_endian=big, is_dense=draw(st.booleans()))
    return FuzzMessage(msg, how)


def _output_problem(msg: MarkerArray) -> str | None:
    """Why a MarkerArray is not well-formed (non-finite, bad scale, mixed headers), or None."""
    frame = marker_array_frame(msg)
    if frame is None:
        return "empty MarkerArray"
    return marker_array_problem(msg, frame)


class _Peer:
    """Publishes to the node; records its MarkerArrays, reconstruction and diagnostics."""

    def __init__(self, context: Context) -> None:
        self.node = Node("fuzz_node", context=context)
        self.pub = self.node.create_publisher(PointCloud2, TOPIC, _RELIABLE)
        self.lock = threading.Lock()
        self.answered: set[int] = set()  # stamps [ns] of well-formed MarkerArrays
        self.marker_arrays = 0
        self.problems: Counter[str] = Counter()
        self.reconstructions = 0
        self.non_finite_reconstructions = 0
        self.diagnostics: dict[str, str] = {}
        self.node.create_subscription(MarkerArray, "/modeler/primitives", self._on_markers,
                                      _RELIABLE)
        self.node.create_subscription(PointCloud2, "/modeler/reconstruction",
                                      self._on_reconstruction, _RELIABLE)
        self.node.create_subscription(PointCloud2, "/modeler/segments", lambda _: None,
                                      _RELIABLE)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)

    def _on_markers(self, msg: MarkerArray) -> None:
        why = _output_problem(msg)
        with self.lock:
            self.marker_arrays += 1
            if why is not None:
                self.problems[re.sub(r"\S+/\d+", "<marker>", why)] += 1
            else:
                self.answered.add(header_of(msg.markers[0]).stamp_ns)

    def _on_reconstruction(self, msg: PointCloud2) -> None:
        try:
            finite = bool(np.isfinite(cloud_to_xyz(msg)).all())
        except PointCloud2Error:
            finite = False
        with self.lock:
            self.reconstructions += 1
            self.non_finite_reconstructions += not finite

    def _on_diag(self, msg: DiagnosticArray) -> None:
        values = read_status_values(msg, "/modeler")
        if values is not None:
            with self.lock:
                self.diagnostics = values


@dataclass
class _Run:
    """What the publishing loop saw."""

    published: int = 0
    mutations: Counter[str] = field(default_factory=Counter)
    rejected_by_adapter: int = 0  # messages the input adapter rejects (checked here)
    well_formed: dict[int, PointCloud2] = field(default_factory=dict)  # stamp [ns] -> msg
    probes_sent: int = 0
    probes_answered: int = 0
    probe_problems: list[str] = field(default_factory=list)
    crashed_after: int | None = None  # messages published when the node was found dead


class _Prober:
    """Sends the valid probe scene and waits for its well-formed answer."""

    def __init__(self, peer: _Peer, proc: Any) -> None:
        from geomodel_ros.tools.synth import render_scene

        self.peer, self.proc = peer, proc
        self.cloud = xyz_to_cloud(render_scene("tiny_box").organized, make_header(FRAME))

    def probe(self, index: int, out: _Run) -> None:
        stamp = (index + 1) * 10**9
        self.cloud.header = make_header(FRAME, stamp)
        self.peer.pub.publish(self.cloud)
        out.probes_sent += 1
        if bench_load._wait(lambda: stamp in self.peer.answered or self.proc.poll() is not None,
                            PROBE_TIMEOUT_S) and stamp in self.peer.answered:
            out.probes_answered += 1
        elif len(out.probe_problems) < 5:
            out.probe_problems.append(f"probe {index + 1} (stamp {stamp} ns) not answered "
                                      f"within {PROBE_TIMEOUT_S} s")


def _publish_all(peer: _Peer, proc: Any, cases: int, seed: int, rate: float,
                 probe_every: int) -> _Run:
    """Publish ``cases`` drawn messages (at most ``rate`` per second) with probes between."""
    out = _Run()
    prober = _Prober(peer, proc)
    period = 1.0 / rate
    tick = threading.Event()
    start = time.monotonic()

    @settings(max_examples=cases, deadline=None, database=None, derandomize=False,
              suppress_health_check=list(HealthCheck))
    @given(item=messages())
    def case(item: FuzzMessage) -> None:
        if out.crashed_after is not None:
            return
        if proc.poll() is not None:
            out.crashed_after = out.published
            return
        if out.published % probe_every == 0:
            prober.probe(out.probes_sent, out)
        item.msg.header = make_header(FRAME, (FUZZ_STAMP_BASE_S + out.published) * 10**9)
        peer.pub.publish(item.msg)
        out.published += 1
        out.mutations[item.mutation] += 1
        try:
            cloud_to_scene(item.msg)
            out.well_formed[stamp_ns(item.msg)] = item.msg
        except PointCloud2Error:
            out.rejected_by_adapter += 1
        tick.wait(max(0.0, start + out.published * period - time.monotonic()))

    hypothesis_seed(seed)(case)()  # reproducible: the same seed draws the same cases
    if out.crashed_after is None and proc.poll() is None:
        prober.probe(out.probes_sent, out)  # the node still answers after the last message
    if proc.poll() is not None and out.crashed_after is None:
        out.crashed_after = out.published
    return out


def _core_failures(well_formed: dict[int, PointCloud2], answered: set[int]) -> dict:
    """Replay the well-formed messages the node did not answer; the core's failures by kind.

    The node answers every well-formed frame it models; one it did not answer was dropped
    (a newer one arrived first) or the core failed on it (logged as ``modeling failed``).
    Replaying it here through the node's own :func:`process_cloud` (same default
    parameters, deterministic) tells which.
    """
    from geomodel_ros.core.params import ModelingParams
    from geomodel_ros.ros.processing import ModelingError, process_cloud

    params = ModelingParams()
    kinds: Counter[str] = Counter()
    for stamp, msg in well_formed.items():
        if stamp in answered:
            continue
        try:
            process_cloud(msg, params)
        except ModelingError as exc:
            kinds[re.sub(r"-?\d+", "#", str(exc))[:90]] += 1
    return {"total": sum(kinds.values()), "kinds": dict(kinds)}


def _log_counts(log_name: str) -> dict:
    """Warning / error lines and tracebacks in the node's log."""
    with open(log_name, errors="replace") as f:
        text = f.read()
    warn = re.findall(r"^\[WARN\].*?\]: (.{0,60})", text, flags=re.M)
    return {"warnings": len(warn),
            "warning_kinds": dict(Counter(re.sub(r"[\d.]+", "#", w[:40]) for w in warn)),
            "errors": len(re.findall(r"^\[ERROR\]", text, flags=re.M)),
            "tracebacks": text.count("Traceback (most recent call last)")}


def _start_node() -> tuple[subprocess.Popen, list[str], str]:
    """Start the node process on this tool's topic; its handle, command line and log file."""
    cmd = [sys.executable, "-m", "geomodel_ros.ros.node", "--ros-args", "-r", f"points:={TOPIC}",
           "-p", "qos_reliability:=reliable", "-p", f"qos_depth:={QOS_DEPTH}"]
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONPATH=os.pathsep.join(filter(None, [str(REPO),
                                                        os.environ.get("PYTHONPATH")])))
    log = tempfile.NamedTemporaryFile("w+", prefix="fuzz_node_", suffix=".log", delete=False)
    proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT, cwd=REPO)
    return proc, cmd, log.name


def _start_and_fuzz(args: argparse.Namespace) -> tuple[_Run, _Peer, int, str, list[str]]:
    """Start the node, fuzz it, stop it; the run, the peer, exit status, log, command."""
    proc, cmd, log_name = _start_node()
    context = Context()
    rclpy.init(args=[], context=context)
    peer = _Peer(context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(peer.node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        if not bench_load._wait(lambda: peer.pub.get_subscription_count() >= 1
                                and peer.node.count_publishers("/modeler/primitives") >= 1
                                or proc.poll() is not None, STARTUP_TIMEOUT_S) \
                or proc.poll() is not None:
            raise RuntimeError(f"the node did not come up (exit status {proc.poll()}); "
                               f"see {log_name}")
        run_ = _publish_all(peer, proc, args.cases, args.seed, args.rate, args.probe_every)
        bench_load._drain(peer, proc)
    finally:
        exit_status = bench_load._stop(proc)
        executor.shutdown(timeout_sec=5.0)
        spinner.join(5.0)
        peer.node.destroy_node()
        rclpy.try_shutdown(context=context)
    return run_, peer, exit_status, log_name, cmd


def run(cases: int, *, seed: int = 0, rate: float = 40.0, probe_every: int = 100) -> dict:
    """Fuzz a freshly started node with ``cases`` messages; the report (module doc)."""
    t0 = time.monotonic()
    args = argparse.Namespace(cases=cases, seed=seed, rate=rate, probe_every=probe_every)
    out, peer, exit_status, log_name, cmd = _start_and_fuzz(args)
    with peer.lock:
        diag = dict(peer.diagnostics)
        report = {
            "cases": out.published, "command": cmd,
            "node_crashes": int(out.crashed_after is not None),
            "crashed_after_messages": out.crashed_after,
            "node_exit_status_on_sigint": exit_status,
            "probes_sent": out.probes_sent, "probes_answered": out.probes_answered,
            "probe_problems": out.probe_problems,
            "marker_arrays": peer.marker_arrays,
            "malformed_outputs": sum(peer.problems.values()),
            "malformed_output_kinds": dict(peer.problems),
            "reconstructions": peer.reconstructions,
            "non_finite_reconstructions": peer.non_finite_reconstructions,
        }
    report["frames"] = {k: int(diag.get(f"frames_{k}", -1))
                        for k in ("received", "processed", "dropped", "failed")}
    report["clear_errors"] = report["frames"]["failed"]
    report["malformed_messages"] = out.rejected_by_adapter
    report["well_formed_messages"] = len(out.well_formed)
    report["core_failures"] = _core_failures(out.well_formed, peer.answered)
    report["log"] = {"file": log_name, **_log_counts(log_name)}
    report["mutations"] = dict(out.mutations)
    report["duration_s"] = round(time.monotonic() - t0, 1)
    report["ok"] = (report["node_crashes"] == 0 and out.probes_answered == out.probes_sent
                    and report["malformed_outputs"] == 0
                    and report["non_finite_reconstructions"] == 0
                    and report["log"]["tracebacks"] == 0)
    return report


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m geomodel_ros.tools.fuzz_node",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rate", type=float, default=40.0, help="messages per second, at most")
    ap.add_argument("--probe-every", type=int, default=100,
                    help="send a valid probe scene every this many messages")
    ap.add_argument("--json", help="write the report here too")
    args = ap.parse_args(argv)
    if args.cases < 1 or args.rate <= 0 or args.probe_every < 1:
        ap.error("--cases and --probe-every must be >= 1, --rate > 0")
    report = run(args.cases, seed=args.seed, rate=args.rate, probe_every=args.probe_every)
    text = json.dumps(report, indent=1, default=float)
    print(text)
    if args.json:
        with open(args.json, "w") as f:
            f.write(text)
    return 0 if report["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
