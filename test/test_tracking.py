"""Stable object ids across frames (geomodel_ros.core.tracking).

Expectations come from the tracker's stated rules (gates, retirement after more than
``max_missed`` missed frames, monotonic ids) and from the statistics of an exponential
moving average: for i.i.d. noise of std s, ``y = a y_prev + (1 - a) x`` has the stationary
std ``s * sqrt((1 - a) / (1 + a))``.
"""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from geomodel_ros.core.errors import InputError
from geomodel_ros.core.params import ParameterError
from geomodel_ros.core.primitives import Primitive, PrimitiveType
from geomodel_ros.core.tracking import (TRACKER_PARAMETERS, Tracker, TrackerConfig,
                                        measure_update_cost)

NOISE = 1e-3  # [m] std of the simulated centre and size noise


def prim(kind, center, dims, rot=None, label=0) -> Primitive:
    return Primitive(label, kind, np.asarray(center, float),
                     np.eye(3) if rot is None else np.asarray(rot, float), dict(dims), 500, 1e-3)


#: Five objects of different types and sizes, 30 cm apart (sizes [m]).
SCENE = [
    ("cuboid", (0.0, 0.0, 1.0), {"length": 0.10, "width": 0.06, "height": 0.04}),
    ("cylinder", (0.3, 0.0, 1.0), {"radius": 0.03, "height": 0.12}),
    ("sphere", (-0.3, 0.0, 1.0), {"radius": 0.04}),
    ("cone", (0.0, 0.3, 1.0), {"radius": 0.03, "height": 0.10}),
    ("plane", (0.0, -0.3, 1.2), {"length": 1.0, "width": 0.6}),
]


def noisy(rng, kind, center, dims, rot=None, label=0, sigma=NOISE) -> Primitive:
    return prim(kind, np.asarray(center) + rng.normal(0.0, sigma, 3),
                {k: v + float(rng.normal(0.0, sigma)) for k, v in dims.items()}, rot, label)


def run_static(smoothing: float, frames: int, seed: int = 1):
    """Track SCENE with noise, inputs shuffled and relabelled; outputs per scene index."""
    rng = np.random.default_rng(seed)
    tracker = Tracker(TrackerConfig(smoothing=smoothing))
    per_object = [[] for _ in SCENE]
    results = []
    for _ in range(frames):
        order = rng.permutation(len(SCENE))
        frame = [noisy(rng, *SCENE[i], label=int(j)) for j, i in enumerate(order)]
        res = tracker.update(frame)
        results.append(res)
        for out, i in zip(res.objects, order):
            per_object[i].append(out)
    return per_object, results


@pytest.mark.parametrize("smoothing", [0.0, 0.8])
def test_static_noisy_scene_keeps_every_id_for_30_frames(smoothing):
    per_object, results = run_static(smoothing, 30)
    first_ids = [objs[0].id for objs in per_object]
    assert sorted(first_ids) == [0, 1, 2, 3, 4]
    for objs, tid in zip(per_object, first_ids):
        assert [o.id for o in objs] == [tid] * 30
    assert results[0].new_ids == (0, 1, 2, 3, 4)
    assert all(r.new_ids == () and r.deleted_ids == () for r in results[1:])


def test_output_keeps_input_order_and_types():
    rng = np.random.default_rng(3)
    tracker = Tracker()
    for _ in range(3):
        frame = [noisy(rng, *obj) for obj in SCENE]
        res = tracker.update(frame)
        assert [o.type for o in res.objects] == [p.type for p in frame]


def test_without_smoothing_the_geometry_is_passed_through_unchanged():
    rng = np.random.default_rng(4)
    tracker = Tracker(TrackerConfig(smoothing=0.0))
    for _ in range(5):
        frame = [noisy(rng, *obj) for obj in SCENE]
        for out, inp in zip(tracker.update(frame).objects, frame):
            assert np.array_equal(out.center, inp.center)
            assert np.array_equal(out.rotation, inp.rotation)
            assert out.dimensions == inp.dimensions


def _size_series(per_object, i):
    return np.array([[o.dimensions[k] for k in SCENE[i][2]] for o in per_object[i]])


def test_smoothing_shrinks_the_size_spread_of_a_static_scene():
    raw, _ = run_static(0.0, 30)
    smooth, _ = run_static(0.8, 30)  # same seed: the same noisy inputs
    for i in range(len(SCENE)):
        assert np.all(_size_series(smooth, i).std(axis=0) < _size_series(raw, i).std(axis=0))


def test_smoothing_shrinks_the_noise_by_the_moving_average_factor():
    a, frames, burn_in = 0.8, 400, 40  # a**burn_in ~ 1e-4: the start has faded out
    smooth, _ = run_static(a, frames)
    expected = NOISE * math.sqrt((1.0 - a) / (1.0 + a))  # = NOISE / 3
    sizes = np.concatenate([(_size_series(smooth, i)[burn_in:] - list(SCENE[i][2].values()))
                            .ravel() for i in range(len(SCENE))])
    centres = np.concatenate([(np.array([o.center for o in smooth[i]])[burn_in:]
                               - SCENE[i][1]).ravel() for i in range(len(SCENE))])
    # ~15 series of ~360 correlated samples (~40 independent each): rms within ~5 % + bias.
    assert np.sqrt(np.mean(sizes ** 2)) == pytest.approx(expected, rel=0.15)
    assert np.sqrt(np.mean(centres ** 2)) == pytest.approx(expected, rel=0.15)


def test_removed_object_is_deleted_after_max_missed_frames_and_never_before():
    rng = np.random.default_rng(5)
    tracker = Tracker(TrackerConfig(max_missed=5))
    ids = [o.id for o in tracker.update([noisy(rng, *obj) for obj in SCENE]).objects]
    gone = ids[1]  # the cylinder leaves after frame 9
    for frame in range(1, 30):
        present = SCENE if frame < 10 else SCENE[:1] + SCENE[2:]
        res = tracker.update([noisy(rng, *obj) for obj in present])
        missed = max(0, frame - 9)  # frames 10, 11, ... are misses number 1, 2, ...
        if missed == 6:  # more than max_missed = 5
            assert res.deleted_ids == (gone,)
        else:
            assert res.deleted_ids == ()
        assert (gone in tracker.active_ids) == (missed <= 5)
        if frame >= 10:
            assert gone not in [o.id for o in res.objects]  # no other object took its id


def test_max_missed_zero_retires_at_the_first_miss():
    tracker = Tracker(TrackerConfig(max_missed=0))
    tracker.update([prim(*SCENE[0])])
    assert tracker.update([]).deleted_ids == (0,)
    assert tracker.active_ids == ()


def test_new_object_gets_a_new_id_never_used_before():
    rng = np.random.default_rng(6)
    tracker = Tracker()
    seen: set[int] = set()
    for frame in range(20):
        present = SCENE[:4] if frame < 12 else SCENE
        res = tracker.update([noisy(rng, *obj) for obj in present])
        ids = [o.id for o in res.objects]
        if frame == 12:
            assert ids[:4] == sorted(seen)
            assert ids[4] not in seen and ids[4] > max(seen)
            assert res.new_ids == (ids[4],)
        seen.update(ids)
    assert seen == {0, 1, 2, 3, 4}


def test_ids_are_never_reused_after_retirement():
    tracker = Tracker(TrackerConfig(max_missed=1))
    cuboid = prim(*SCENE[0])
    assert [o.id for o in tracker.update([cuboid]).objects] == [0]
    tracker.update([])
    assert tracker.update([]).deleted_ids == (0,)
    # The same object comes back at the same place: a new track, not the retired id.
    assert [o.id for o in tracker.update([cuboid]).objects] == [1]
    assert tracker.reset() == (1,)
    assert [o.id for o in tracker.update([cuboid]).objects] == [2]


def test_object_back_within_max_missed_keeps_its_id():
    tracker = Tracker(TrackerConfig(max_missed=3))
    cuboid = prim(*SCENE[0])
    tracker.update([cuboid])
    for _ in range(3):
        assert tracker.update([]).deleted_ids == ()
    assert [o.id for o in tracker.update([cuboid]).objects] == [0]


@pytest.mark.parametrize("smoothing", [0.0, 0.8])
def test_object_moving_2cm_per_frame_keeps_its_id_without_lag(smoothing):
    rng = np.random.default_rng(7)
    tracker = Tracker(TrackerConfig(smoothing=smoothing))
    kind, start, dims = SCENE[0]
    for frame in range(30):
        moving = noisy(rng, kind, np.asarray(start) + [0.02 * frame, 0.0, 0.0], dims)
        still = noisy(rng, *SCENE[2])
        res = tracker.update([moving, still])
        assert [o.id for o in res.objects] == [0, 1]
        # 2 cm per frame is above static_motion (1 cm): never averaged, so no lag.
        assert np.array_equal(res.objects[0].center, moving.center)


def test_neighbours_of_different_types_do_not_swap_ids():
    # A cuboid and a cylinder of the same overall size (diagonal of the extents) 4 cm apart:
    # a type change would be allowed where either stands, but same-type matches win.
    box = {"length": 0.06, "width": 0.05, "height": 0.04}
    height = math.sqrt(0.06 ** 2 + 0.05 ** 2 + 0.04 ** 2 - 0.06 ** 2)
    cyl = {"radius": 0.03, "height": height}
    a, b = np.array([0.0, 0.0, 1.0]), np.array([0.04, 0.0, 1.0])
    rng = np.random.default_rng(8)
    tracker = Tracker()
    for frame in range(30):
        swapped = frame % 2 == 1  # each stands where the other stood a frame before
        res = tracker.update([noisy(rng, "cuboid", b if swapped else a, box),
                              noisy(rng, "cylinder", a if swapped else b, cyl)])
        assert [o.id for o in res.objects] == [0, 1]
        assert [o.type for o in res.objects] == ["cuboid", "cylinder"]


def test_type_flicker_keeps_the_id_and_takes_the_new_type():
    rng = np.random.default_rng(9)
    tracker = Tracker()
    kind, center, dims = SCENE[0]
    sequence = ["cuboid", "unknown", "cuboid", "unknown", "unknown", "cuboid"]
    for t in sequence:
        obj = noisy(rng, kind, center, dims) if t == "cuboid" else prim("unknown", center, {})
        res = tracker.update([obj, noisy(rng, *SCENE[1])])
        assert [o.id for o in res.objects] == [0, 1]
        assert res.objects[0].type == t


def test_other_type_of_another_size_at_the_same_place_gets_a_new_id():
    tracker = Tracker()
    tracker.update([prim(*SCENE[0])])  # a 10 x 6 x 4 cm box
    res = tracker.update([prim("cylinder", SCENE[0][1], {"radius": 0.1, "height": 0.3})])
    assert [o.id for o in res.objects] == [1]


@pytest.mark.parametrize("ratio, same_id", [(1.05, True), (1.15, False)])
def test_type_change_needs_the_overall_size_to_agree_tightly(ratio, same_id):
    # Type change allowed for a size ratio up to 1.5 ** 0.25 = 1.107 (a quarter of the
    # log-size gate); a cylinder whose diagonal is `ratio` times the box's, at its centre.
    kind, center, dims = SCENE[0]
    diagonal = ratio * math.sqrt(sum(v * v for v in dims.values()))
    cyl = {"radius": 0.03, "height": math.sqrt(diagonal ** 2 - 0.06 ** 2)}
    tracker = Tracker()
    tracker.update([prim(kind, center, dims)])
    assert [o.id for o in tracker.update([prim("cylinder", center, cyl)]).objects] == [
        0 if same_id else 1]


def test_other_type_a_little_away_gets_a_new_id():
    # Type change allowed within a quarter of the centre gate, 0.5 * 0.1166 + 0.03 = 8.8 cm.
    tracker = Tracker()
    tracker.update([prim(*SCENE[0])])
    res = tracker.update([prim("unknown", np.asarray(SCENE[0][1]) + [0.03, 0.0, 0.0], {})])
    assert [o.id for o in res.objects] == [1]


def test_same_type_of_very_different_size_gets_a_new_id():
    tracker = Tracker()
    tracker.update([prim("sphere", (0, 0, 1), {"radius": 0.04})])
    res = tracker.update([prim("sphere", (0, 0, 1), {"radius": 0.07})])  # 1.75 > 1.5
    assert [o.id for o in res.objects] == [1]


def _tilted(angle):
    return Rotation.from_rotvec([angle, 0.0, 0.0]).as_matrix()


@pytest.mark.parametrize("change, same_id", [
    ({"shift": (0.2, 0.1, 0.0)}, True),       # slides in its plane (occlusion): same desk
    ({"shift": (0.0, 0.0, 0.05)}, False),     # 5 cm along the normal: another plane
    ({"angle": math.radians(8)}, True),       # normal within the 15 deg gate
    ({"angle": math.radians(30)}, False),     # a different plane through the same centre
])
def test_planes_match_by_normal_and_offset(change, same_id):
    kind, center, dims = SCENE[4]  # 1 x 0.6 m, normal z: centre gate 0.61 m
    tracker = Tracker()
    tracker.update([prim(kind, center, dims)])
    moved = prim(kind, np.asarray(center) + change.get("shift", (0, 0, 0)), dims,
                 _tilted(change.get("angle", 0.0)))
    assert [o.id for o in tracker.update([moved]).objects] == [0 if same_id else 1]


def test_cuboid_axes_permuted_between_frames_keep_pose_and_extents_with_smoothing():
    rng = np.random.default_rng(10)
    base = Rotation.from_euler("zyx", [0.4, -0.2, 0.1]).as_matrix()
    dims = np.array([0.10, 0.06, 0.04])
    tracker = Tracker(TrackerConfig(smoothing=0.8))
    group = Rotation.create_group("O").as_matrix()  # the 24 rotations of a cube
    group = np.round(group)
    for frame in range(40):
        perm = np.eye(3) if frame == 0 else group[rng.integers(len(group))]
        rot = base @ Rotation.from_rotvec(rng.normal(0, math.radians(1), 3)).as_matrix() @ perm
        shown = np.abs(perm).T @ (dims + rng.normal(0, NOISE, 3))  # extents along rot's axes
        out = tracker.update([prim("cuboid", (0, 0, 1),
                                   dict(zip(("length", "width", "height"), shown)), rot)])
        (obj,) = out.objects
        assert obj.id == 0
        angle = Rotation.from_matrix(base.T @ obj.rotation).magnitude()
        assert angle < math.radians(4)  # raw noise: 1 deg per axis, 1.6 deg on average
        got = [obj.dimensions[k] for k in ("length", "width", "height")]
        assert np.allclose(got, dims, atol=5 * NOISE)


def test_rotation_smoothing_shrinks_the_angular_noise():
    rng = np.random.default_rng(11)
    base = Rotation.from_euler("zyx", [0.3, 0.2, -0.1]).as_matrix()
    a, sigma = 0.8, math.radians(1.0)
    tracker = Tracker(TrackerConfig(smoothing=a))
    raw, smooth = [], []
    for _ in range(300):
        noise = Rotation.from_rotvec(rng.normal(0, sigma, 3))
        rot = base @ noise.as_matrix()
        (obj,) = tracker.update([prim("cylinder", (0, 0, 1), SCENE[1][2], rot)]).objects
        raw.append(noise.magnitude())
        smooth.append(Rotation.from_matrix(base.T @ obj.rotation).magnitude())
    ratio = np.sqrt(np.mean(np.square(smooth[40:]))) / np.sqrt(np.mean(np.square(raw[40:])))
    assert ratio == pytest.approx(math.sqrt((1 - a) / (1 + a)), rel=0.2)
    assert np.allclose(obj.rotation.T @ obj.rotation, np.eye(3), atol=1e-9)


def test_enum_and_string_types_match_each_other():
    Kind = PrimitiveType
    tracker = Tracker(TrackerConfig(smoothing=0.5))
    kind, center, dims = SCENE[0]
    first = tracker.update([prim(Kind.CUBOID, center, dims)]).objects[0]
    assert first.type is Kind.CUBOID
    assert tracker.update([prim("cuboid", center, dims)]).objects[0].id == first.id
    assert tracker.update([prim(Kind.UNKNOWN, center, {})]).objects[0].id == first.id


def test_input_ids_are_ignored():
    tracker = Tracker()
    kind, center, dims = SCENE[0]
    tracker.update([prim(kind, center, dims, label=7)])
    assert tracker.update([prim(kind, center, dims, label=3)]).objects[0].id == 0


def test_empty_frames_are_fine():
    tracker = Tracker(TrackerConfig(max_missed=1))
    assert tracker.update([]).objects == []
    tracker.update([prim(*SCENE[0])])
    assert tracker.update([]).deleted_ids == ()
    assert tracker.update([]).deleted_ids == (0,)


def test_config_has_one_definition_and_validates():
    fields = {f.name: f.default for f in dataclasses.fields(TrackerConfig)}
    assert fields == {s.name: s.default for s in TRACKER_PARAMETERS}
    with pytest.raises(ParameterError, match="max_missed"):
        TrackerConfig(max_missed=-1)
    with pytest.raises(ParameterError, match="smoothing"):
        TrackerConfig(smoothing=1.0)
    with pytest.raises(ParameterError, match="integer"):
        TrackerConfig(max_missed=2.5)
    with pytest.raises(dataclasses.FrozenInstanceError):
        TrackerConfig().smoothing = 0.5


def test_measure_update_cost_runs():
    assert measure_update_cost(n_objects=4, frames=5) > 0.0


@pytest.mark.parametrize("bad", [
    {"center": np.array([0.0, np.nan, 1.0])},
    {"center": np.zeros(2)},
    {"rotation": np.full((3, 3), np.inf)},
    {"dimensions": {"radius": float("nan")}},
])
def test_invalid_primitives_raise_and_leave_the_tracker_unchanged(bad):
    tracker = Tracker()
    tracker.update([prim(*SCENE[2])])
    broken = dataclasses.replace(prim(*SCENE[2]), **bad)
    with pytest.raises(InputError, match="primitive 1"):
        tracker.update([prim(*SCENE[2]), broken])
    assert tracker.active_ids == (0,)
    assert [o.id for o in tracker.update([prim(*SCENE[2])]).objects] == [0]


def test_tracking_imports_without_ros():
    code = ("import sys, geomodel_ros.core.tracking; "
            "ros = ('rclpy', 'std_msgs', 'geometry_msgs', 'visualization_msgs', 'sensor_msgs'); "
            "sys.exit(any(m.split('.')[0] in ros for m in sys.modules))")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


@pytest.mark.parametrize("index, flip", [
    (1, np.diag([1.0, -1.0, -1.0])),   # cylinder: the axis has no direction
    (4, np.diag([-1.0, -1.0, 1.0])),   # plane: the in-plane axes have no direction
])
def test_flipped_axes_of_symmetric_shapes_keep_the_tracks_axes_with_smoothing(index, flip):
    kind, center, dims = SCENE[index]
    base = Rotation.from_euler("zyx", [0.5, 0.1, 0.2]).as_matrix()
    tracker = Tracker(TrackerConfig(smoothing=0.8))
    for frame in range(6):
        rot = base @ flip if frame % 2 else base
        (obj,) = tracker.update([prim(kind, center, dims, rot)]).objects
        assert obj.id == 0
        assert np.allclose(obj.rotation, base, atol=1e-9)
        assert np.allclose(np.abs(obj.rotation.T @ rot), np.eye(3), atol=1e-9)  # same shape
