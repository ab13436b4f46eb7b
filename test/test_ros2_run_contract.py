"""The ``ros2 run geomodel_ros modeler`` contract, end to end in a colcon workspace.

The package source is copied into ``ws/src/geomodel_ros`` and built with colcon (from
PyPI).  After ``. install/setup.bash`` the executable is resolved exactly like ``ros2 run``
does (``get_package_prefix('geomodel_ros') + '/lib/geomodel_ros/modeler'``) and started as
its own process with the installed params file and a topic remap.  The test process
publishes a synthetic cloud, checks the MarkerArray and the reconstruction it gets back,
then stops the node with SIGINT and expects a clean exit.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from builtin_interfaces.msg import Time
from rclpy.context import Context
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header
from visualization_msgs.msg import Marker, MarkerArray

from geomodel_ros.tools.synth import render_scene
from msg_adapters.pointcloud2 import cloud_to_fields, cloud_to_xyz_and_mask, xyz_to_cloud

REPO = Path(__file__).resolve().parent.parent
#: What a source checkout of the package consists of (build products are left out).
PACKAGE_CONTENT = ("package.xml", "setup.py", "setup.cfg", "resource", "config", "launch",
                   "geomodel_ros", "msg_adapters")
RELIABLE = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
STAMP = (1_700_000_123, 456_000_000)


def _bash(script: str, cwd: Path, env: dict[str, str], timeout: float = 120.0
          ) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", "-c", script], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=timeout)


def _clean_env(tmp: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("AMENT_PREFIX_PATH", "COLCON_PREFIX_PATH", "PYTHONPATH",
                        "COLCON_CURRENT_PREFIX")}
    env["PATH"] = f"{Path(sys.executable).parent}:{env.get('PATH', '/usr/bin:/bin')}"
    env["COLCON_HOME"] = str(tmp / "colcon_home")
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # DDS stays on loopback
    env["ROS_DOMAIN_ID"] = os.environ["ROS_DOMAIN_ID"]  # this session's domain
    env["PYTHONUNBUFFERED"] = "1"
    return env


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """Build the package with colcon; return (executable, params file, environment)."""
    tmp = tmp_path_factory.mktemp("colcon")
    ws = tmp / "ws"
    src = ws / "src" / "geomodel_ros"
    src.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    for name in PACKAGE_CONTENT:
        path = REPO / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=ignore)
        else:
            shutil.copy2(path, src / name)
    env = _clean_env(tmp)
    py = sys.executable

    listed = _bash(f'"{py}" -m colcon list', ws, env)
    assert listed.returncode == 0, listed.stderr
    assert "geomodel_ros" in listed.stdout and "(ros.ament_python)" in listed.stdout, (
        f"colcon does not see an ament_python package: {listed.stdout!r}")

    built = _bash(f'"{py}" -m colcon build --event-handlers console_direct-', ws, env)
    assert built.returncode == 0, f"colcon build failed:\n{built.stdout}\n{built.stderr}"

    resolve = (
        '. install/setup.bash && python -c "'
        "import json, os, importlib.util as u; "
        "from ament_index_python.packages import get_package_prefix, "
        "get_package_share_directory as share; "
        "print(json.dumps({'prefix': get_package_prefix('geomodel_ros'), "
        "'share': share('geomodel_ros'), 'module': u.find_spec('geomodel_ros.ros.node').origin, "
        "'env': dict(os.environ)}))"
        '"'
    )
    out = _bash(resolve, ws, env)
    assert out.returncode == 0, out.stderr
    info = json.loads(out.stdout.strip().splitlines()[-1])
    exe = Path(info["prefix"]) / "lib" / "geomodel_ros" / "modeler"
    assert exe.is_file() and os.access(exe, os.X_OK), f"ros2 run would not find {exe}"
    assert Path(info["prefix"]).is_relative_to(ws / "install")
    # the node that runs is the installed copy, not the source tree
    assert Path(info["module"]).is_relative_to(ws / "install"), info["module"]
    params = Path(info["share"]) / "config" / "modeler.yaml"
    assert params.is_file()
    return exe, params, info["env"]


class _Collector:
    """Every message of ``topic``, and whether a publisher of it has been matched.

    Graph discovery (``count_publishers``) can see the node's publisher before the
    middleware has matched it with this subscription; a message published before that is
    not delivered (with tracking, the node's first frame is the only one that starts with
    DELETEALL), so the test waits for the match.
    """

    def __init__(self, node: Node, msg_type, topic: str) -> None:
        self.msgs: list = []
        self.matched = 0
        self.cond = threading.Condition()
        node.create_subscription(msg_type, topic, self._on_msg, RELIABLE,
                                 event_callbacks=SubscriptionEventCallbacks(
                                     matched=self._on_matched))

    def _on_matched(self, status) -> None:
        with self.cond:
            self.matched = status.current_count

    def _on_msg(self, msg) -> None:
        with self.cond:
            self.msgs.append(msg)
            self.cond.notify_all()

    def wait(self, timeout: float):
        with self.cond:
            self.cond.wait_for(lambda: bool(self.msgs), timeout)
            return self.msgs[0] if self.msgs else None


def _output(log: Path) -> str:
    return log.read_text(errors="replace") if log.exists() else ""


def test_ros2_run_modeler(installed, tmp_path):
    exe, params, env = installed
    env = {**env, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
           "ROS_DOMAIN_ID": os.environ["ROS_DOMAIN_ID"]}
    log = tmp_path / "modeler.log"
    ctx = Context()
    rclpy.init(args=[], context=ctx)
    peer = Node("contract_peer", context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(peer)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    # The peer's endpoints exist before the node starts: the node's publishers are matched
    # with them while it starts up, not after its first frame.
    pub = peer.create_publisher(PointCloud2, "/test/points", RELIABLE)
    markers = _Collector(peer, MarkerArray, "/modeler/primitives")
    recon = _Collector(peer, PointCloud2, "/modeler/reconstruction")
    with open(log, "w") as sink:
        proc = subprocess.Popen(
            [str(exe), "--ros-args", "--params-file", str(params), "-r", "points:=/test/points"],
            env=env, stdout=sink, stderr=subprocess.STDOUT, cwd=tmp_path)
    try:
        deadline = time.monotonic() + 30.0
        while pub.get_subscription_count() < 1 or markers.matched < 1 or recon.matched < 1:
            assert proc.poll() is None, f"modeler exited early:\n{_output(log)}"
            assert time.monotonic() < deadline, f"modeler never appeared:\n{_output(log)}"
            time.sleep(0.01)

        scene = render_scene("tiny_box")
        header = Header(stamp=Time(sec=STAMP[0], nanosec=STAMP[1]), frame_id="camera_optical")
        cloud = xyz_to_cloud(scene.organized, header)
        # The node's input is best effort (config default): publish until it answers.
        got = None
        deadline = time.monotonic() + 30.0
        while got is None:
            assert proc.poll() is None, f"modeler died:\n{_output(log)}"
            assert time.monotonic() < deadline, f"no MarkerArray received:\n{_output(log)}"
            pub.publish(cloud)
            got = markers.wait(timeout=3.0)
        rec = recon.wait(timeout=10.0)
        assert rec is not None, f"no reconstruction received:\n{_output(log)}"

        assert got.markers[0].action == Marker.DELETEALL
        for m in got.markers:
            assert m.header.frame_id == "camera_optical"
            assert (m.header.stamp.sec, m.header.stamp.nanosec) == STAMP
        shapes = {m.ns: m for m in got.markers if m.action == Marker.ADD and m.ns != "labels"}
        assert set(shapes) == {"plane", "cuboid"}, [m.ns for m in got.markers]
        box = shapes["cuboid"]
        assert box.type == Marker.CUBE
        size = np.sort(1000 * np.array([box.scale.x, box.scale.y, box.scale.z]))
        assert size == pytest.approx([50, 60, 80], abs=4)  # ground truth 80 x 60 x 50 mm
        desk = shapes["plane"]
        assert 1000 * np.array([desk.scale.x, desk.scale.y]) == pytest.approx([400, 400], abs=10)
        texts = [m.text for m in got.markers if m.ns == "labels"]
        assert any(t.startswith("cuboid l=") and " mm, confidence " in t for t in texts), texts

        assert rec.header.frame_id == "camera_optical"
        assert (rec.header.stamp.sec, rec.header.stamp.nanosec) == STAMP
        pts, mask = cloud_to_xyz_and_mask(rec)
        ids = cloud_to_fields(rec, ["object_id"], mask=mask)["object_id"]
        assert set(np.unique(ids).tolist()) == {box.id, desk.id}
        assert len(pts) > 1000
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        try:
            code = proc.wait(timeout=20.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            code = None
        executor.shutdown(timeout_sec=5.0)
        peer.destroy_node()
        rclpy.try_shutdown(context=ctx)
    text = _output(log)
    assert code == 0, f"modeler exit status {code} after SIGINT:\n{text}"
    assert "Traceback" not in text, text
    assert "modeling clouds from '/test/points'" in text, text


@pytest.mark.parametrize("override, message", [
    ("min_radius:=3.0", "min_radius (3.0) must be smaller than max_radius"),
    ("voxel_size:=5.0", "voxel_size out of range"),
    ("qos_reliability:=sometimes", "qos_reliability"),
])
def test_ros2_run_rejects_invalid_parameters(installed, override, message):
    exe, params, env = installed
    done = subprocess.run(
        [str(exe), "--ros-args", "--params-file", str(params), "-p", override],
        env={**env, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
             "ROS_DOMAIN_ID": os.environ["ROS_DOMAIN_ID"]},
        capture_output=True, text=True, timeout=60)
    text = done.stdout + done.stderr
    assert done.returncode == 2, text
    assert "invalid parameters" in text and message in text, text
    assert "Traceback" not in text, text


def test_colcon_installs_what_the_launch_file_uses(installed):
    from test_launch_file import LAUNCH, RVIZ, config_files_named_by_the_launch_file

    share = installed[1].parent.parent  # .../share/geomodel_ros/config/modeler.yaml
    assert (share / "launch" / "modeler.launch.py").read_text() == LAUNCH.read_text()
    assert (share / "config" / "modeler.rviz").read_text() == RVIZ.read_text()
    named = config_files_named_by_the_launch_file()
    assert {"modeler.yaml", "fastdds_large_data.xml", "modeler.rviz"} <= named
    for name in named:
        assert (share / "config" / name).is_file(), f"{name} is not installed"
