"""The core (algorithm, synth, CLI, file IO) imports and runs with every ROS module blocked."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

BLOCKER = textwrap.dedent("""
    import importlib.abc
    import sys

    BLOCKED = ("rclpy", "sensor_msgs", "visualization_msgs", "std_msgs", "geometry_msgs")

    class BlockRos(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ImportError(f"{name} is blocked: the core must not need ROS")
            return None

    sys.meta_path.insert(0, BlockRos())
""")

CHECK_BLOCKER = BLOCKER + textwrap.dedent("""
    for name in ("rclpy", "rclpy.node", "sensor_msgs.msg", "std_msgs", "geometry_msgs.msg",
                 "visualization_msgs.msg"):
        try:
            __import__(name)
        except ImportError:
            continue
        raise SystemExit(f"{name} was imported although blocked")
    print("blocked")
""")

CORE = BLOCKER + textwrap.dedent("""
    import numpy as np

    import geomodel_ros
    import geomodel_ros.tools.cli
    import geomodel_ros.tools.io
    import geomodel_ros.core.modeling
    import geomodel_ros.tools.synth
    from geomodel_ros.core.modeling import model_objects
    from geomodel_ros.tools.synth import render_scene

    scene = render_scene("tiny_box")
    result = model_objects(scene.points, scene.labels)
    print(",".join(o.type for o in result.objects))
    assert geomodel_ros.tools.cli.main(["params"]) == 0
    leaked = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)
    assert not leaked, leaked
""")


def _run(code: str) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=120)


def test_blocker_blocks_ros_modules():
    proc = _run(CHECK_BLOCKER)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "blocked"


def test_core_imports_and_models_without_ros():
    proc = _run(CORE)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert lines[0] == "plane,cuboid"
    assert "ros__parameters:" in proc.stdout   # `geomodel params` ran
