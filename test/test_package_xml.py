"""package.xml declares what the package needs at run time, with keys rosdep resolves.

Every module of the package (``geomodel_ros``, ``msg_adapters``, the launch file; not the
tests) is read with ``ast``; each import that is neither the standard library nor the
package itself must map (table below) onto a dependency that package.xml declares, or, for a
library without a rosdep key, onto a comment in package.xml that says how to install it.
The rosdep keys were looked up in rosdistro's ``rosdep/python.yaml`` (``python3-open3d-pip``
and ``python3-hypothesis`` exist there; no key provides ``rosbags``, ``lzf`` or ``pykdtree``).
"""

from __future__ import annotations

import ast
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE_XML = ROOT / "package.xml"
#: Where the package's modules are (the tests' own imports are test dependencies).
SOURCES = ("geomodel_ros", "msg_adapters", "launch")
FIRST_PARTY = {"geomodel_ros", "msg_adapters"}

#: Import name -> rosdep key of the package that provides it.
ROSDEP_KEYS = {
    # ROS 2 packages: the key is the package name
    **{name: name for name in (
        "rclpy", "sensor_msgs", "visualization_msgs", "std_msgs", "std_srvs", "geometry_msgs",
        "shape_msgs", "diagnostic_msgs", "rcl_interfaces", "builtin_interfaces",
        "geomodel_msgs", "ament_index_python", "launch", "launch_ros", "tf2_ros")},
    # Python libraries: rosdistro rosdep/python.yaml
    "numpy": "python3-numpy",
    "scipy": "python3-scipy",
    "threadpoolctl": "python3-threadpoolctl",
    "yaml": "python3-yaml",
    "open3d": "python3-open3d-pip",
    "hypothesis": "python3-hypothesis",
}
#: Imports that no rosdep key provides -> the install command package.xml must name.
NO_ROSDEP_KEY = {
    "rosbags": "pip install rosbags",
    "lzf": "pip install python-lzf",
    "pykdtree": "pip install pykdtree",
}
#: Development tools (not used by the node, the CLI or the launch file): their imports may be
#: test dependencies.
DEVELOPMENT_TOOLS = {Path("geomodel_ros/tools/fuzz.py"), Path("geomodel_ros/tools/fuzz_node.py")}
RUNTIME_TAGS = ("exec_depend", "depend")
TEST_TAGS = RUNTIME_TAGS + ("test_depend",)
#: A plausible e-mail address (local@domain.tld).
EMAIL = re.compile(r"^[A-Za-z0-9._%+-]+@[A-Za-z0-9.-]+\.[A-Za-z]{2,}$")


def third_party_imports(path: Path) -> set[str]:
    """Top-level names of the absolute imports of ``path`` outside stdlib and the package."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return {n for n in names if n not in sys.stdlib_module_names and n not in FIRST_PARTY}


def _modules() -> list[Path]:
    return sorted(p.relative_to(ROOT) for d in SOURCES for p in (ROOT / d).rglob("*.py"))


def _declared(root: ET.Element, tags) -> set[str]:
    return {e.text.strip() for tag in tags for e in root.iter(tag)}


def unmet_imports(modules: list[Path], declared_runtime: set[str], declared_test: set[str],
                  comments: str) -> list[str]:
    """Say, per module, which import package.xml does not cover (empty: all covered)."""
    problems = []
    for module in modules:
        declared = declared_test if module in DEVELOPMENT_TOOLS else declared_runtime
        for name in sorted(third_party_imports(ROOT / module)):
            if name in NO_ROSDEP_KEY:
                if NO_ROSDEP_KEY[name] not in comments:
                    problems.append(f"{module}: {name}: no comment with "
                                    f"'{NO_ROSDEP_KEY[name]}'")
            elif name not in ROSDEP_KEYS:
                problems.append(f"{module}: {name}: not in this test's table")
            elif ROSDEP_KEYS[name] not in declared:
                problems.append(f"{module}: {name}: {ROSDEP_KEYS[name]} not declared")
    return problems


@pytest.fixture(scope="module")
def manifest() -> ET.Element:
    return ET.parse(PACKAGE_XML).getroot()


def _comments() -> str:
    return " ".join(re.findall(r"<!--(.*?)-->", PACKAGE_XML.read_text(), re.S))


def test_format_3_and_identity(manifest):
    assert manifest.tag == "package" and manifest.get("format") == "3"
    assert manifest.findtext("name") == "geomodel_ros"
    assert re.fullmatch(r"\d+\.\d+\.\d+", manifest.findtext("version"))
    assert manifest.find("export/build_type").text == "ament_python"


def test_maintainer_has_a_valid_email(manifest):
    maintainers = manifest.findall("maintainer")
    assert maintainers
    for m in maintainers:
        assert EMAIL.match(m.get("email", "")), m.get("email")
        assert m.text and m.text.strip()


def test_the_email_check_rejects_malformed_addresses():
    for bad in ("maintainers", "a@b", "a b@c.de", "@geomodel-ros.dev", ""):
        assert not EMAIL.match(bad)


def test_every_import_maps_to_a_declared_dependency(manifest):
    modules = _modules()
    assert Path("geomodel_ros/ros/node.py") in modules
    assert Path("launch/modeler.launch.py") in modules
    problems = unmet_imports(modules, _declared(manifest, RUNTIME_TAGS),
                             _declared(manifest, TEST_TAGS), _comments())
    assert not problems, "\n".join(problems)


def test_keys_without_rosdep_entry_are_not_declared(manifest):
    # declaring a key rosdep does not know breaks `rosdep install` for users
    declared = _declared(manifest, TEST_TAGS + ("build_depend",))
    assert not declared & set(NO_ROSDEP_KEY)
    assert not declared & {"python3-rosbags", "python3-lzf", "python3-open3d",
                                "python3-pykdtree"}


def test_no_dependency_is_declared_twice(manifest):
    names = [e.text.strip() for tag in TEST_TAGS for e in manifest.iter(tag)]
    assert len(names) == len(set(names))


def test_launch_and_rviz_are_run_dependencies(manifest):
    assert {"launch", "launch_ros", "rviz2"} <= _declared(manifest, RUNTIME_TAGS)


def test_the_check_reports_an_undeclared_or_unknown_import(tmp_path, monkeypatch):
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    module = tmp_path / "mod.py"
    module.write_text("import os\nimport numpy as np\nfrom scipy import linalg\n"
                      "import geomodel_ros.core\nimport rosbags.rosbag2\nimport cv2\n")
    problems = unmet_imports([Path("mod.py")], {"python3-numpy"}, {"python3-numpy"}, "")
    assert problems == ["mod.py: cv2: not in this test's table",
                        "mod.py: rosbags: no comment with 'pip install rosbags'",
                        "mod.py: scipy: python3-scipy not declared"]
    assert unmet_imports([Path("mod.py")], {"python3-numpy", "python3-scipy"}, set(),
                         "pip install rosbags") == ["mod.py: cv2: not in this test's table"]
