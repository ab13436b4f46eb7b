"""Issue 6, part 2: the running ``modeler`` node never dies and never lies.

Real rclpy pub/sub in one process with a private ``Context`` per test, the real core, and
conditions with timeouts instead of fixed sleeps (the only timed waits pace a publisher).

* A burst of malformed and degenerate clouds interleaved with good ones: the node keeps
  running, accounts for every frame, and models the next good frame correctly.
* Rejected parameter sets change nothing: same parameters, same markers for the same cloud.
* Input faster than the node can model (frames arriving while one is in progress; the
  core is held at a gate, so the outcome does not depend on timing): every frame is
  accounted for, only the newest waiting frame is modeled, in stamp order (no queue), no
  failures, well-formed outputs.  Rates, latency and memory under sustained load are
  measured by ``python -m geomodel_ros.tools.bench_load``, not asserted here.
"""

from __future__ import annotations

import array
import math
import threading

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from builtin_interfaces.msg import Time
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header
from visualization_msgs.msg import Marker, MarkerArray

from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import PARAMETERS
from geomodel_ros.ros.node import ModelerNode
from geomodel_ros.tools.synth import render_scene
from msg_adapters.pointcloud2 import xyz_to_cloud
from ros_helpers import FRAME, RELIABLE, TIMEOUT, wait_until
from ros_helpers import scene_cloud as _scene_cloud


# --------------------------------------------------------------------------- plumbing


class MarkerLog:
    """Every MarkerArray in arrival order."""

    def __init__(self, node: Node, topic: str) -> None:
        self.items: list[MarkerArray] = []
        self._cond = threading.Condition()
        self.sub = node.create_subscription(MarkerArray, topic, self._on, RELIABLE)

    def _on(self, msg: MarkerArray) -> None:
        with self._cond:
            self.items.append(msg)
            self._cond.notify_all()

    def wait_for_stamp(self, sec: int, timeout: float = TIMEOUT) -> MarkerArray:
        def found():
            return next((m for m in self.items
                         if m.markers and m.markers[0].header.stamp.sec == sec), None)

        with self._cond:
            if not self._cond.wait_for(lambda: found() is not None, timeout):
                got = [m.markers[0].header.stamp.sec for m in self.items if m.markers]
                pytest.fail(f"no MarkerArray stamped {sec} within {timeout} s (got {got})")
            return found()

    def snapshot(self) -> list[MarkerArray]:
        with self._cond:
            return list(self.items)


class GatedCore:
    """The real ``model_scene`` behind a gate: frames pile up while one is held."""

    def __init__(self) -> None:
        self.gate = threading.Event()
        self.gate.set()
        self._lock = threading.Lock()
        self._calls = 0

    @property
    def calls(self) -> int:
        with self._lock:
            return self._calls

    def __call__(self, points, params, *, organized_shape=None):
        with self._lock:
            self._calls += 1
        if not self.gate.wait(TIMEOUT):
            raise RuntimeError("test gate never opened")
        return model_scene(points, params, organized_shape=organized_shape)


class Harness:
    def __init__(self, context: Context, core=model_scene, topic: str = "/rel/points",
                 **overrides) -> None:
        values = {"qos_reliability": "reliable", "qos_depth": 5, **overrides}
        self.node = ModelerNode(
            context=context, model_scene=core,
            cli_args=["--ros-args", "-r", f"points:={topic}"],
            parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])
        self.peer = Node("rel_peer", context=context)
        self.pub = self.peer.create_publisher(PointCloud2, topic, RELIABLE)
        self.markers = MarkerLog(self.peer, "/modeler/primitives")
        # subscribed like RViz, so that the node really serializes and sends them
        self.peer.create_subscription(PointCloud2, "/modeler/segments", lambda _: None,
                                      RELIABLE)
        self.peer.create_subscription(PointCloud2, "/modeler/reconstruction",
                                      lambda _: None, RELIABLE)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.peer)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()
        wait_until(lambda: self.pub.get_subscription_count() >= 1
                   and self.markers.sub.get_publisher_count() >= 1, "discovery")

    def publish_and_wait_received(self, msg: PointCloud2) -> None:
        before = self.node.stats().received
        self.pub.publish(msg)
        wait_until(lambda: self.node.stats().received > before, "the node to receive a frame")

    def settled(self) -> bool:
        """Every received frame is accounted for (nothing waiting or in progress)."""
        s = self.node.stats()
        return s.processed + s.dropped + s.failed == s.received

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=10.0)
        self.thread.join(10.0)
        self.node.destroy_node()
        self.peer.destroy_node()


@pytest.fixture
def harness(context):
    made: list[Harness] = []

    def make(**overrides) -> Harness:
        made.append(Harness(context, **overrides))
        return made[-1]

    yield make
    for h in made:
        h.close()


def stamp(sec: int, nanosec: int = 0) -> Header:
    return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=FRAME)


def scene_cloud(name: str, sec: int) -> PointCloud2:
    return _scene_cloud(name, sec, 0)


def shape_namespaces(markers: MarkerArray) -> set[str]:
    return {m.ns for m in markers.markers if m.action == Marker.ADD and m.ns != "labels"}


def assert_markers_sane(markers: MarkerArray) -> None:
    # DELETEALL at most first (tracked ids: only in the first frame), then DELETE / ADD.
    assert markers.markers
    assert all(m.action != Marker.DELETEALL for m in markers.markers[1:])
    for m in markers.markers:
        if m.action != Marker.ADD:
            continue
        values = [m.pose.position.x, m.pose.position.y, m.pose.position.z,
                  m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z,
                  m.pose.orientation.w]
        assert all(map(math.isfinite, values)), (m.ns, values)
        assert all(math.isfinite(s) and s > 0 for s in (m.scale.x, m.scale.y, m.scale.z)), \
            (m.ns, m.scale)
        assert m.header.frame_id == FRAME


def marker_signature(markers: MarkerArray) -> list[tuple]:
    return [(m.ns, m.id, m.type, round(m.pose.position.x, 9), round(m.pose.position.y, 9),
             round(m.pose.position.z, 9), round(m.scale.x, 9), round(m.scale.y, 9),
             round(m.scale.z, 9), m.text) for m in markers.markers if m.action == Marker.ADD]


# --------------------------------------------------------------------------- bad input
def _raw_cloud(points, sec: int, *, datatype=PointField.FLOAT32, big=False, names="xyz",
               height=1) -> PointCloud2:
    """Build an x, y, z cloud by hand (any datatype, byte order and field names)."""
    pts = np.asarray(points, dtype=np.float64)
    element = np.dtype({PointField.FLOAT32: "f4", PointField.FLOAT64: "f8",
                        PointField.INT16: "i2"}[datatype]).newbyteorder(">" if big else "<")
    step = 3 * element.itemsize
    width = len(pts) // height
    msg = PointCloud2(header=stamp(sec), height=height, width=width, is_bigendian=big,
                      point_step=step, row_step=step * width, is_dense=False,
                      fields=[PointField(name=n, offset=i * element.itemsize,
                                         datatype=datatype, count=1)
                              for i, n in enumerate(names)])
    with np.errstate(invalid="ignore", over="ignore"):
        msg.data = array.array("B", pts.astype(element).tobytes())
    return msg


def bad_clouds(first_sec: int) -> list[tuple[str, PointCloud2]]:
    """Every kind of malformed or degenerate cloud, each with its own stamp."""
    rng = np.random.default_rng(7)
    blob = rng.normal(scale=0.1, size=(300, 3)) + [0, 0, 1]
    kinds: list[tuple[str, PointCloud2]] = []

    def add(name, msg):
        kinds.append((name, msg))

    sec = iter(range(first_sec, first_sec + 100))
    m = _raw_cloud(blob, next(sec), names="xz_")
    add("missing y", m)
    m = _raw_cloud(blob, next(sec))
    m.point_step = 8
    add("point_step smaller than the fields", m)
    m = _raw_cloud(blob, next(sec))
    m.data = m.data[:-5]
    add("data too short", m)
    m = _raw_cloud(blob, next(sec))
    m.data.extend(b"\0" * 40)
    add("data too long", m)
    m = _raw_cloud(blob, next(sec))
    m.row_step = 4
    add("row_step too small", m)
    m = _raw_cloud(blob, next(sec))
    m.fields[1].datatype = 99
    add("unknown datatype", m)
    m = _raw_cloud(blob, next(sec))
    m.fields[2].count = 0
    add("count 0", m)
    add("integer xyz", _raw_cloud(blob, next(sec), datatype=PointField.INT16))
    add("repeated field", _raw_cloud(blob, next(sec), names="xyx"))
    m = _raw_cloud(blob, next(sec))
    m.height = 0
    add("height 0 with data", m)
    add("empty", _raw_cloud(np.zeros((0, 3)), next(sec)))
    add("all NaN", _raw_cloud(np.full((300, 3), np.nan), next(sec), height=10))
    add("all Inf", _raw_cloud(np.full((300, 3), np.inf), next(sec)))
    patches = blob.copy()
    patches[::3] = np.nan
    patches[1::7, 2] = -np.inf
    add("NaN/Inf patches", _raw_cloud(patches, next(sec)))
    add("1 point", _raw_cloud(blob[:1], next(sec)))
    add("3 points", _raw_cloud(blob[:3], next(sec)))
    add("huge", _raw_cloud(rng.uniform(-1e6, 1e6, (2000, 3)), next(sec)))
    add("tiny", _raw_cloud(rng.uniform(-1e-6, 1e-6, (2000, 3)) + [0, 0, 1], next(sec),
                           datatype=PointField.FLOAT64))
    add("collinear", _raw_cloud(np.c_[np.linspace(-0.2, 0.2, 2000), np.zeros(2000),
                                      np.ones(2000)], next(sec)))
    add("coplanar", _raw_cloud(np.c_[rng.uniform(-0.1, 0.1, (3000, 2)), np.ones(3000)],
                               next(sec), big=True))
    add("duplicates", _raw_cloud(np.tile([[0.0, 0.1, 1.0]], (2000, 1)), next(sec)))
    return kinds


def test_burst_of_bad_clouds_never_stops_the_node(harness):
    h = harness()
    published = 0
    sec = 100
    for i, (kind, bad) in enumerate(bad_clouds(first_sec=1000)):
        h.publish_and_wait_received(bad)
        published += 1
        if i % 4 == 3:  # a good frame now and then (it may be dropped: newest wins)
            sec += 1
            h.publish_and_wait_received(scene_cloud("tiny_box", sec))
            published += 1
    wait_until(h.settled, "the node to account for every frame")
    s = h.node.stats()
    assert s.received == published
    assert s.failed >= 1  # the malformed ones the worker got to
    for markers in h.markers.snapshot():
        assert_markers_sane(markers)

    # the node is alive and models the next good frame correctly
    h.pub.publish(scene_cloud("tiny_shapes", 777))
    markers = h.markers.wait_for_stamp(777)
    assert_markers_sane(markers)
    assert {"plane", "cuboid", "sphere", "cylinder"} <= shape_namespaces(markers)
    wait_until(h.settled, "the last frame to be accounted for")
    assert h.node.stats().processed == s.processed + 1


def test_every_bad_cloud_alone_is_failed_or_modeled_never_fatal(harness):
    """One at a time (no drops): each frame is either failed or gives sane markers."""
    # Per-frame markers (no tracking): every processed frame, even an empty one, then has
    # a stamped MarkerArray (DELETEALL) to check.
    h = harness(publish_reconstruction=True, publish_segments=True, tracking=False)
    for kind, bad in bad_clouds(first_sec=2000):
        before = h.node.stats()
        h.publish_and_wait_received(bad)
        wait_until(h.settled, f"the {kind!r} frame to be accounted for")
        after = h.node.stats()
        if after.processed > before.processed:
            markers = h.markers.wait_for_stamp(bad.header.stamp.sec)
            assert_markers_sane(markers)
        else:
            assert after.failed == before.failed + 1, kind
    h.pub.publish(scene_cloud("tiny_box", 3000))
    assert {"plane", "cuboid"} <= shape_namespaces(h.markers.wait_for_stamp(3000))


# --------------------------------------------------------------------------- parameters
def test_rejected_parameter_sets_change_nothing(harness):
    h = harness()
    h.pub.publish(scene_cloud("tiny_shapes", 1))
    reference = marker_signature(h.markers.wait_for_stamp(1))
    params = h.node.modeling_params
    values = {p.name: p.value for p in h.node.get_parameters(list(params.to_dict()))}

    rejected = [
        [Parameter("voxel_size", value=-1.0)],
        [Parameter("voxel_size", value=math.nan)],
        [Parameter("voxel_size", value=math.inf)],
        [Parameter("voxel_size", value="coarse")],
        [Parameter("normal_neighbors", value=2.5)],
        [Parameter("min_radius", value=5.0)],  # >= max_radius
        [Parameter("developable_curvature_ratio", value=0.9)],  # >= sphere ratio
        [Parameter("edge_correction", value=1)],
        [Parameter("qos_depth", value=7)],  # read-only
    ]
    for params_set in rejected:
        (result,) = h.node.set_parameters(params_set)
        assert not result.successful and result.reason, params_set
    # atomically: one bad value rejects the whole set, the good one included
    result = h.node.set_parameters_atomically([Parameter("voxel_size", value=0.005),
                                               Parameter("max_radius", value=0.001)])
    assert not result.successful and "min_radius" in result.reason

    assert h.node.modeling_params == params
    assert {p.name: p.value for p in h.node.get_parameters(list(values))} == values
    h.pub.publish(scene_cloud("tiny_shapes", 2))
    assert marker_signature(h.markers.wait_for_stamp(2)) == reference
    assert h.node.stats().failed == 0


# --------------------------------------------------------------------------- load
def test_frames_arriving_during_modeling_are_dropped_not_queued(harness):
    core = GatedCore()
    h = harness(core=core, qos_depth=1)
    organized = render_scene("apart").organized
    rounds, burst = 3, 5
    sec, expected_stamps = 0, []
    for r in range(rounds):
        core.gate.clear()
        sec += 1
        h.publish_and_wait_received(xyz_to_cloud(organized, stamp(sec)))
        wait_until(lambda: core.calls == 2 * r + 1, "the worker to hold the frame")
        expected_stamps.append(sec)
        for _ in range(burst):  # all arrive while the first one is being modeled
            sec += 1
            h.publish_and_wait_received(xyz_to_cloud(organized, stamp(sec)))
        expected_stamps.append(sec)  # the newest replaced the others in the mailbox
        core.gate.set()
        h.markers.wait_for_stamp(sec)
        wait_until(h.settled, "the node to go idle")

    s = h.node.stats()
    assert (s.received, s.processed, s.dropped, s.failed) == (
        rounds * (1 + burst), 2 * rounds, rounds * (burst - 1), 0)
    assert core.calls == 2 * rounds
    items = h.markers.snapshot()
    # modeled in arrival order, never an older frame after a newer one
    assert [m.markers[0].header.stamp.sec for m in items] == expected_stamps
    for markers in items:
        assert_markers_sane(markers)
        assert shape_namespaces(markers) == {"plane", "cuboid", "cylinder", "sphere"}


# --------------------------------------------------------------------------- parameters
# (every parameter at its range ends and random combinations; keep these last: see
# param_node)
#: The consistency rules, stated independently (as in test_reliability): smaller < larger.
CONSISTENCY_RULES = (("min_radius", "max_radius"),
                     ("developable_curvature_ratio", "sphere_curvature_ratio"))
_SPECS = {q.name: q for q in PARAMETERS}


def _violated(values: dict) -> list[tuple[str, str]]:
    return [(a, b) for a, b in CONSISTENCY_RULES if not values[a] < values[b]]


def _range_end_sets():
    """Both ends of every parameter; a partner a rule needs goes to its own far end."""
    defaults = {q.name: q.default for q in PARAMETERS}
    for spec in PARAMETERS:
        for end in (False, True) if spec.type is bool else \
                spec.choices if spec.type is str else (spec.low, spec.high):
            values = {spec.name: end}
            for a, b in _violated({**defaults, **values}):
                partner = b if spec.name == a else a
                values[partner] = _SPECS[partner].high if partner == b else _SPECS[partner].low
            yield pytest.param(values, id=f"{spec.name}={end}")


@pytest.fixture(scope="module")
def param_node():
    """One node for all parameter cases (each case restores the defaults it changed).

    It lives until the end of this module, so it has its own input topic (it never models
    the other tests' frames) and these tests come last.
    """
    import rclpy

    ctx = Context()
    rclpy.init(args=[], context=ctx)
    # Per-frame markers (no tracking): every processed frame, even one without objects,
    # has a stamped MarkerArray (DELETEALL) to check.
    h = Harness(ctx, topic="/rel_params/points", tracking=False)
    h.next_sec = 5000
    yield h
    h.close()
    rclpy.try_shutdown(context=ctx)


def _set_and_model(h: Harness, values: dict) -> None:
    """Set ``values`` through the parameter interface; check the verdict and the next frame."""
    before_params = h.node.modeling_params
    result = h.node.set_parameters_atomically(
        [Parameter(k, value=v) for k, v in values.items()])
    broken = _violated({**before_params.to_dict(), **values})
    if broken:
        a, b = broken[0]
        assert not result.successful
        assert a in result.reason and b in result.reason, result.reason
        assert h.node.modeling_params == before_params
        return
    assert result.successful, result.reason
    try:
        assert {k: getattr(h.node.modeling_params, k) for k in values} == values
        h.next_sec += 1
        before = h.node.stats()
        h.pub.publish(scene_cloud("tiny_box", h.next_sec))
        wait_until(lambda: h.settled() and h.node.stats().received > before.received,
                   "the frame to be accounted for")
        after = h.node.stats()
        assert after.failed == before.failed, "the node could not model the frame"
        assert_markers_sane(h.markers.wait_for_stamp(h.next_sec))
    finally:
        restored = h.node.set_parameters_atomically(
            [Parameter(k, value=getattr(before_params, k)) for k in values])
        assert restored.successful and h.node.modeling_params == before_params


@pytest.mark.parametrize("values", _range_end_sets())
def test_every_parameter_at_its_range_ends_through_the_node(param_node, values):
    _set_and_model(param_node, values)


def _in_range(spec):
    if spec.type is bool:
        return st.booleans()
    if spec.type is str:
        return st.sampled_from(spec.choices)
    if spec.type is int:
        return st.integers(int(spec.low), int(spec.high))
    return st.floats(spec.low, spec.high, allow_nan=False)


@settings(max_examples=8, deadline=None, derandomize=True, database=None,
          suppress_health_check=list(HealthCheck))
@given(values=st.fixed_dictionaries({q.name: _in_range(q) for q in PARAMETERS}))
def test_random_parameter_combinations_through_the_node(param_node, values):
    _set_and_model(param_node, values)
