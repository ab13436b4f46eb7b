"""The core imports and runs with every ROS module blocked; the layers import what they may."""

from __future__ import annotations

import ast
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


# ---------------------------------------------------------------------------------------
# layers: who may import what (read from the source, so a lazy import counts too)
# ---------------------------------------------------------------------------------------

#: Packages that define ROS messages (and rclpy's message (de)serialization): only
#: msg_adapters may import them.
MESSAGE_PACKAGES = ("sensor_msgs", "std_msgs", "visualization_msgs", "geometry_msgs",
                    "builtin_interfaces", "diagnostic_msgs", "rcl_interfaces",
                    "rclpy.serialization")


def _imports(path: Path) -> list[str]:
    """Every module named by an import statement of ``path`` (relative ones resolved)."""
    package = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    names = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package.rsplit(".", node.level - 1)[0] if node.level else ""
            module = ".".join(filter(None, [base, node.module or ""]))
            names += [module] + [f"{module}.{a.name}" for a in node.names]
    return names


def _within(name: str, packages) -> bool:
    return any(name == p or name.startswith(p + ".") for p in packages)


def _sources(folder: str) -> list[Path]:
    files = sorted((ROOT / folder).rglob("*.py"))
    assert files, folder
    return files


def test_imports_helper_sees_absolute_relative_and_lazy_imports():
    probe = ROOT / "msg_adapters" / "markers.py"
    names = _imports(probe)
    assert "msg_adapters.pointcloud2.xyz_to_cloud" in names  # from .pointcloud2 import ...
    assert "visualization_msgs.msg.MarkerArray" in names
    # an import inside a function (bags._play_qos) counts too
    assert "rclpy.qos.QoSProfile" in _imports(ROOT / "geomodel_ros" / "ros" / "bags.py")
    assert _within("rclpy.serialization.serialize_message", MESSAGE_PACKAGES)
    assert not _within("rclpy.node", MESSAGE_PACKAGES)


def test_msg_adapters_import_only_core_types_of_geomodel_ros():
    for path in _sources("msg_adapters"):
        ours = [n for n in _imports(path) if _within(n, ["geomodel_ros"])]
        bad = [n for n in ours if not _within(n, ["geomodel_ros.core"])]
        assert not bad, f"{path.relative_to(ROOT)} imports {bad}"


def test_only_msg_adapters_touch_message_packages():
    for path in _sources("geomodel_ros"):
        bad = [n for n in _imports(path) if _within(n, MESSAGE_PACKAGES)]
        assert not bad, f"{path.relative_to(ROOT)} imports {bad}; go through msg_adapters"


def test_core_imports_nothing_of_the_ros_layer_or_the_tools():
    for path in _sources("geomodel_ros/core"):
        bad = [n for n in _imports(path)
               if _within(n, ["geomodel_ros", "msg_adapters", "rclpy"])
               and not _within(n, ["geomodel_ros.core"])]
        assert not bad, f"{path.relative_to(ROOT)} imports {bad}"
