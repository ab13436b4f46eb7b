"""The README documents the node's interfaces: topics, services, parameters, messages.

Read from the sources (the node's ``create_*`` calls, the parameter tables, the ``.msg``
files), so that an interface added without documentation fails here; the planner snippet
of the README must be valid Python that calls the tested conversion as it is defined.
"""

from __future__ import annotations

import ast
import inspect
import re
from pathlib import Path

import pytest

from geomodel_ros.core.tracking import TRACKER_PARAMETERS
from geomodel_ros.ros.node import NODE_NUMERIC_PARAMETERS, NODE_PARAMETERS, TRACKING_PARAMETERS
from geomodel_ros.tools.planner_example import to_collision_objects

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()
MSG_DIR = ROOT / "geomodel_msgs" / "msg"


def _section(title: str) -> str:
    start = README.index(title)
    end = README.find("\n## ", start + len(title))
    return README[start:end if end >= 0 else None]


def _node_interfaces() -> set[str]:
    tree = ast.parse((ROOT / "geomodel_ros" / "ros" / "node.py").read_text())
    names = set()
    for node in ast.walk(tree):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                and node.func.attr in ("create_publisher", "create_subscription",
                                       "create_service", "create_input_subscription")):
            names.add(ast.literal_eval(node.args[1]))
    return names


def _fields(msg: str) -> list[tuple[str, str]]:
    """(type, name) of every field of a .msg file (constants and comments left out)."""
    fields = []
    for line in (MSG_DIR / f"{msg}.msg").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line and "=" not in line:
            ftype, name = line.split()[:2]
            fields.append((ftype, name))
    return fields


def _table_after(heading: str) -> dict[str, str]:
    """Rows ``| `field` | type | ... |`` of the first table after ``heading`` -> type."""
    text = README[README.index(heading):]
    rows = {}
    for line in text.splitlines()[1:]:
        if rows and not line.startswith("|"):
            break
        m = re.match(r"\| `(\w+)` \| ([\w/\[\]]+) \|", line)
        if m:
            rows[m.group(1)] = m.group(2)
    return rows


def test_every_topic_and_service_of_the_node_is_in_the_node_section():
    section = _section("## The ROS 2 node")
    interfaces = _node_interfaces()
    assert {"points", "~/primitives", "/diagnostics"} <= interfaces
    missing = [t for t in interfaces if f"| `{t}`" not in section]
    assert not missing, f"undocumented topics/services: {missing}"


def test_typed_output_interfaces_are_documented():
    section = _section("## The ROS 2 node")
    assert "| `~/objects` | geomodel_msgs/PrimitiveArray |" in section
    assert "| `~/detect` (service) | std_srvs/Trigger |" in section


def test_every_node_and_tracker_parameter_is_documented():
    section = _section("## The ROS 2 node")
    names = [p.name for p in (*NODE_PARAMETERS, *NODE_NUMERIC_PARAMETERS, *TRACKING_PARAMETERS)]
    assert len(TRACKING_PARAMETERS) == len(TRACKER_PARAMETERS)
    missing = [n for n in names if f"`{n}`" not in section]
    assert not missing, f"undocumented parameters: {missing}"


@pytest.mark.parametrize("msg", ["PrimitiveArray", "Primitive", "SupportSurface"])
def test_message_tables_match_the_msg_files(msg):
    table = _table_after(f"`{msg}`\n\n| field | type | meaning |")
    fields = _fields(msg)
    assert fields, f"{msg}.msg has no fields?"
    assert list(table) == [name for _, name in fields], "fields and order"
    for ftype, name in fields:
        assert table[name] == ftype, (name, table[name], ftype)


def test_primitive_type_constants_are_documented_with_their_values():
    text = (MSG_DIR / "Primitive.msg").read_text()
    constants = re.findall(r"^uint8 (\w+)=(\d+)$", text, re.M)
    assert len(constants) == 7
    row = _section("### Messages").split("| `type` | uint8 |")[1].splitlines()[0]
    for name, value in constants:
        assert f"`{name}`={value}" in row


def test_planner_snippet_is_python_that_calls_the_tested_conversion():
    section = _section("## For planners")
    (code,) = re.findall(r"```python\n(.*?)```", section, re.S)
    tree = ast.parse(code)  # a syntax error fails here
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call)
             and getattr(n.func, "id", "") == "to_collision_objects"]
    assert calls, "the snippet shows the conversion"
    parameters = inspect.signature(to_collision_objects).parameters
    for call in calls:
        assert len(call.args) <= len(parameters)
        assert all(k.arg in parameters for k in call.keywords)
    assert '"/modeler/objects"' in code and len(code.splitlines()) <= 25
