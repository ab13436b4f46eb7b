"""The ``modeler`` node with real rclpy pub/sub in one process (private Context per test).

The core is the real :func:`geomodel_ros.core.modeling.model_scene`, wrapped by
:class:`CoreProbe` and passed to the node (``ModelerNode(model_scene=...)``); the probe
records its calls and can hold the worker (newest-frame-wins test) or fail a frame.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.exceptions import ParameterException
from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker, MarkerArray

from geomodel_msgs.msg import Primitive as PrimitiveMsg
from geomodel_msgs.msg import PrimitiveArray

from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.primitives import ModelingResult, Primitive
from geomodel_ros.ros import node as node_module
from geomodel_ros.ros.node import NODE_PARAMETERS, ModelerNode
from geomodel_ros.ros.processing import ObjectTracking, process_cloud
from geomodel_ros.core.params import PARAMETERS, ModelingParams, ParameterError
from geomodel_ros.tools.synth import NoiseModel, render_scene
from msg_adapters.diagnostics import read_status_values
from msg_adapters.pointcloud2 import cloud_to_fields, cloud_to_xyz_and_mask, xyz_to_cloud
from ros_helpers import FRAME, RELIABLE, TIMEOUT, scene_cloud, wait_until





class Collector:
    """Subscription that stores messages and lets the test wait for them."""

    def __init__(self, node: Node, msg_type, topic: str, qos=RELIABLE) -> None:
        self.msgs: list = []
        self._cond = threading.Condition()
        self.sub = node.create_subscription(msg_type, topic, self._on_msg, qos)

    def _on_msg(self, msg) -> None:
        with self._cond:
            self.msgs.append(msg)
            self._cond.notify_all()

    def wait(self, n: int = 1, timeout: float = TIMEOUT):
        with self._cond:
            if not self._cond.wait_for(lambda: len(self.msgs) >= n, timeout):
                pytest.fail(f"timed out after {timeout} s waiting for message #{n} on "
                            f"{self.sub.topic_name} (got {len(self.msgs)})")
            return self.msgs[n - 1]

    def __len__(self) -> int:
        with self._cond:
            return len(self.msgs)


class CoreProbe:
    """Wraps ``model_scene``: records calls, can hold the worker or fail frames."""

    def __init__(self, inner) -> None:
        self.inner = inner
        self.calls: list[dict] = []
        self.gate = threading.Event()
        self.gate.set()
        self.entered = threading.Semaphore(0)
        self.fail_next = 0

    def __call__(self, points, params, *, organized_shape=None):
        self.calls.append({"n": len(points), "params": params,
                           "organized_shape": organized_shape, "dtype": points.dtype})
        self.entered.release()
        if not self.gate.wait(TIMEOUT):
            raise RuntimeError("test gate never opened")
        if self.fail_next:
            self.fail_next -= 1
            raise RuntimeError("injected core failure")
        return self.inner(points, params, organized_shape=organized_shape)


@pytest.fixture
def core():
    return CoreProbe(model_scene)


class Harness:
    """The node under test + a peer node publishing clouds and collecting outputs."""

    def __init__(self, context: Context, core: CoreProbe,
                 overrides: dict | None = None, threads: int = 1,
                 own_executor: bool = False) -> None:
        values = {"qos_reliability": "reliable", "qos_depth": 5, **(overrides or {})}
        self.node = ModelerNode(
            context=context, model_scene=core,
            cli_args=["--ros-args", "-r", "points:=/test/points"],
            parameter_overrides=[Parameter(k, value=v) for k, v in values.items()],
        )
        self.peer = Node("peer", context=context)
        self.pub = self.peer.create_publisher(PointCloud2, "/test/points", RELIABLE)
        self.markers = Collector(self.peer, MarkerArray, "/modeler/primitives")
        self.segments = Collector(self.peer, PointCloud2, "/modeler/segments")
        self.recon = Collector(self.peer, PointCloud2, "/modeler/reconstruction")
        self.objects = Collector(self.peer, PrimitiveArray, "/modeler/objects")
        # threads=1 is the node's own executor (``main``): ~/detect must not block it.
        self.executor = SingleThreadedExecutor(context=context) if threads == 1 else \
            MultiThreadedExecutor(num_threads=threads, context=context)
        # own_executor: the node alone in a single-threaded executor, as in ``main`` (the
        # peer's traffic then does not wake the node's executor).
        self.node_executor = SingleThreadedExecutor(context=context) if own_executor \
            else self.executor
        self.node_executor.add_node(self.node)
        self.executor.add_node(self.peer)
        self.threads = [threading.Thread(target=e.spin, daemon=True)
                        for e in {id(self.executor): self.executor,
                                  id(self.node_executor): self.node_executor}.values()]
        for thread in self.threads:
            thread.start()
        wait_until(lambda: self.pub.get_subscription_count() >= 1
                   and all(c.sub.get_publisher_count() >= 1
                           for c in (self.markers, self.segments, self.recon, self.objects)),
                   "publishers and subscriptions to match")

    def publish_and_wait_received(self, msg: PointCloud2) -> None:
        before = self.node.stats().received
        self.pub.publish(msg)
        wait_until(lambda: self.node.stats().received > before, "the node to receive a frame")

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=10.0)
        if self.node_executor is not self.executor:
            self.node_executor.shutdown(timeout_sec=10.0)
        for thread in self.threads:
            thread.join(10.0)
        self.node.destroy_node()
        self.peer.destroy_node()


@pytest.fixture
def make_harness(context, core):
    made: list[Harness] = []

    def make(threads: int = 1, own_executor: bool = False, **overrides) -> Harness:
        h = Harness(context, core, overrides, threads, own_executor)
        made.append(h)
        return h

    yield make
    for h in made:
        h.close()


def shapes(array: MarkerArray) -> dict[str, list[Marker]]:
    out: dict[str, list[Marker]] = {}
    for m in array.markers:
        if m.action == Marker.ADD and m.ns != "labels":
            out.setdefault(m.ns, []).append(m)
    return out


def mm(*values) -> np.ndarray:
    return 1000.0 * np.array(values, dtype=float)


# --------------------------------------------------------------------------- end to end
def _size_mm(m: Marker) -> dict[str, float]:
    """Dimensions [mm] shown by a shape marker, named as in Primitive.dimensions."""
    s = 1000.0 * np.array([m.scale.x, m.scale.y, m.scale.z])
    if m.type == Marker.TRIANGLE_LIST:  # cone mesh in the marker's local frame
        local = 1000.0 * np.array([[p.x, p.y, p.z] for p in m.points])
        return {"radius": float(np.hypot(local[:, 0], local[:, 1]).max()),
                "height": float(np.ptp(local[:, 2]))}
    if m.ns == "plane":
        return {"length": s[0], "width": s[1]}
    if m.ns == "cylinder":
        return {"radius": s[0] / 2, "height": s[2]}
    if m.ns == "sphere":
        return {"radius": s[0] / 2}
    return {"length": s[0], "width": s[1], "height": s[2]}


def test_scene_is_modeled_and_published_with_the_input_header(make_harness, core):
    h = make_harness()
    scene = render_scene("scene3")
    cloud = scene_cloud("scene3", sec=1700000000, nanosec=123456789)
    h.pub.publish(cloud)
    markers = h.markers.wait()

    assert markers.markers[0].action == Marker.DELETEALL
    for m in markers.markers:
        assert m.header.frame_id == FRAME
        assert (m.header.stamp.sec, m.header.stamp.nanosec) == (1700000000, 123456789)
    found = shapes(markers)
    assert {"plane", "cuboid", "cylinder", "cone", "sphere"} <= set(found)
    # every ground-truth object has a marker of its type, at its place, of its size
    for gt in scene.objects:
        candidates = [m for m in found.get(gt.type, [])
                      if np.linalg.norm(_position(m) - gt.center) < 0.01]
        assert len(candidates) == 1, f"no {gt.type} marker near {gt.center}"
        got = _size_mm(candidates[0])
        want = {k: 1000.0 * v for k, v in gt.dimensions.items()}
        tol = 10.0 if gt.type == "plane" else 4.0
        if gt.type == "cuboid":  # the modeler may name the box's axes differently
            assert sorted(got.values()) == pytest.approx(sorted(want.values()), abs=tol)
        else:
            assert got == pytest.approx(want, abs=tol), gt.type
    labels = [m for m in markers.markers if m.ns == "labels"]
    assert any(m.text.startswith("cylinder r=50.0 h=60.0") for m in labels), \
        [m.text for m in labels]

    # the core got every row of the organized cloud as float64, and its image shape
    assert core.calls[-1]["n"] == 624 * 1104
    assert core.calls[-1]["dtype"] == np.float64
    assert core.calls[-1]["organized_shape"] == (624, 1104)

    segments = h.segments.wait()
    recon = h.recon.wait()
    for msg in (segments, recon):
        assert msg.header.frame_id == FRAME
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1700000000, 123456789)
    # segments keep the input's layout, so labels are pixel-aligned
    assert (segments.height, segments.width) == (624, 1104)
    seg_ids = cloud_to_fields(segments, ["object_id"], keep_organized=True)["object_id"]
    assert np.all(seg_ids[~scene.valid_mask] == -1)
    object_ids = {m.id for ms in found.values() for m in ms}
    assert set(np.unique(seg_ids[seg_ids >= 0]).tolist()) == object_ids
    rec_pts, rec_mask = cloud_to_xyz_and_mask(recon)
    rec_ids = cloud_to_fields(recon, ["object_id"], mask=rec_mask)["object_id"]
    modeled = {m.id for ns, ms in found.items() if ns != "unknown" for m in ms}
    assert set(np.unique(rec_ids).tolist()) == modeled
    # the reconstructed cylinders lie on their markers' surfaces (caps inside)
    for cyl in found["cylinder"]:
        axis = _rot(cyl)[:, 2]
        q = rec_pts[rec_ids == cyl.id] - _position(cyl)
        radial = np.linalg.norm(q - np.outer(q @ axis, axis), axis=1)
        assert radial.max() == pytest.approx(cyl.scale.x / 2, abs=1e-3)
        assert np.abs(q @ axis).max() == pytest.approx(cyl.scale.z / 2, abs=1e-3)
    # processed counts a frame once all its outputs are out (the clouds go last)
    wait_until(lambda: h.node.stats().processed == 1, "the frame to be processed")
    stats = h.node.stats()
    assert (stats.processed, stats.failed, stats.dropped) == (1, 0, 0)


def _position(m: Marker) -> np.ndarray:
    return np.array([m.pose.position.x, m.pose.position.y, m.pose.position.z])


def _rot(m: Marker) -> np.ndarray:
    o = m.pose.orientation
    x, y, z, w = o.x, o.y, o.z, o.w
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def test_empty_cloud_clears_markers_without_calling_the_core(make_harness, core):
    h = make_harness()
    empty = xyz_to_cloud(np.full((4, 5, 3), np.nan), Header(stamp=Time(sec=7), frame_id=FRAME))
    h.pub.publish(empty)
    markers = h.markers.wait()
    assert [m.action for m in markers.markers] == [Marker.DELETEALL]
    assert markers.markers[0].header.stamp.sec == 7
    assert h.recon.wait().width == 0
    segments = h.segments.wait()
    assert (segments.height, segments.width) == (4, 5)
    assert np.all(cloud_to_fields(segments, ["object_id"])["object_id"] == -1)
    assert core.calls == []


# --------------------------------------------------------------------------- robustness
def test_malformed_cloud_is_skipped_and_the_node_keeps_running(make_harness, core, capfd):
    h = make_harness()
    good = scene_cloud("tiny_box", sec=5)
    bad = scene_cloud("tiny_box", sec=4)
    bad.data = bad.data[:-bad.point_step]  # data length != row_step * height
    h.publish_and_wait_received(bad)
    wait_until(lambda: h.node.stats().failed == 1, "the malformed frame to be counted")
    no_z = scene_cloud("tiny_box", sec=4)
    no_z.fields = [f for f in no_z.fields if f.name != "z"]
    h.publish_and_wait_received(no_z)
    wait_until(lambda: h.node.stats().failed == 2, "the frame without z to be counted")
    h.pub.publish(good)
    markers = h.markers.wait()
    assert markers.markers[0].header.stamp.sec == 5
    assert {"plane", "cuboid"} <= set(shapes(markers))
    assert len(core.calls) == 1
    wait_until(lambda: h.node.stats().processed == 1, "the good frame to be processed")
    log = capfd.readouterr().err
    assert "skipping malformed PointCloud2" in log and "expected row_step*height" in log
    # throttled: the second malformed frame within WARN_THROTTLE_S is not logged again
    assert log.count("skipping malformed PointCloud2") == 1


def test_core_failure_is_skipped_and_the_next_frame_is_modeled(make_harness, core, capfd):
    h = make_harness()
    core.fail_next = 1
    h.publish_and_wait_received(scene_cloud("tiny_box", sec=1))
    wait_until(lambda: h.node.stats().failed == 1, "the failed frame to be counted")
    h.pub.publish(scene_cloud("tiny_box", sec=2))
    markers = h.markers.wait()
    assert markers.markers[0].header.stamp.sec == 2
    assert len(h.markers) == 1
    wait_until(lambda: h.node.stats().processed == 1, "the second frame to be processed")
    assert h.node.stats().failed == 1
    assert "RuntimeError: injected core failure" in capfd.readouterr().err


def test_newest_frame_wins_and_drops_are_counted(make_harness, core, capfd):
    h = make_harness()
    core.gate.clear()  # hold the worker inside the core
    h.publish_and_wait_received(scene_cloud("tiny_box", sec=1))
    assert core.entered.acquire(timeout=TIMEOUT), "worker never reached the core"
    for sec in (2, 3, 4):  # 2 waits in the mailbox, 3 replaces it, 4 replaces 3
        h.publish_and_wait_received(scene_cloud("tiny_box", sec=sec))
    stats = h.node.stats()
    assert (stats.received, stats.dropped, stats.processed) == (4, 2, 0)
    log = capfd.readouterr().err
    assert log.count("input is faster than processing") == 1  # throttled
    core.gate.set()
    h.markers.wait(2)
    wait_until(lambda: h.node.stats().processed == 2, "both frames to be processed")
    assert [m.markers[0].header.stamp.sec for m in h.markers.msgs] == [1, 4]
    assert len(core.calls) == 2
    stats = h.node.stats()
    assert stats.dropped == 2 and stats.failed == 0
    assert stats.last_latency_s > 0 and stats.last_timing["total_s"] > 0


# --------------------------------------------------------------------------- parameters
def test_every_parameter_is_declared_with_descriptor(make_harness):
    node = make_harness().node
    for spec in PARAMETERS:
        assert node.get_parameter(spec.name).value == spec.default
        d = node.describe_parameter(spec.name)
        assert spec.description in d.description
        if spec.unit and spec.unit not in ("1", "count"):
            assert f"[{spec.unit}]" in d.description
        if spec.type is float:
            assert d.floating_point_range[0].from_value == spec.low
            assert d.floating_point_range[0].to_value == spec.high
        elif spec.type is int:
            r = d.integer_range[0]
            assert (r.from_value, r.to_value, r.step) == (spec.low, spec.high, 1)
    for p in NODE_PARAMETERS:
        assert node.has_parameter(p.name)
    assert node.describe_parameter("qos_depth").read_only
    assert "best_effort" in node.describe_parameter("qos_reliability").additional_constraints
    assert node.describe_parameter("input").read_only
    assert node.modeling_params == ModelingParams()


def test_parameter_sets_are_validated_and_applied_from_the_next_frame(make_harness, core):
    h = make_harness()
    node = h.node

    (ok,) = node.set_parameters([Parameter("voxel_size", value=0.004)])
    assert ok.successful
    assert node.modeling_params.voxel_size == 0.004

    rejected = [
        (Parameter("voxel_size", value=5.0), "out of range"),
        (Parameter("voxel_size", value="fine"), "Wrong parameter type"),
        (Parameter("voxel_size", value=math.nan), "out of range"),
        (Parameter("min_radius", value=3.0), "min_radius"),  # >= max_radius (2.0)
        (Parameter("developable_curvature_ratio", value=0.5), "sphere_curvature_ratio"),
        (Parameter("qos_depth", value=3), "read-only"),
        (Parameter("normal_neighbors", value=16.5), "Wrong parameter type"),
    ]
    for param, expected in rejected:
        (result,) = node.set_parameters([param])
        assert not result.successful, param.name
        assert expected in result.reason, result.reason
    assert node.modeling_params == ModelingParams(voxel_size=0.004)
    assert node.get_parameter("voxel_size").value == 0.004
    assert node.get_parameter("min_radius").value == 0.002

    # both radii in one atomic set are consistent
    result = node.set_parameters_atomically([Parameter("min_radius", value=3.0),
                                             Parameter("max_radius", value=5.0)])
    assert result.successful
    assert (node.modeling_params.min_radius, node.modeling_params.max_radius) == (3.0, 5.0)

    # the next frame is modeled with exactly the accepted parameters
    h.pub.publish(scene_cloud("tiny_box"))
    h.markers.wait()
    assert core.calls[-1]["params"] == ModelingParams(voxel_size=0.004, min_radius=3.0,
                                                      max_radius=5.0)


def test_output_switches_take_effect(make_harness):
    h = make_harness()
    results = h.node.set_parameters([Parameter("publish_segments", value=False),
                                     Parameter("publish_reconstruction", value=False)])
    assert all(r.successful for r in results)
    h.pub.publish(scene_cloud("tiny_box"))
    h.markers.wait()
    wait_until(lambda: h.node.stats().processed == 1, "the frame to be processed")
    assert len(h.segments) == 0 and len(h.recon) == 0


@pytest.mark.parametrize("overrides, error, match", [
    ({"min_radius": 3.0}, ParameterError, "min_radius"),
    ({"qos_reliability": "sometimes"}, ParameterError, "qos_reliability"),
    ({"input": "rgb"}, ParameterError, r"'input' = 'rgb' is not allowed; use one of: "
                                       r"points, depth"),
    ({"voxel_size": 5.0}, ParameterException, "out of range"),
    ({"normal_neighbors": 1.5}, ParameterException, "normal_neighbors"),
])
def test_invalid_initial_parameters_raise(context, overrides, error, match):
    with pytest.raises(error, match=match):
        ModelerNode(context=context,
                    parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()])


def test_initial_parameters_may_move_both_radii(context):
    node = ModelerNode(context=context, parameter_overrides=[
        Parameter("min_radius", value=3.0), Parameter("max_radius", value=5.0)])
    try:
        assert (node.modeling_params.min_radius, node.modeling_params.max_radius) == (3.0, 5.0)
    finally:
        node.destroy_node()


def test_topics_qos_and_namespace(context):
    node = ModelerNode(context=context, namespace="/robot")
    try:
        (subscription,) = node._inputs
        assert subscription.subscription.topic_name == "/robot/points"
        assert node._pub_markers.topic_name == "/robot/modeler/primitives"
        assert node._pub_segments.topic_name == "/robot/modeler/segments"
        assert node._pub_reconstruction.topic_name == "/robot/modeler/reconstruction"
        # qos_reliability auto without any publisher yet: best effort (matches any)
        qos = subscription.subscription.qos_profile
        assert qos.reliability == ReliabilityPolicy.BEST_EFFORT and qos.depth == 1
        assert node.input_reliability == {"/robot/points": "best_effort"}
    finally:
        node.destroy_node()


def test_diagnostics_report_counters(make_harness):
    h = make_harness()
    diag = Collector(h.peer, DiagnosticArray, "/diagnostics", qos=10)
    msg = diag.wait(timeout=10.0)
    (status,) = [s for s in msg.status if s.hardware_id == "/modeler"]
    values = {kv.key: kv.value for kv in status.values}
    assert {"rate_hz", "frames_received", "frames_dropped", "frames_failed",
            "last_latency_s"} <= set(values)
    assert values["frames_dropped"] == "0"


# --------------------------------------------------------------------------- tracked ids
#: Range noise of the tracked-id tests [m at 0.5 m]: every frame differs, yet the core's
#: segmentation of the 160 x 120 scenes stays the same (at 1 mm the cone of tiny_shapes
#: merges with the desk in some frames: a different object set, not a tracking matter).
TRACK_NOISE = NoiseModel(sigma_at_0_5m=0.0003)


def _noisy_cloud(name: str, seed: int, sec: int, *, remove: str | None = None) -> PointCloud2:
    """Render ``name`` with fresh sensor noise.

    ``remove``: the pixels of that ground-truth type become NaN (the object left the scene).
    """
    scene = render_scene(name, noise=TRACK_NOISE, rng=seed)
    points = scene.organized.copy()
    if remove is not None:
        (gone,) = [o.id for o in scene.objects if o.type == remove]
        points[scene.label_image == gone] = np.nan
    return xyz_to_cloud(points, Header(stamp=Time(sec=sec), frame_id=FRAME))


def _process(h: Harness, cloud: PointCloud2) -> PrimitiveArray:
    """Publish one frame, wait until it is processed (no drops), return its objects."""
    before = h.node.stats().processed
    h.publish_and_wait_received(cloud)
    wait_until(lambda: h.node.stats().processed > before, "the frame to be processed")
    msg = h.objects.wait(before + 1)
    assert msg.header.stamp.sec == cloud.header.stamp.sec
    return msg


def _ids_by_type(msg: PrimitiveArray) -> dict[int, int]:
    return {p.id: p.type for p in msg.primitives}


def test_static_noisy_scene_keeps_every_id(make_harness):
    h = make_harness()
    clouds = [_noisy_cloud("tiny_shapes", seed, 10 + seed) for seed in range(10)]
    assert not np.array_equal(cloud_to_xyz_and_mask(clouds[0])[0],
                              cloud_to_xyz_and_mask(clouds[1])[0])  # the noise differs
    frames = [_process(h, c) for c in clouds]
    first = _ids_by_type(frames[0])
    assert {PrimitiveMsg.PLANE, PrimitiveMsg.CUBOID, PrimitiveMsg.SPHERE,
            PrimitiveMsg.CYLINDER} <= set(first.values())
    for msg in frames[1:]:
        assert _ids_by_type(msg) == first
    markers = list(h.markers.msgs)
    assert markers[0].markers[0].action == Marker.DELETEALL  # start-up only
    for array in markers:
        assert all(m.action != Marker.DELETE for m in array.markers)
    for array in markers[1:]:
        assert all(m.action == Marker.ADD for m in array.markers)
        assert {m.id for m in array.markers if m.ns != "labels"} == set(first)


def test_removed_object_is_deleted_after_max_missed_frames(make_harness):
    h = make_harness(tracking_max_missed=2)
    full = _process(h, _noisy_cloud("tiny_shapes", 0, 1))
    (sphere,) = [p.id for p in full.primitives if p.type == PrimitiveMsg.SPHERE]
    n_markers = len(h.markers)
    for k in range(3):  # missed 1, 2 (kept), 3 > max_missed (retired)
        msg = _process(h, _noisy_cloud("tiny_shapes", 1 + k, 2 + k, remove="sphere"))
        assert sphere not in _ids_by_type(msg)
        assert set(_ids_by_type(msg)) == set(_ids_by_type(full)) - {sphere}
        array = h.markers.wait(n_markers + k + 1)
        deletes = {(m.ns, m.id) for m in array.markers if m.action == Marker.DELETE}
        if k < 2:
            assert deletes == set()
        else:
            assert deletes == {("sphere", sphere), ("labels", sphere)}
        assert all(m.action != Marker.DELETEALL for m in array.markers)
    # back in the scene: a new id, never the retired one
    back = _process(h, _noisy_cloud("tiny_shapes", 9, 9))
    (again,) = [p.id for p in back.primitives if p.type == PrimitiveMsg.SPHERE]
    assert again != sphere and again > max(_ids_by_type(full))


def test_without_tracking_ids_are_segment_labels_and_markers_start_with_deleteall(
        make_harness):
    h = make_harness(tracking=False)
    for sec in (1, 2):
        msg = _process(h, _noisy_cloud("tiny_box", sec, sec))
        assert h.markers.wait(sec).markers[0].action == Marker.DELETEALL
        labels = cloud_to_fields(h.segments.wait(sec), ["object_id"])["object_id"]
        assert set(_ids_by_type(msg)) == set(np.unique(labels[labels >= 0]).tolist())


def test_tracking_parameters_are_declared_and_validated(make_harness):
    h = make_harness(tracking_smoothing=0.5)
    assert h.node.tracker_config.smoothing == 0.5
    d = h.node.describe_parameter("tracking_max_missed")
    assert (d.integer_range[0].from_value, d.integer_range[0].to_value) == (0, 100000)
    (bad,) = h.node.set_parameters([Parameter("tracking_smoothing", value=1.5)])
    assert not bad.successful
    (bad,) = h.node.set_parameters([Parameter("expected_rate_min", value=200.0)])  # > max
    assert not bad.successful and "expected_rate_max" in bad.reason
    (ok,) = h.node.set_parameters([Parameter("tracking_max_missed", value=7)])
    assert ok.successful and h.node.tracker_config.max_missed == 7
    assert h.node.tracker_config.smoothing == 0.5


# --------------------------------------------------------------------------- on demand
@pytest.mark.parametrize("threads", [1, 3])
def test_detect_processes_exactly_one_frame_when_not_continuous(make_harness, core, threads):
    # With one executor thread (the node's own), the frame published while the call waits
    # must still be received: a blocking ~/detect callback would deadlock here.
    h = make_harness(threads=threads, continuous=False)
    for sec in (1, 2):
        h.publish_and_wait_received(_noisy_cloud("tiny_box", sec, sec))
    assert h.node.stats().ignored == 2 and core.calls == []

    client = h.peer.create_client(Trigger, "/modeler/detect")
    assert client.wait_for_service(timeout_sec=TIMEOUT)
    future = client.call_async(Trigger.Request())
    wait_until(lambda: h.node._detect_pending, "the request to reach the node")
    h.publish_and_wait_received(_noisy_cloud("tiny_box", 3, 3))
    wait_until(future.done, "the detect answer")
    answer = future.result()
    assert answer.success, answer.message
    assert "cuboid" in answer.message and "3.000000000" in answer.message
    for sec in (4, 5):
        h.publish_and_wait_received(_noisy_cloud("tiny_box", sec, sec))
    s = h.node.stats()
    assert (s.processed, s.ignored, len(core.calls)) == (1, 4, 1)
    assert [m.header.stamp.sec for m in h.objects.msgs] == [3]


@pytest.mark.parametrize("threads", [1, 3])
def test_detect_times_out_without_a_frame(make_harness, threads):
    h = make_harness(threads=threads, continuous=False, detect_timeout=0.2)
    client = h.peer.create_client(Trigger, "/modeler/detect")
    assert client.wait_for_service(timeout_sec=TIMEOUT)
    future = client.call_async(Trigger.Request())
    wait_until(future.done, "the detect answer")
    assert not future.result().success and "detect_timeout" in future.result().message
    assert h.node._detect_pending == []


def test_waiting_detect_is_resumed_per_wake_up_not_spun(make_harness, monkeypatch):
    # The waiting call is resumed once per executor wake-up: with no input for 1.5 s that
    # is the 1 Hz diagnostics timer and its own timeout timer, a handful of times; an
    # executor that polled it in a loop would resume it thousands of times.
    resumed = []

    class CountingWake:
        def __await__(self):
            resumed.append(time.monotonic())
            yield

    monkeypatch.setattr(node_module, "_NextWake", CountingWake)
    h = make_harness(threads=1, continuous=False, detect_timeout=1.5)
    client = h.peer.create_client(Trigger, "/modeler/detect")
    assert client.wait_for_service(timeout_sec=TIMEOUT)
    called_at = time.monotonic()
    future = client.call_async(Trigger.Request())
    wait_until(future.done, "the detect answer")
    assert time.monotonic() - called_at >= 1.5  # it did wait for its timeout
    assert not future.result().success and "detect_timeout" in future.result().message
    assert 1 <= len(resumed) <= 20, len(resumed)


def test_detect_answer_wakes_a_waiting_call_at_once(make_harness, core):
    # The worker's outcome wakes the node's executor: the answer does not wait for its next
    # wake-up (the 1 Hz timer cancelled, the timeout an hour: nothing else would wake it).
    h = make_harness(own_executor=True, continuous=False, detect_timeout=3600.0)
    h.node._diag_timer.cancel()
    client = h.peer.create_client(Trigger, "/modeler/detect")
    assert client.wait_for_service(timeout_sec=TIMEOUT)
    future = client.call_async(Trigger.Request())
    wait_until(lambda: h.node._detect_pending, "the request to reach the node")
    core.gate.clear()  # the frame stays in the core until the executor is idle again
    h.publish_and_wait_received(_noisy_cloud("tiny_box", 7, 7))
    assert core.entered.acquire(timeout=TIMEOUT)
    time.sleep(0.3)  # the executor has resumed the call once (not done) and waits again
    core.gate.set()
    wait_until(future.done, "the detect answer")
    assert future.result().success and "7.000000000" in future.result().message


# --------------------------------------------------------------------------- diagnostics
def _status(msg: DiagnosticArray):
    (status,) = [s for s in msg.status if s.hardware_id == "/modeler"]
    return status


def _now_cloud(h: Harness, name: str = "tiny_box") -> PointCloud2:
    cloud = scene_cloud(name)
    cloud.header.stamp = h.node.get_clock().now().to_msg()
    return cloud


def test_diagnostics_stay_ok_when_frames_are_dropped(make_harness, core):
    h = make_harness(expected_rate_min=0.0)  # the rate of a test is no camera's
    diag = Collector(h.peer, DiagnosticArray, "/diagnostics", qos=10)
    core.gate.clear()  # hold the worker: the frames behind it replace each other
    h.publish_and_wait_received(_now_cloud(h))
    assert core.entered.acquire(timeout=TIMEOUT)
    for _ in range(3):
        h.publish_and_wait_received(_now_cloud(h))
    core.gate.set()
    wait_until(lambda: h.node.stats().processed == 2, "the held and the newest frame")
    n = len(diag)
    msg = diag.wait(n + 1)  # a report after both were processed
    values = read_status_values(msg, "/modeler")
    assert (values["frames_dropped"], values["frames_processed"]) == ("2", "2")
    # every report, including the first one that saw the drops, is OK
    for report in list(diag.msgs):
        assert _status(report).level == b"\x00", _status(report).message


def test_diagnostics_warn_on_stale_results_and_a_low_rate(make_harness):
    h = make_harness(expected_rate_min=0.0, max_result_age=5.0)
    diag = Collector(h.peer, DiagnosticArray, "/diagnostics", qos=10)
    _process(h, scene_cloud("tiny_box", sec=42))  # stamped 1970: the result lags
    msg = diag.wait(len(diag) + 1)
    assert _status(msg).level == b"\x01" and "old" in _status(msg).message
    # a current frame, but fewer frames than expected per second
    h.node.set_parameters([Parameter("max_result_age", value=0.0),
                           Parameter("expected_rate_min", value=50.0)])
    _process(h, _now_cloud(h))
    msg = diag.wait(len(diag) + 1)
    assert _status(msg).level == b"\x01" and "rate" in _status(msg).message


def test_tracking_switched_off_and_on_never_reuses_an_id(make_harness):
    h = make_harness()
    first = _ids_by_type(_process(h, _noisy_cloud("tiny_box", 0, 1)))
    h.node.set_parameters([Parameter("tracking", value=False)])
    _process(h, _noisy_cloud("tiny_box", 1, 2))
    h.node.set_parameters([Parameter("tracking", value=True)])
    again = _ids_by_type(_process(h, _noisy_cloud("tiny_box", 2, 3)))
    assert sorted(again.values()) == sorted(first.values())
    assert min(again) > max(first)  # fresh ids after the restart of tracking
    assert h.markers.wait(3).markers[0].action == Marker.DELETEALL  # markers restart too


def test_support_planes_are_published_under_the_tracked_ids():
    """Segment labels 5 (desk) and 6 (box) become track ids 0 and 1; the support follows."""
    desk = Primitive(5, "plane", np.array([0.0, 0.1, 0.8]), np.diag([1.0, -1.0, -1.0]),
                     {"length": 0.6, "width": 0.4}, 900, 0.001)
    box = Primitive(6, "cuboid", np.array([0.0, 0.05, 0.78]), np.eye(3),
                    {"length": 0.1, "width": 0.1, "height": 0.05}, 300, 0.001)
    normal = np.array([0.0, -0.6, -0.8])

    def stand_in(points, params, *, organized_shape=None):
        del params, organized_shape
        result = ModelingResult([desk, box], {}, supports={5: (normal, 0.7), 9: (normal, 0.1)})
        return np.full(len(points), 5), result

    tracking = ObjectTracking()
    for sec in (1, 2):
        frame = process_cloud(scene_cloud("tiny_box", sec=sec), ModelingParams(),
                              model_scene=stand_in, tracking=tracking)
        assert [(p.id, p.type) for p in frame.objects.primitives] == [
            (0, PrimitiveMsg.PLANE), (1, PrimitiveMsg.CUBOID)]
        (support,) = frame.objects.support_surfaces  # label 9 is no published object
        assert support.id == 0
        assert list(support.plane.coef) == pytest.approx([0.0, -0.6, -0.8, 0.7])


def test_destroy_waits_for_the_reliable_publishers_acknowledgements_within_a_bound(
        context, monkeypatch):
    # The process crashed at exit inside destroy_publisher (a message still in flight is the
    # suspected cause); destroy_node first waits, within ACK_TIMEOUT_S in all, for each
    # publisher's data to be acknowledged.
    from rclpy.publisher import Publisher

    waits = []

    def acked(self, timeout):
        waits.append((self.topic_name, timeout.nanoseconds * 1e-9))
        return True

    monkeypatch.setattr(Publisher, "wait_for_all_acked", acked)
    node = ModelerNode(context=context)
    topics = {pub.topic_name for pub in node.publishers}
    node.destroy_node()
    assert {topic for topic, _ in waits} == topics
    assert all(0.0 < left <= node_module.ACK_TIMEOUT_S for _, left in waits), waits
