"""Helpers shared by the tests that run real rclpy pub/sub (import after conftest set-up)."""

from __future__ import annotations

import time

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from geomodel_ros.tools.synth import render_scene
from msg_adapters.pointcloud2 import xyz_to_cloud

#: Longest wait for any condition [s].
TIMEOUT = 30.0
FRAME = "camera_optical"
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)

_SCENES: dict[str, np.ndarray] = {}


def wait_until(predicate, what: str, timeout: float = TIMEOUT) -> None:
    """Poll ``predicate`` until it holds; fail the test after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.002)


def scene_cloud(name: str, sec: int = 42, nanosec: int = 500) -> PointCloud2:
    """Organized (H, W) cloud of a synthetic scene, NaN where the camera saw nothing."""
    if name not in _SCENES:
        _SCENES[name] = render_scene(name).organized
    header = Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=FRAME)
    return xyz_to_cloud(_SCENES[name], header)
