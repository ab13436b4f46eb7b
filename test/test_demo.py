"""`make demo` in a reduced form: a small scene through the node process over DDS."""

import json
import re
from pathlib import Path

import numpy as np

from geomodel_ros.tools.demo import run_demo

#: MoveIt SolidPrimitive name and its dimensions [m] per ground-truth type (the published
#: contract of Primitive.msg: BOX [x, y, z], CYLINDER/CONE [height, radius], SPHERE [r];
#: a plane is a BOX of zero thickness whose in-plane size depends on the view).
MOVEIT = {"cuboid": ("BOX", lambda d: sorted([d["length"], d["width"], d["height"]])),
          "cylinder": ("CYLINDER", lambda d: [d["height"], d["radius"]]),
          "sphere": ("SPHERE", lambda d: [d["radius"]]),
          "plane": ("BOX", None)}
#: A row of the typed-objects table: id, type, shape, "a x b x c" [mm], "(x, y, z)" [m].
ROW = re.compile(r"^\s+(\d+)\s+([a-z]+)\s+([A-Z]+|-)\s+([\d.]+(?: x [\d.]+)*|-)\s+"
                 r"\(([-+\d., ]+)\)$")
#: Size tolerance [mm]: the method's error on the clean tiny_box (0.75 mm at most) plus the
#: table's rounding to 0.1 mm.
SIZE_TOL_MM = 1.0
#: Centre tolerance [m] (the tiny_box cuboid's centre is within 0.4 mm; printed to 1 mm).
CENTER_TOL = 0.0015


def typed_rows(out: str) -> list[tuple[int, str, str, list[float], np.ndarray]]:
    """Rows of the typed-objects table printed after ``typed objects on /modeler/objects``."""
    head = out.index("typed objects on /modeler/objects")
    rows = []
    for line in out[head:].splitlines()[2:]:
        m = ROW.match(line)
        if m is None:
            break
        dims = [] if m[4] == "-" else [float(v) for v in m[4].split(" x ")]
        rows.append((int(m[1]), m[2], m[3], dims,
                     np.array([float(v) for v in m[5].split(",")])))
    return rows


def test_reduced_demo_models_every_frame_and_writes_pictures(tmp_path, capsys):
    code = run_demo(tmp_path / "demo", scenes=("tiny_box",), frames=2, rate=4.0)
    out = capsys.readouterr().out
    assert code == 0, out
    assert "2/2 frames modeled" in out
    assert "2/2 objects found with the right type" in out
    for name in ("segments.png", "reconstruction.png", "overlay.png"):
        png = Path(tmp_path / "demo" / "tiny_box" / name)
        assert png.exists() and png.stat().st_size > 10_000

    # the typed objects, beside the markers: one row per ground-truth object, of its type,
    # MoveIt shape and size, at its place
    truth = json.loads((tmp_path / "demo" / "scenes_bag.json").read_text())
    objects = truth["scenes"][0]["objects"]
    assert "typed objects on /modeler/objects: 2/2 frames" in out, out
    rows = typed_rows(out)
    assert sorted(r[1] for r in rows) == sorted(o["type"] for o in objects), out
    assert len({r[0] for r in rows}) == len(rows)  # ids unique
    for obj in objects:
        (row,) = [r for r in rows if r[1] == obj["type"]]
        shape, size = MOVEIT[obj["type"]]
        assert row[2] == shape, row
        if size is None:  # plane: zero thickness
            assert len(row[3]) == 3 and row[3][2] == 0.0
            continue
        dims = sorted(row[3]) if shape == "BOX" else row[3]
        np.testing.assert_allclose(dims, 1000 * np.asarray(size(obj["dimensions"])),
                                   atol=SIZE_TOL_MM)
        assert np.linalg.norm(row[4] - obj["center"]) < CENTER_TOL, (row, obj)


def test_demo_fails_when_no_typed_objects_arrive(tmp_path, capsys, monkeypatch):
    """Markers without typed objects are not a complete run: exit code 1."""
    import geomodel_ros.tools.demo as demo

    monkeypatch.setattr(demo, "OBJECTS_TOPIC", "/modeler/no_such_topic")
    code = run_demo(tmp_path / "demo", scenes=("tiny_box",), frames=1, rate=4.0,
                    pictures=False, timeout_s=2.0)
    out = capsys.readouterr().out
    assert code == 1, out
    assert "typed objects for 0" in out
    assert "typed objects on /modeler/no_such_topic: 0/1 frames" in out
