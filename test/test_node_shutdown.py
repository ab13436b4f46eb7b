"""SIGINT while a frame is being modeled: the modeler exits 0, never finalizing under it.

The node runs in a child process (its ``main``, as ``ros2 run`` starts it) with a scene
modeler that blocks for a set time before modeling, so that a frame is surely in progress
when the signal arrives. A frame that outlasts ``WORKER_JOIN_TIMEOUT_S`` is abandoned: the
process exits at once with status 0 and a warning, and the interpreter is not finalized
(its exit handlers do not run: tearing numpy or open3d down under a thread inside them can
crash the process). A frame that ends within the wait is finished and the process exits
as usual. A crash in native code while modeling leaves every thread's Python stack in the
log (the node enables :mod:`faulthandler`).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from geomodel_ros.tools.synth import render_scene
from msg_adapters.pointcloud2 import xyz_to_cloud

TOPIC = "/shutdown_test/points"

#: The child: the node's main with a blocking scene modeler and a short join timeout.
CHILD = textwrap.dedent("""
    import atexit, ctypes, functools, sys, time
    import geomodel_ros.ros.node as node
    from geomodel_ros.core.modeling import model_scene

    node.WORKER_JOIN_TIMEOUT_S = float(sys.argv[1])
    block = float(sys.argv[2])

    def blocking(*args, **kwargs):
        print("MODELING", flush=True)
        if block < 0:  # a crash in native code while modeling
            ctypes.string_at(0)
        time.sleep(block)
        return model_scene(*args, **kwargs)

    node.ModelerNode = functools.partial(node.ModelerNode, model_scene=blocking)
    atexit.register(lambda: print("FINALIZED", flush=True))
    raise SystemExit(node.main(sys.argv[3:]))
""")


def _run_and_interrupt(tmp_path, join_timeout: float, block: float, interrupt: bool = True
                       ) -> tuple[int, str, float]:
    """Start the child, feed it a frame, SIGINT it once the frame is in progress.

    Return its exit status, its output and the seconds from the signal (or, without
    ``interrupt``, from the frame's start) to its exit. A negative ``block`` crashes the
    child's modeler in native code.
    """
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    log = tmp_path / "child.log"
    with open(log, "w") as sink:
        proc = subprocess.Popen(
            [sys.executable, "-c", CHILD, str(join_timeout), str(block),
             "--ros-args", "-r", f"points:={TOPIC}"],
            env=env, stdout=sink, stderr=subprocess.STDOUT)
    ctx = Context()
    rclpy.init(args=[], context=ctx)
    peer = Node("shutdown_peer", context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(peer)
    threading.Thread(target=executor.spin, daemon=True).start()
    try:
        pub = peer.create_publisher(PointCloud2, TOPIC, QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE))
        cloud = xyz_to_cloud(render_scene("tiny_box").organized, Header(frame_id="cam"))
        deadline = time.monotonic() + 60.0
        while "MODELING" not in log.read_text():
            assert proc.poll() is None, log.read_text()
            assert time.monotonic() < deadline, f"no frame reached the node:\n{log.read_text()}"
            if pub.get_subscription_count():
                pub.publish(cloud)
            time.sleep(0.2)
        sent = time.monotonic()
        if interrupt:
            proc.send_signal(signal.SIGINT)
        try:
            code = proc.wait(timeout=join_timeout + block + 30.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            pytest.fail(f"the node did not exit after SIGINT:\n{log.read_text()}")
        return code, log.read_text(), time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        executor.shutdown(timeout_sec=5.0)
        peer.destroy_node()
        rclpy.try_shutdown(context=ctx)


def test_a_frame_outlasting_the_wait_is_abandoned_without_finalizing(tmp_path):
    # The frame blocks 60 s, the node waits 0.5 s for it.
    code, text, took = _run_and_interrupt(tmp_path, join_timeout=0.5, block=60.0)
    assert code == 0, text
    assert "exiting: 1 frame(s) still being modeled after 0.5 s, abandoned" in text, text
    assert "FINALIZED" not in text, text
    assert "Traceback" not in text, text
    assert took < 30.0, text  # not the 60 s of the frame


def test_a_frame_ending_within_the_wait_is_finished_and_the_exit_is_as_usual(tmp_path):
    # The frame blocks 1 s, the node waits up to 30 s for it.
    code, text, _ = _run_and_interrupt(tmp_path, join_timeout=30.0, block=1.0)
    assert code == 0, text
    assert "abandoned" not in text, text
    assert "FINALIZED" in text, text
    assert "Traceback" not in text, text


def test_a_crash_in_native_code_leaves_every_threads_python_stack(tmp_path):
    # A fault inside numpy, open3d or the middleware kills the process (SIGSEGV); the
    # node enables Python's fault handler, so the log names where each thread was.
    code, text, _ = _run_and_interrupt(tmp_path, join_timeout=5.0, block=-1.0,
                                       interrupt=False)
    assert code == -signal.SIGSEGV, text
    assert "Fatal Python error: Segmentation fault" in text, text
    assert "in blocking" in text, text  # the modeling thread's frame that crashed
