"""A few hundred fuzz cases of each layer stay in the suite: core, command line, running node.

The 10,000-case runs are benchmark commands (``python -m geomodel_ros.tools.fuzz core|cli
--cases 10000``, ``python -m geomodel_ros.tools.fuzz_node --cases 10000``; figures in
BENCHMARKS.md).  Here the same harnesses run with a fixed seed and a small budget over the
whole range of magnitudes (1e-6 .. 1e9 m), and must see no crash and no non-finite output.
The last tests pin two crashes the fuzzers found (a garbage return at 1e9 m overflowed
the voxel arithmetic; a 1.5 mm object 10 m away had a face with no second direction).
"""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from sensor_msgs.msg import PointField
from std_msgs.msg import Header

from geomodel_ros.core import modeling
from geomodel_ros.core.errors import InputError
from geomodel_ros.tools import fuzz
from msg_adapters.malformed import FieldSpec, pack_points, raw_cloud
from msg_adapters.pointcloud2 import PointCloud2Error, cloud_to_xyz

#: In-suite magnitudes: the whole drawn range [m].
SUITE_MAGNITUDE = 1e9


# ------------------------------------------------------------------ the fuzz harness itself
def test_fuzz_counts_a_raising_core_as_crashes(monkeypatch):
    def broken(*_args, **_kwargs):
        raise RuntimeError("boom")

    monkeypatch.setattr(modeling, "model_scene", broken)
    report = fuzz.fuzz("core", 5, seed=1)
    assert report["cases"] == 5 and report["crash"] == 5 and report["ok"] == 0
    assert report["crash_kinds"] == {"RuntimeError in test_fuzz.broken": 5}


def test_fuzz_counts_non_finite_outputs_and_clear_errors(monkeypatch):
    real = modeling.model_scene
    did = {"clear_error": 0, "non_finite": 0}
    last = [None]  # the points of the previous call: an organized case is modeled twice

    def lying(points, *_args, **_kwargs):
        if len(points) % 2:
            did["clear_error"] += 1
            raise InputError("no finite points")
        if points is not last[0]:
            did["non_finite"] += 1
        last[0] = points
        _, result = real(np.zeros((0, 3)), rng=0)  # a genuine (empty) result
        result.objects.append(_nan_primitive())
        return np.zeros(len(points), dtype=np.int64), result

    monkeypatch.setattr(modeling, "model_scene", lying)
    report = fuzz.fuzz("core", 20, seed=2)
    assert report["cases"] == 20 and report["ok"] == report["crash"] == 0
    assert min(did.values()) > 0
    assert (report["clear_error"], report["non_finite"]) == (did["clear_error"],
                                                             did["non_finite"])


def _nan_primitive():
    from geomodel_ros.core.primitives import Primitive

    return Primitive(1, "sphere", np.array([0.0, 0.0, np.nan]), np.eye(3), {"radius": 0.1},
                     10, 0.0)


# ------------------------------------------------------------------ malformed messages
def test_pack_points_writes_declared_fields_in_either_byte_order():
    pts = np.array([[1.0, -2.0, 0.5]])
    little = [FieldSpec("x", 0, PointField.FLOAT32), FieldSpec("z", 4, PointField.FLOAT64),
              FieldSpec("ring", 12, PointField.UINT16, 2)]
    assert pack_points(pts, little, 18) == (struct.pack("<fdHH", 1.0, 0.5, 0, 0) + b"\0\0")
    big = pack_points(pts, [FieldSpec("y", 2, PointField.FLOAT32)], 6, big_endian=True)
    assert big == b"\0\0" + struct.pack(">f", -2.0)


def test_pack_points_overlaps_overwrite_and_fields_past_the_step_are_cut():
    pts = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    fields = [FieldSpec("x", 0, PointField.FLOAT32), FieldSpec("y", 2, PointField.FLOAT32),
              FieldSpec("z", 6, PointField.FLOAT32), FieldSpec("q", 0, 99)]
    data = pack_points(pts, fields, 8)
    assert len(data) == 16
    for i, (x, y, z) in enumerate(pts):
        row = data[8 * i:8 * i + 8]
        assert row[:2] == struct.pack("<f", x)[:2]  # x's low half survives
        assert row[2:6] == struct.pack("<f", y)  # y overwrote x's high half
        assert row[6:] == struct.pack("<f", z)[:2]  # z cut at point_step
    ints = pack_points([[np.nan, 1e20, -3.0]], [FieldSpec("x", 0, PointField.INT16),
                                                 FieldSpec("y", 2, PointField.INT16),
                                                 FieldSpec("z", 4, PointField.INT16)], 6)
    assert ints == struct.pack("<hhh", 0, 0, -3)


def test_raw_cloud_keeps_every_lie_and_the_adapter_rejects_it():
    fields = [FieldSpec(n, 4 * i, PointField.FLOAT32) for i, n in enumerate("xyz")]
    data = pack_points([[0.0, 0.0, 1.0]] * 4, fields, 12)
    msg = raw_cloud(Header(frame_id="f"), fields, height=1, width=5, point_step=12,
                    row_step=60, data=data)
    assert (msg.width, msg.row_step, len(msg.data)) == (5, 60, 48)
    with pytest.raises(PointCloud2Error, match="48 bytes, expected"):
        cloud_to_xyz(msg)
    msg.width, msg.row_step = 4, 48
    assert np.array_equal(cloud_to_xyz(msg), [[0.0, 0.0, 1.0]] * 4)


# ------------------------------------------------------------------ a few hundred cases each
def test_core_fuzz_no_crash_no_non_finite():
    report = fuzz.fuzz("core", 300, seed=0, max_magnitude=SUITE_MAGNITUDE)
    assert report["cases"] == 300
    assert report["crash"] == 0, report["crash_examples"]
    assert report["non_finite"] == 0
    assert report["ok"] > 0


def test_cli_fuzz_no_crash_no_non_finite():
    report = fuzz.fuzz("cli", 200, seed=0, max_magnitude=SUITE_MAGNITUDE)
    assert report["cases"] == 200
    assert report["crash"] == 0, report["crash_examples"]
    assert report["non_finite"] == 0
    assert report["ok"] > 0 and report["clear_error"] > 0  # damaged files are refused


def test_node_fuzz_survives_malformed_messages_and_keeps_answering():
    from geomodel_ros.tools import fuzz_node

    cases, probe_every = 300, 100
    r = fuzz_node.run(cases, seed=0, rate=60.0, probe_every=probe_every)
    assert r["node_crashes"] == 0 and r["node_exit_status_on_sigint"] == 0, r["log"]
    assert r["cases"] == cases
    assert r["probes_sent"] == cases // probe_every + 1 == r["probes_answered"], \
        r["probe_problems"]
    assert r["malformed_outputs"] == 0, r["malformed_output_kinds"]
    assert r["non_finite_reconstructions"] == 0
    assert r["log"]["tracebacks"] == 0 and r["log"]["errors"] == 0
    frames = r["frames"]
    # reliable QoS: every message arrives, and every frame is accounted for
    assert frames["received"] == cases + r["probes_sent"]
    assert frames["processed"] + frames["dropped"] + frames["failed"] == frames["received"]
    assert frames["failed"] >= 1 and r["malformed_messages"] >= 1
    assert set(r["mutations"]) == set(fuzz_node.MUTATIONS)


# ------------------------------------------------------------------ crashes the fuzzers found
def test_core_on_a_tiny_object_far_away_does_not_crash():
    rng = np.random.default_rng(0)
    direction = np.array([0.72, 0.16, 0.5]) / np.linalg.norm([0.72, 0.16, 0.5])
    points = rng.uniform(-0.75e-3, 0.75e-3, (274, 3)) + 10.0 * direction
    labels, result = modeling.model_scene(points, rng=0)
    assert labels.shape == (len(points),)
    for o in result.objects:
        assert all(math.isfinite(v) for v in [*o.center, *o.dimensions.values(), o.rmse])


def _tabletop_with_a_garbage_return() -> np.ndarray:
    rng = np.random.default_rng(0)
    table = np.c_[rng.uniform(-0.5, 0.5, (2000, 2)), np.ones(2000)]
    return np.r_[table, [[1e9, 1e9, 1e9]]]


def test_core_on_coordinates_near_1e9_gives_finite_output_or_a_clear_error():
    points = _tabletop_with_a_garbage_return()
    try:
        labels, result = modeling.model_scene(points, rng=0)
    except InputError as exc:
        assert str(exc)
        return
    assert labels.shape == (len(points),)
    assert labels[-1] == -1  # the garbage return belongs to no object
    for o in result.objects:
        assert all(math.isfinite(v) for v in [*o.center, *o.dimensions.values()])


def test_cli_on_coordinates_near_1e9_succeeds_or_prints_one_error_line(tmp_path):
    assert fuzz.run_cli_case(_tabletop_with_a_garbage_return(), ".npy", "none",
                             tmp_path) in ("ok", "clear_error")
