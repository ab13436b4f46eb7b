"""Frames modeled at once: worker processes (``ProcessModeler``) and the node's ``workers``.

The reference for every result is the core's ``model_scene`` called in this process with
the same points and parameters: a worker process must give exactly that (same seed).
"""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest
from rclpy.exceptions import ParameterException
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2

from geomodel_ros.core.errors import InputError
from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.ros.frame_workers import MAX_WORKERS, ProcessModeler
from geomodel_ros.ros.node import ModelerNode
from geomodel_ros.ros.processing import process_cloud
from geomodel_ros.tools.synth import render_scene
from msg_adapters.pointcloud2 import cloud_to_xyz, xyz_to_cloud
from ros_helpers import TIMEOUT, scene_cloud, wait_until
from test_node import Harness


def _msg_key(o) -> tuple:
    """Return an object message's id, type, pose and dimensions."""
    p = o.pose
    return (o.id, o.type, p.position.x, p.position.y, p.position.z, p.orientation.x,
            p.orientation.y, p.orientation.z, p.orientation.w, tuple(o.dimensions))


def _same_objects(a, b) -> None:
    """Assert two ModelingResults hold the same objects (ids, types, poses, sizes)."""
    assert [(o.id, o.type) for o in a.objects] == [(o.id, o.type) for o in b.objects]
    for x, y in zip(a.objects, b.objects):
        np.testing.assert_array_equal(x.center, y.center)
        np.testing.assert_array_equal(x.rotation, y.rotation)
        assert x.dimensions == y.dimensions


@pytest.fixture(scope="module")
def scene_points() -> np.ndarray:
    return render_scene("tiny_box").points


@pytest.fixture
def modeler():
    pm = ProcessModeler(2)
    yield pm
    pm.close()


def _worker_pids(pm: ProcessModeler) -> list[int]:
    pool = pm._current_pool()  # noqa: SLF001 - the test kills a worker on purpose
    return [p.pid for p in pool._processes.values()]  # noqa: SLF001


def test_worker_result_is_the_in_process_result(modeler, scene_points):
    params = ModelingParams()
    want_labels, want = model_scene(scene_points, params)
    labels, got = modeler(scene_points, params)
    np.testing.assert_array_equal(labels, want_labels)
    assert len(got.objects) >= 1
    _same_objects(got, want)


def test_core_errors_reach_the_caller_unchanged(modeler):
    with pytest.raises(InputError):
        modeler(np.zeros((5, 2)), ModelingParams())
    # the workers survive a frame the core rejects
    labels, _ = modeler(render_scene("tiny_box").points, ModelingParams())
    assert labels.max() >= 0


def _dead(pid: int) -> bool:
    """Tell whether process ``pid`` is gone or a zombie.

    Reaped before the open (FileNotFoundError) or between the open and the read
    (ProcessLookupError): gone.
    """
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().split()[2] == "Z"
    except (FileNotFoundError, ProcessLookupError):
        return True


def test_a_killed_worker_fails_one_frame_and_the_next_is_modeled(modeler, scene_points):
    modeler.start()
    victim = _worker_pids(modeler)[0]
    os.kill(victim, signal.SIGKILL)
    wait_until(lambda: _dead(victim), "the worker to die")
    with pytest.raises(RuntimeError, match="worker process died"):
        for _ in range(3):  # the pool notices the death within a call or two
            modeler(scene_points, ModelingParams())
            time.sleep(0.2)
    labels, got = modeler(scene_points, ModelingParams())
    want_labels, want = model_scene(scene_points, ModelingParams())
    np.testing.assert_array_equal(labels, want_labels)
    _same_objects(got, want)
    assert victim not in _worker_pids(modeler)


@pytest.mark.parametrize("workers", [0, -1, MAX_WORKERS + 1])
def test_workers_out_of_range_are_rejected(workers):
    with pytest.raises(ValueError, match="workers must be in"):
        ProcessModeler(workers)


def test_a_closed_modeler_refuses_frames(scene_points):
    pm = ProcessModeler(1)
    pm.close()
    with pytest.raises(RuntimeError, match="closed"):
        pm(scene_points, ModelingParams())


# --------------------------------------------------------------------------- the node
def _frame(sec: int) -> PointCloud2:
    """Return the tiny_box scene stamped ``sec`` s; frame 2 lacks one point, 1 is whole.

    The stand-in cores below tell the two frames apart by their point counts: with two
    workers, either frame may reach the core first.
    """
    msg = scene_cloud("tiny_box", sec=sec)
    if sec == 2:
        xyz = cloud_to_xyz(msg, keep_organized=True)
        first_valid = np.flatnonzero(np.isfinite(xyz).all(axis=-1).ravel())[0]
        xyz.reshape(-1, 3)[first_valid] = np.nan
        msg = xyz_to_cloud(xyz, msg.header)
    return msg


class SlowFirst:
    """Stand-in core: frame 1 ends ``hold`` s after frame 2's modeling ended.

    Frame 1 (the one with ``first_points`` valid points, whichever reaches the core first) waits
    for frame 2 to finish (at most ``timeout`` s, so that a node that models one frame at a
    time still ends) and then ``hold`` s more: the order in which the two end, and that
    frame 2 waits at least ``hold`` s for its turn, hold however slowly the machine runs.
    """

    def __init__(self, hold: float, timeout: float = 15.0) -> None:
        self.hold = hold
        self.timeout = timeout
        self.first_points = len(cloud_to_xyz(_frame(1)))
        self.finished: list[int] = []  # frames (1, 2) in the order their modeling ended
        self.lock = threading.Lock()
        self.later_done = threading.Event()
        self.first_started = threading.Event()

    def is_first(self, points) -> bool:
        return int(np.isfinite(points).all(axis=1).sum()) == self.first_points

    def __call__(self, points, params, *, organized_shape=None):
        first = self.is_first(points)
        if first:
            self.first_started.set()
            self.later_done.wait(self.timeout)
            time.sleep(self.hold)
        out = model_scene(points, params, organized_shape=organized_shape)
        with self.lock:
            self.finished.append(1 if first else 2)
        if not first:
            self.later_done.set()
        return out


def _publish_both(h: Harness, core: SlowFirst) -> None:
    """Publish frame 1, wait until a worker has taken it to the core, then frame 2.

    A frame not yet taken when the next arrives is replaced by it (the newest frame wins);
    on a loaded machine a worker thread may take longer to wake than frame 2 to arrive.
    """
    h.publish_and_wait_received(_frame(1))
    wait_until(core.first_started.is_set, "a worker to start modeling frame 1")
    h.publish_and_wait_received(_frame(2))


def test_frames_modeled_at_once_are_published_in_arrival_order(context):
    core = SlowFirst(hold=1.0)
    h = Harness(context, core, {"workers": 2})
    try:
        _publish_both(h, core)
        h.objects.wait(2)
        wait_until(lambda: h.node.stats().processed == 2, "both frames to be processed")
        assert core.finished == [2, 1], "the second frame was not modeled while the first was"
        # markers: the first frame's; the second's only if tracking changed something
        assert [m.markers[0].header.stamp.sec for m in h.markers.msgs] in ([1], [1, 2])
        assert [m.header.stamp.sec for m in h.objects.msgs] == [1, 2]
        # tracking saw the frames in order: the same box keeps its id
        ids = [[o.id for o in m.primitives] for m in h.objects.msgs]
        assert ids[0] == ids[1] and len(ids[0]) >= 1
        stats = h.node.stats()
        assert stats.dropped == 0 and stats.failed == 0
        assert stats.last_timing["turn_s"] > 0.5  # the second frame waited for the first
    finally:
        h.close()


def _exited(pid: int) -> bool:
    """Whether process ``pid`` is gone or a zombie (it may vanish while being read)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split()[2] == "Z"
    except (FileNotFoundError, ProcessLookupError):
        return True


def test_node_workers_give_the_in_process_objects(context):
    h = Harness(context, model_scene, {"workers": 2, "tracking": False})
    try:
        assert h.node._processes is not None  # noqa: SLF001 - real worker processes
        pids = _worker_pids(h.node._processes)  # noqa: SLF001
        assert len(pids) == 2 and os.getpid() not in pids
        cloud = scene_cloud("tiny_box", sec=7)
        h.pub.publish(cloud)
        got = h.objects.wait()
        want = process_cloud(cloud, ModelingParams(), segments=False, reconstruction=False)
        assert len(got.primitives) >= 1
        assert [_msg_key(o) for o in got.primitives] == \
            [_msg_key(o) for o in want.objects.primitives]
    finally:
        h.close()
    for pid in pids:  # destroy_node stops the worker processes
        wait_until(lambda pid=pid: _exited(pid), f"worker {pid} to exit", timeout=TIMEOUT)


def test_workers_out_of_range_stop_the_node_at_start(context):
    with pytest.raises(ParameterException, match="workers"):
        ModelerNode(context=context, parameter_overrides=[Parameter("workers", value=0)])


def test_workers_is_read_only(context):
    node = ModelerNode(context=context)
    try:
        assert node.get_parameter("workers").value == 1
        assert node.describe_parameter("workers").read_only
        assert node._processes is None  # noqa: SLF001 - one worker models in-process
    finally:
        node.destroy_node()


class SlowFirstFails(SlowFirst):
    """Stand-in core: the first frame ends after the second (:class:`SlowFirst`), failing."""

    def __call__(self, points, params, *, organized_shape=None):
        out = super().__call__(points, params, organized_shape=organized_shape)
        if self.is_first(points):
            raise RuntimeError("injected core failure")
        return out


def test_a_frame_failing_after_a_later_one_was_modeled_does_not_hold_it(context, capfd):
    core = SlowFirstFails(hold=0.5)
    h = Harness(context, core, {"workers": 2})
    try:
        _publish_both(h, core)
        got = h.objects.wait(1)
        assert got.header.stamp.sec == 2
        wait_until(lambda: h.node.stats().failed == 1, "the first frame's failure to count")
        wait_until(lambda: h.node.stats().processed == 1, "the second frame to be processed")
        assert core.finished == [2, 1]
        assert len(h.objects) == 1
        assert "injected core failure" in capfd.readouterr().err
    finally:
        h.close()
