"""The launch file and the RViz config: they compile/parse and name only what exists.

``launch`` and ``launch_ros`` are not installed here, so the launch file is checked from its
source: it compiles, defines ``generate_launch_description``, starts the ``modeler``
executable of this package, and every parameter it sets and every topic it remaps is one
the node declares or creates (read from ``geomodel_ros/ros/node.py``, so that a renamed
topic or parameter fails this test).  The RViz config is YAML whose displays subscribe to
the node's outputs with the right display types.  ``setup.py`` must install both, and
a colcon build of the package must put every config file the launch file names into
``share/geomodel_ros/config``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import yaml

from geomodel_ros.core.params import PARAMETERS
from geomodel_ros.ros.node import NODE_PARAMETERS

ROOT = Path(__file__).resolve().parent.parent
LAUNCH = ROOT / "launch" / "modeler.launch.py"
RVIZ = ROOT / "config" / "modeler.rviz"
NODE = ROOT / "geomodel_ros" / "ros" / "node.py"
#: Parameters a params file or launch file may set on the node.
NODE_PARAMETER_NAMES = {p.name for p in PARAMETERS} | {p.name for p in NODE_PARAMETERS}
#: Launch arguments the launch file must offer.
LAUNCH_ARGUMENTS = {"params_file", "namespace", "points_topic", "use_large_data_profile",
                    "rviz"}


def _call_name(node: ast.Call) -> str:
    func = node.func
    return func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")


def _node_topics() -> set[str]:
    """Topic and service names the node creates (first string argument after the type)."""
    names = set()
    for node in ast.walk(ast.parse(NODE.read_text())):
        if isinstance(node, ast.Call) and _call_name(node) in (
                "create_publisher", "create_subscription", "create_service",
                "create_input_subscription"):
            topic = node.args[1]
            assert isinstance(topic, ast.Constant), ast.dump(topic)
            names.add(topic.value)
    return names


def _calls(tree: ast.AST, name: str) -> list[ast.Call]:
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call) and _call_name(n) == name]


def _keywords(call: ast.Call) -> dict[str, ast.expr]:
    return {k.arg: k.value for k in call.keywords}


@pytest.fixture(scope="module")
def launch_tree() -> ast.Module:
    source = LAUNCH.read_text()
    compile(source, str(LAUNCH), "exec")  # a syntax error fails here
    return ast.parse(source)


@pytest.fixture(scope="module")
def modeler_node(launch_tree) -> dict[str, ast.expr]:
    nodes = [_keywords(c) for c in _calls(launch_tree, "Node")]
    modelers = [k for k in nodes if isinstance(k.get("executable"), ast.Constant)
                and k["executable"].value == "modeler"]
    assert len(modelers) == 1, "the launch file must start exactly one modeler"
    return modelers[0]


def test_node_topics_are_read_from_the_node():
    # the reference set itself: the outputs the README documents and the input
    assert {"points", "~/primitives", "~/segments", "~/reconstruction",
            "/diagnostics"} <= _node_topics()


def test_launch_file_defines_generate_launch_description(launch_tree):
    functions = {n.name for n in launch_tree.body if isinstance(n, ast.FunctionDef)}
    assert "generate_launch_description" in functions


def test_launch_file_starts_the_modeler_of_this_package(launch_tree, modeler_node):
    package = modeler_node["package"]
    if isinstance(package, ast.Name):  # a module constant
        assigned = {t.id: n.value for n in launch_tree.body if isinstance(n, ast.Assign)
                    for t in n.targets if isinstance(t, ast.Name)}
        package = assigned[package.id]
    assert ast.literal_eval(package) == "geomodel_ros"
    assert "namespace" in modeler_node and "parameters" in modeler_node


def test_launch_file_declares_its_arguments(launch_tree):
    declared = {ast.literal_eval(c.args[0]) for c in _calls(launch_tree, "DeclareLaunchArgument")}
    assert LAUNCH_ARGUMENTS <= declared
    used = {ast.literal_eval(c.args[0]) for c in _calls(launch_tree, "LaunchConfiguration")}
    assert used == declared, "every argument declared is used and vice versa"


def test_launch_file_sets_only_existing_parameters(modeler_node):
    parameters = modeler_node["parameters"]
    assert isinstance(parameters, ast.List)
    dicts = [e for e in parameters.elts if isinstance(e, ast.Dict)]
    names = {ast.literal_eval(k) for d in dicts for k in d.keys}
    assert names, "the launch file overrides at least qos_reliability"
    unknown = names - NODE_PARAMETER_NAMES
    assert not unknown, f"parameters the node does not declare: {sorted(unknown)}"


def test_launch_file_remaps_only_topics_of_the_node(modeler_node):
    remaps = modeler_node["remappings"]
    assert isinstance(remaps, ast.List)
    sources = {ast.literal_eval(t.elts[0]) for t in remaps.elts}
    assert "points" in sources
    unknown = sources - _node_topics()
    assert not unknown, f"remapped topics the node does not have: {sorted(unknown)}"


def test_large_data_profile_points_at_the_installed_profile(launch_tree):
    (env,) = _calls(launch_tree, "SetEnvironmentVariable")
    assert ast.literal_eval(env.args[0]) == "FASTRTPS_DEFAULT_PROFILES_FILE"
    assert "fastdds_large_data.xml" in ast.unparse(env.args[1])
    assert "condition" in _keywords(env), "the profile is only set on request"
    assert (ROOT / "config" / "fastdds_large_data.xml").is_file()


def test_the_parameter_check_rejects_an_unknown_name():
    # the check above must be able to fail: a misspelt parameter is not in the set
    assert "qos_reliabilty" not in NODE_PARAMETER_NAMES
    assert "qos_reliability" in NODE_PARAMETER_NAMES


# ---------------------------------------------------------------------------------------
# RViz
# ---------------------------------------------------------------------------------------

def _displays() -> list[dict]:
    config = yaml.safe_load(RVIZ.read_text())
    return config["Visualization Manager"]["Displays"]


def _display(topic: str) -> dict:
    (found,) = [d for d in _displays() if d.get("Topic", {}).get("Value") == topic]
    return found


def test_rviz_config_fixed_frame():
    config = yaml.safe_load(RVIZ.read_text())
    assert config["Visualization Manager"]["Global Options"]["Fixed Frame"] == "camera_optical"


@pytest.mark.parametrize("topic, display_class, enabled", [
    ("/modeler/primitives", "rviz_default_plugins/MarkerArray", True),
    ("/modeler/segments", "rviz_default_plugins/PointCloud2", True),
    ("/modeler/reconstruction", "rviz_default_plugins/PointCloud2", True),
    ("/points", "rviz_default_plugins/PointCloud2", False),
])
def test_rviz_config_displays(topic, display_class, enabled):
    display = _display(topic)
    assert display["Class"] == display_class
    assert display["Enabled"] is enabled


def test_rviz_segments_are_coloured_by_their_rgb_field():
    assert _display("/modeler/segments")["Color Transformer"] == "RGB8"


def test_rviz_topics_are_outputs_of_the_node():
    private = {t[2:] for t in _node_topics() if t.startswith("~/")}
    for display in _displays():
        topic = display.get("Topic", {}).get("Value")
        if topic is None or topic == "/points":
            continue
        node, _, name = topic.strip("/").partition("/")
        assert node == "modeler" and name in private, topic


# ---------------------------------------------------------------------------------------
# installation
# ---------------------------------------------------------------------------------------

def _data_files() -> dict[str, str]:
    """``setup.py``'s data_files as {destination: source expression}."""
    tree = ast.parse((ROOT / "setup.py").read_text())
    (setup,) = _calls(tree, "setup")
    entries = _keywords(setup)["data_files"]
    return {ast.unparse(e.elts[0]): ast.unparse(e.elts[1]) for e in entries.elts}


def test_setup_installs_launch_file_and_rviz_config():
    files = _data_files()
    assert files["f'share/{PACKAGE}/launch'"] == "glob('launch/*.launch.py')"
    config = files["f'share/{PACKAGE}/config'"]
    for pattern in ("config/*.yaml", "config/*.rviz", "config/*.xml"):
        assert pattern in config
    assert LAUNCH.match("launch/*.launch.py") and RVIZ.match("config/*.rviz")


def config_files_named_by_the_launch_file() -> set[str]:
    """Names of the config files (.yaml, .xml, .rviz) the launch file refers to.

    The colcon build of ``test_ros2_run_contract.py`` checks that they are installed.
    """
    tree = ast.parse(LAUNCH.read_text())
    return {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)
            and isinstance(n.value, str) and n.value.endswith((".yaml", ".xml", ".rviz"))}
