"""Extreme coordinates and huge clouds: the ``max_range`` gate and ``max_points`` bound.

Points beyond ``max_range`` from the sensor origin, rows at the origin (a driver's "no
return") and non-finite rows must be dropped like invalid points (label -1, rows kept)
before any voxel arithmetic, so a scene with garbage appended models exactly like the scene
without it. A magnitude that still does not fit the
voxel grids raises :class:`InputError` naming the parameters (never an overflow). Above
``max_points`` valid points the scene is averaged on a voxel grid first; every input row
still gets a label, constant within each voxel.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from geomodel_ros.core.errors import InputError
from geomodel_ros.core.faces import count_voxels, voxelize
from geomodel_ros.core.input import DOWNSAMPLE_GROWTH, in_range, origin_rows
from geomodel_ros.core.modeling import model_objects, model_scene
from geomodel_ros.core.params import PARAMETERS, ModelingParams, ParameterError
from geomodel_ros.core.primitives import PrimitiveType
from geomodel_ros.core.segmentation import segment_scene
from geomodel_ros.tools.bench_memory import FLOOR_Z, floor_with_boxes
from geomodel_ros.tools.cli import main
from geomodel_ros.tools.synth import render_scene

SCENE = "tiny_box"
RANGE = {p.name: (p.low, p.high) for p in PARAMETERS}["max_range"]


@pytest.fixture(scope="module")
def scene():
    return render_scene(SCENE)


@pytest.fixture(scope="module")
def near_result(scene):
    """``model_scene`` on the clean scene (labels, objects as dicts)."""
    labels, result = model_scene(scene.points)
    return labels, [o.to_dict() for o in result.objects]


def _garbage(rng: np.random.Generator, n: int) -> np.ndarray:
    """Rows that must all be dropped: far, huge, overflowing, NaN and inf (n, 3) [m]."""
    far = rng.normal(size=(n, 3))
    far *= rng.choice([21.0, 1e3, 1e9, 1e200], size=(n, 1)) / np.linalg.norm(far, axis=1,
                                                                            keepdims=True)
    far[0] = [np.nan, 0.1, 0.5]
    far[1] = [np.inf, 0.0, 0.0]
    far[2] = [0.0, -np.inf, 0.3]
    far[3] = [1e308, 1e308, 1e308]      # its squared norm overflows
    far[4] = [np.nan, np.nan, np.nan]
    return far


def _interleave(near: np.ndarray, extra: np.ndarray, rng: np.random.Generator
                ) -> tuple[np.ndarray, np.ndarray]:
    """``near`` with ``extra`` rows inserted at random places; mask of the near rows."""
    n = len(near) + len(extra)
    is_near = np.zeros(n, dtype=bool)
    is_near[np.sort(rng.choice(n, len(near), replace=False))] = True
    out = np.empty((n, 3))
    out[is_near] = near
    out[~is_near] = extra
    return out, is_near


# ---------------------------------------------------------------------------------------
# Coordinates around 1e9 m
# ---------------------------------------------------------------------------------------

def test_cli_on_a_cloud_of_1e9_coordinates_exits_0_and_says_the_points_were_ignored(
        tmp_path, capsys):
    pts = np.random.default_rng(0).normal(size=(2000, 3)) * 1e9
    np.save(tmp_path / "cloud.npy", pts)
    out_json = tmp_path / "o.json"
    code = main(["model", str(tmp_path / "cloud.npy"), "--json", str(out_json)])
    out, err = capsys.readouterr()
    assert code == 0
    assert "Traceback" not in err
    assert err.splitlines() == [
        "geomodel: warning: 2000 of 2000 points are farther than max_range = 20 m from the "
        "origin and were ignored"]
    assert out.startswith("0 objects (no objects)")
    assert json.loads(out_json.read_text())["objects"] == []


def test_cli_reports_a_grid_too_large_as_one_error_line(tmp_path, capsys):
    pts = np.random.default_rng(1).uniform(-5e4, 5e4, size=(500, 3))   # all within 1e5 m
    np.save(tmp_path / "cloud.npy", pts)
    code = main(["model", str(tmp_path / "cloud.npy"), "--json", str(tmp_path / "o.json"),
                 "--set", "max_range=1e5", "--set", "seg_voxel_size=0.0005",
                 "--set", "noise_model=fixed"])
    _, err = capsys.readouterr()
    assert code == 2
    assert "Traceback" not in err
    (line,) = err.splitlines()
    assert line.startswith("geomodel: error: points too large for a voxel grid")
    assert "max_range" in line and "seg_voxel_size" in line


def test_model_scene_and_model_objects_ignore_1e9_coordinates():
    pts = np.random.default_rng(2).normal(size=(2000, 3)) * 1e9
    labels, result = model_scene(pts)
    assert labels.shape == (2000,) and np.all(labels == -1)
    assert result.objects == []
    assert model_objects(pts, np.zeros(2000, dtype=np.int64)).objects == []
    assert np.all(segment_scene(pts).labels == -1)


# ---------------------------------------------------------------------------------------
# Far and non-finite rows change nothing for the near scene
# ---------------------------------------------------------------------------------------

def test_far_and_non_finite_rows_get_label_minus_one_and_leave_the_objects_unchanged(
        scene, near_result):
    rng = np.random.default_rng(3)
    pts, is_near = _interleave(scene.points, _garbage(rng, 3000), rng)
    labels, result = model_scene(pts)
    near_labels, near_objects = near_result
    assert np.all(labels[~is_near] == -1)
    np.testing.assert_array_equal(labels[is_near], near_labels)
    assert [o.to_dict() for o in result.objects] == near_objects
    assert {o["type"] for o in near_objects} == {"plane", "cuboid"}   # a real scene


def test_far_rows_labelled_as_an_object_do_not_change_model_objects(scene):
    rng = np.random.default_rng(4)
    garbage = _garbage(rng, 500)
    pts, is_near = _interleave(scene.points, garbage, rng)
    labels = np.full(len(pts), -1, dtype=np.int64)
    labels[is_near] = scene.labels
    # The garbage claims to belong to the box (id 1) and to a third object (id 2).
    labels[~is_near] = rng.choice([1, 2], size=len(garbage))
    got = model_objects(pts, labels).objects
    want = model_objects(scene.points, scene.labels).objects
    assert [o.to_dict() for o in got] == [o.to_dict() for o in want]
    assert [o.id for o in got] == [0, 1]


def test_organized_cloud_keeps_its_shape_with_far_pixels(scene, near_result):
    org = scene.organized.copy()
    holes = np.flatnonzero(~scene.valid_mask.ravel())
    assert len(holes) > 100                      # the scene has background pixels to fill
    flat = org.reshape(-1, 3)
    flat[holes] = [0.0, 0.0, 1e9]                # far instead of NaN
    flat[holes[::2], 2] = -50.0
    labels, result = model_scene(flat, organized_shape=org.shape[:2])
    near_labels, near_objects = near_result
    assert labels.shape == (org.shape[0] * org.shape[1],)
    assert np.all(labels[holes] == -1)
    np.testing.assert_array_equal(labels[scene.valid_mask.ravel()], near_labels)
    assert [o.to_dict() for o in result.objects] == near_objects
    np.testing.assert_array_equal(segment_scene(org).labels,
                                  segment_scene(scene.organized).labels)


def test_rows_at_the_origin_are_no_returns_like_nan_rows(scene, near_result):
    # Some drivers write (0, 0, 0) for a pixel without a return: the scene must model
    # exactly as with NaN there (labels, objects and the frame's noise estimate).
    org = scene.organized.copy()
    holes = np.flatnonzero(~scene.valid_mask.ravel())
    assert len(holes) > 100
    flat = org.reshape(-1, 3)
    flat[holes] = 0.0
    labels, result = model_scene(flat, organized_shape=org.shape[:2])
    ref_labels, ref = model_scene(scene.organized.reshape(-1, 3),
                                  organized_shape=org.shape[:2])
    assert np.all(labels[holes] == -1)
    np.testing.assert_array_equal(labels, ref_labels)
    assert [o.to_dict() for o in result.objects] == [o.to_dict() for o in ref.objects]
    assert result.noise == ref.noise
    np.testing.assert_array_equal(labels[scene.valid_mask.ravel()], near_result[0])


def test_only_exact_origin_rows_are_no_returns():
    pts = np.array([[0.0, 0.0, 0.0], [-0.0, 0.0, -0.0], [0.0, 0.0, 1e-9], [1e-300, 0.0, 0.0],
                    [0.0, 0.5, 0.0], [0.1, 0.2, 0.3]])
    np.testing.assert_array_equal(origin_rows(pts), [0, 1])
    np.testing.assert_array_equal(in_range(pts, 5.0), [False, False, True, True, True, True])
    # beyond the range cube, through the squared norms
    far = np.vstack([pts, [[30.0, 0.0, 0.0]]])
    np.testing.assert_array_equal(in_range(far, 5.0),
                                  [False, False, True, True, True, True, False])
    assert len(origin_rows(np.zeros((0, 3)))) == 0


def test_cli_does_not_call_origin_rows_far(tmp_path, capsys):
    pts = np.random.default_rng(0).uniform(-1.0, 1.0, size=(2000, 3))
    pts[:500] = 0.0
    np.save(tmp_path / "cloud.npy", pts)
    assert main(["model", str(tmp_path / "cloud.npy"), "--json", str(tmp_path / "o.json")]) == 0
    _, err = capsys.readouterr()
    assert "farther than max_range" not in err and "Traceback" not in err


def test_range_is_inclusive_and_measured_from_the_origin():
    # |(3, 4, 0)| = 5 exactly; the points off by 1 mm lie outside.
    pts = np.array([[3.0, 4.0, 0.0], [3.0, 4.0, 0.001], [-3.0, 0.0, -4.0], [0.0, 0.0, 5.001],
                    [np.nan, 0.0, 0.0], [1e200, 0.0, 0.0]])
    np.testing.assert_array_equal(in_range(pts, 5.0), [True, False, True, False, False, False])


def test_range_gate_is_exact_near_the_corners_of_the_range_cube():
    # |(5, 5, 5)| = 8.66 m and |(5.7, 5.7, 5.7)| = 9.87 m are inside 10 m although beyond
    # the cube of half-edge 10 / sqrt(3) = 5.77 m on some axis; |(6, 6, 6)| = 10.39 m is not.
    pts = np.array([[5.0, 5.0, 5.0], [5.7, 5.7, 5.7], [6.0, 6.0, 6.0], [0.0, 0.0, -9.99],
                    [np.nan] * 3, [0.1, 0.2, 0.3]])
    np.testing.assert_array_equal(in_range(pts, 10.0), [True, True, False, True, False, True])
    # every coordinate within the cube (|x| <= 5 m): only the NaN row is out
    inside = np.array([[0.1, 0.2, 0.3], [np.nan, 1.0, 1.0], [-5.0, 5.0, -5.0]])
    np.testing.assert_array_equal(in_range(inside, 10.0), [True, False, True])
    assert not in_range(np.array([[np.inf, 0.0, 0.0]]), 10.0)[0]
    assert in_range(np.zeros((0, 3)), 10.0).shape == (0,)


# ---------------------------------------------------------------------------------------
# max_range at its range ends
# ---------------------------------------------------------------------------------------

def test_max_range_is_limited_to_its_documented_range():
    assert RANGE == (0.1, 1e5)
    assert ModelingParams(max_range=0.1).max_range == 0.1
    assert ModelingParams(max_range=1e5).max_range == 1e5
    for bad in (0.0999, 1.0001e5, float("nan")):
        with pytest.raises(ParameterError, match="max_range"):
            ModelingParams(max_range=bad)


def test_smallest_max_range_drops_a_scene_half_a_metre_away(scene):
    # The tiny_box scene lies 0.4-0.75 m from the camera: nothing is within 0.1 m.
    assert np.nanmin(np.linalg.norm(scene.points, axis=1)) > 0.1
    labels, result = model_scene(scene.points, ModelingParams(max_range=0.1))
    assert np.all(labels == -1) and result.objects == []


def test_largest_max_range_models_the_scene_like_the_default(scene, near_result):
    labels, result = model_scene(scene.points, ModelingParams(max_range=1e5))
    np.testing.assert_array_equal(labels, near_result[0])
    assert [o.to_dict() for o in result.objects] == near_result[1]


# ---------------------------------------------------------------------------------------
# Magnitudes that still do not fit a voxel grid
# ---------------------------------------------------------------------------------------

def test_huge_range_with_tiny_voxels_raises_input_error_naming_the_parameters():
    pts = np.random.default_rng(5).uniform(-5e4, 5e4, size=(3000, 3))
    # 1e5 m / 5e-4 m = 2e8 cells per axis, 8e24 in the box: more than int64 holds. (With
    # noise_model auto the voxels would follow the sparse sampling of such a cloud.)
    params = ModelingParams(max_range=1e5, seg_voxel_size=0.0005, noise_model="fixed")
    with pytest.raises(InputError, match="max_range.*seg_voxel_size"):
        model_scene(pts, params)
    with pytest.raises(InputError, match="voxel_size"):
        model_objects(pts, np.zeros(len(pts), dtype=np.int64),
                      ModelingParams(max_range=1e5, voxel_size=0.0002, noise_model="fixed"))


def test_voxelize_checks_the_grid_in_floats_before_integer_arithmetic():
    # A small spread far from the origin: cell indices ~1e19 do not fit in int64.
    far = np.array([[1e15, 0.0, 0.0], [1e15 + 1.0, 0.0, 0.0]])
    with pytest.raises(InputError, match="too large for a voxel grid"):
        voxelize(far, 1e-4)
    # (1e6 + 1)**3 ~ 1e18 cells is below 2**62 ~ 4.6e18: still exact.
    pts = np.array([[0.0, 0.0, 0.0], [1e6, 1e6, 1e6], [0.2, 0.3, 0.4]])
    centroids, inverse, counts = voxelize(pts, 1.0)
    np.testing.assert_array_equal(inverse, [0, 1, 0])
    np.testing.assert_array_equal(counts, [2, 1])
    np.testing.assert_allclose(centroids, [[0.1, 0.15, 0.2], [1e6, 1e6, 1e6]])
    assert count_voxels(pts, 1.0) == 2          # the sparse box: sorted keys
    assert count_voxels(pts[[0, 2]], 1.0) == 1  # a dense box of one cell
    assert count_voxels(pts[[0, 2]], 0.25) == 2  # (0.2, 0.3, 0.4) is now in cell (0, 1, 1)
    with pytest.raises(InputError, match="too large for a voxel grid"):
        count_voxels(far, 1e-4)
    # With groups the key space multiplies: 1e18 cells x 10 groups no longer fits.
    with pytest.raises(InputError):
        voxelize(pts, 1.0, groups=np.array([0, 9, 0]))


# ---------------------------------------------------------------------------------------
# Huge clouds: downsampling above max_points
# ---------------------------------------------------------------------------------------

def test_scene_with_exactly_max_points_is_not_downsampled(scene, near_result):
    n_valid = int(np.count_nonzero(scene.valid_mask))
    labels, result = model_scene(scene.points, ModelingParams(max_points=n_valid))
    np.testing.assert_array_equal(labels, near_result[0])
    assert [o.to_dict() for o in result.objects] == near_result[1]
    assert "downsample_s" not in result.timing


def _voxel_keys(points: np.ndarray, voxel: float) -> np.ndarray:
    """One integer per voxel of edge ``voxel`` [m] (the points are within a few metres)."""
    cells = np.floor(points / voxel).astype(np.int64) + 10_000
    return (cells[:, 0] * 20_000 + cells[:, 1]) * 20_000 + cells[:, 2]


def _working_voxel(points: np.ndarray, params: ModelingParams) -> float:
    """Smallest seg_voxel_size * GROWTH**k with at most max_points occupied voxels."""
    for k in range(40):
        v = params.seg_voxel_size * DOWNSAMPLE_GROWTH ** k
        if len(np.unique(_voxel_keys(points, v))) <= params.max_points:
            return v
    raise AssertionError("no voxel found")


def test_huge_cloud_is_downsampled_and_every_row_labelled():
    pts, boxes = floor_with_boxes(200_000, extent=3.0, seed=6)
    params = ModelingParams(max_points=30_000)
    voxel = _working_voxel(pts, params)
    # The floor alone (9 m^2) needs voxels of at least sqrt(9 / 30000) = 17 mm.
    assert voxel >= math.sqrt(9.0 / params.max_points)
    labels, result = model_scene(pts, params)
    assert labels.shape == (len(pts),)
    assert "downsample_s" in result.timing
    # Each row carries the label of its voxel: constant within every voxel.
    keys = _voxel_keys(pts, voxel)
    _, first, inv = np.unique(keys, return_index=True, return_inverse=True)
    np.testing.assert_array_equal(labels, labels[first][inv.ravel()])
    # The floor is one plane, the three boxes are cuboids with their true sizes within
    # one working voxel, and their points carry their labels.
    cuboids = [o for o in result.objects if o.type == PrimitiveType.CUBOID]
    assert len(cuboids) == len(boxes)
    for box in boxes:
        top = box.center - [0.0, 0.0, box.size[2]]       # the top face centre (towards -z)
        near = np.linalg.norm(pts - top, axis=1) < 0.5 * min(box.size[:2])
        obj = min(cuboids, key=lambda o: np.linalg.norm(o.center[:2] - box.center[:2]))
        assert np.mean(labels[near] == obj.id) > 0.95
        np.testing.assert_allclose(sorted(obj.dimensions.values()), sorted(box.size),
                                   atol=voxel)
    floor_pts = np.abs(pts[:, 2] - FLOOR_Z) < 0.002
    floor_labels = labels[floor_pts]
    floor_id = np.bincount(floor_labels[floor_labels >= 0]).argmax()
    assert np.mean(floor_labels == floor_id) > 0.9
    assert result.objects[[o.id for o in result.objects].index(floor_id)].type == \
        PrimitiveType.PLANE


def test_downsampling_uses_only_the_points_in_range():
    pts, _ = floor_with_boxes(60_000, extent=2.0, seed=7)
    rng = np.random.default_rng(8)
    garbage = _garbage(rng, 40_000)
    mixed, is_near = _interleave(pts, garbage, rng)
    params = ModelingParams(max_points=20_000)
    labels, result = model_scene(mixed, params)
    ref_labels, ref = model_scene(pts, params)
    assert np.all(labels[~is_near] == -1)
    np.testing.assert_array_equal(labels[is_near], ref_labels)
    assert [o.to_dict() for o in result.objects] == [o.to_dict() for o in ref.objects]


# ---------------------------------------------------------------------------------------
# The node: far points are dropped, a grid too large skips the frame
# ---------------------------------------------------------------------------------------

@pytest.fixture
def make_node(context):
    from test_node import CoreProbe, Harness

    made = []

    def make(**overrides):
        h = Harness(context, CoreProbe(model_scene), overrides)
        made.append(h)
        return h

    yield make
    for h in made:
        h.close()


def _cloud(points: np.ndarray, sec: int):
    from builtin_interfaces.msg import Time
    from std_msgs.msg import Header

    from msg_adapters.pointcloud2 import xyz_to_cloud
    from ros_helpers import FRAME

    return xyz_to_cloud(points, Header(stamp=Time(sec=sec), frame_id=FRAME))


def test_node_models_a_frame_without_its_far_points(make_node, scene, near_result):
    from msg_adapters.pointcloud2 import cloud_to_fields
    from ros_helpers import wait_until
    from test_node import shapes

    h = make_node()
    org = scene.organized.copy()
    far = ~scene.valid_mask
    org[far] = [0.0, 0.0, 1e9]
    h.pub.publish(_cloud(org, sec=3))
    found = shapes(h.markers.wait())
    assert set(found) == {o["type"] for o in near_result[1]}
    seg_ids = cloud_to_fields(h.segments.wait(), ["object_id"], keep_organized=True)["object_id"]
    assert np.all(seg_ids[far] == -1)
    np.testing.assert_array_equal(seg_ids[~far], near_result[0])
    wait_until(lambda: h.node.stats().processed == 1, "the frame to be processed")
    assert h.node.stats().failed == 0


def test_node_skips_a_frame_too_large_for_the_voxel_grid_with_a_warning(make_node, capfd):
    from ros_helpers import wait_until

    h = make_node(max_range=1e5, seg_voxel_size=0.0005, noise_model="fixed")
    pts = np.random.default_rng(9).uniform(-5e4, 5e4, size=(3000, 3))
    h.publish_and_wait_received(_cloud(pts, sec=1))
    wait_until(lambda: h.node.stats().failed == 1, "the frame to be counted as failed")
    h.publish_and_wait_received(_cloud(pts, sec=2))
    wait_until(lambda: h.node.stats().failed == 2, "the second frame to be counted as failed")
    assert h.node.stats().processed == 0
    assert len(h.markers) == 0
    log = capfd.readouterr().err
    assert "Traceback" not in log
    # one warning (throttled) that names the error and the parameters to change
    assert log.count("InputError: points too large for a voxel grid") == 1
    assert "max_range" in log and "seg_voxel_size" in log
