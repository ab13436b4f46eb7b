"""Scene segmentation (``segment_scene``) on synthetic and real scenes.

Synthetic scenes with exact ground truth (objects touching, stacked, occluded, apart), end
to end on a stacked scene, real Kinect scenes (osd_learn), and degenerate or malformed
input. Parts that must not be joined: test_segmentation_joins.py.

IoUs quoted in comments were measured with the segmentation of commit 4429b4b (union-find
patch merging); the assertions are the requirements, not the measurements.
"""

from __future__ import annotations

import functools
import itertools
import re
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from data_helpers import require

from geomodel_ros.tools.benchmark import OSD_GROUPS, data_dir
from geomodel_ros.tools.evaluation import dimension_errors, segmentation_scores
from geomodel_ros.core.params import ModelingParams, load_params_file
from geomodel_ros.core.modeling import InputError, model_scene
from geomodel_ros.core.segmentation import segment_scene
from geomodel_ros.tools.synth import (SENSOR_NOISE, Box, Cylinder, Sphere, render_scene,
                                      scene_geometry)
from geomodel_ros.tools.synth.scenes import (DESK_CENTER, DESK_NORMAL, SCENE_NAMES,
                                             SEGMENTATION_CAMERA, SEGMENTATION_SCENE_NAMES,
                                             _desk, _rest_on_desk, _standing)

CONFIG = Path(__file__).resolve().parent.parent / "config"
MM = 1e-3
#: Pairs of object ids (lower/first, upper/second) that touch by construction.
CONTACTS = {
    "touching": {(1, 2), (1, 3)},  # box 2 face to face with box 1; cylinder 3 against box 1
    "stacked": {(1, 2), (3, 4)},   # box 2 on box 1; cylinder 4 on box 3
    "occluded": set(),
    "apart": set(),
}
EXPECTED_TYPES = {
    "touching": ["plane", "cuboid", "cuboid", "cylinder"],
    "stacked": ["plane", "cuboid", "cuboid", "cuboid", "cylinder"],
    "occluded": ["plane", "cuboid", "cylinder"],
    "apart": ["plane", "cuboid", "cylinder", "sphere"],
}


def _scores(labels: np.ndarray, gt: np.ndarray, ids) -> dict:
    return {s.gt_id: s for s in segmentation_scores(labels, gt, list(ids))}


def _iou_report(scores: dict) -> str:
    return ", ".join(f"{k}: IoU {s.iou:.3f}{' under' if s.under else ''}"
                     f"{' over' if s.over else ''}" for k, s in scores.items())


# ---------------------------------------------------------------------------------------
# The synthetic scenes themselves
# ---------------------------------------------------------------------------------------

def test_segmentation_scenes_are_registered():
    assert set(SEGMENTATION_SCENE_NAMES) <= set(SCENE_NAMES)
    for name in SEGMENTATION_SCENE_NAMES:
        camera, _ = scene_geometry(name)
        assert camera == SEGMENTATION_CAMERA
    assert (SEGMENTATION_CAMERA.width, SEGMENTATION_CAMERA.height) == (320, 181)


def _separation(a, b) -> tuple[float, np.ndarray]:
    """Bound the distance between convex shapes ``a`` and ``b`` from below.

    Returns the best lower bound [m] found over candidate directions, from their support
    functions, and its direction u (from a to b): -b.support(-u) - a.support(u) >= 0 means
    the plane u . x = a.support(u) separates them (they touch when it is 0).
    """
    delta = b.center - a.center
    flat = delta - (delta @ DESK_NORMAL) * DESK_NORMAL
    candidates = [delta, flat, DESK_NORMAL, *a.rotation.T, *b.rotation.T]
    best, best_u = -np.inf, None
    for u in candidates:
        if np.linalg.norm(u) < 1e-12:
            continue
        for sign in (1.0, -1.0):
            v = sign * u / np.linalg.norm(u)
            gap = -b.support(-v) - a.support(v)
            if gap > best:
                best, best_u = gap, v
    return best, best_u


@pytest.mark.parametrize("name", SEGMENTATION_SCENE_NAMES)
def test_scene_objects_do_not_intersect_and_touch_where_built_to(name):
    _, shapes = scene_geometry(name)
    desk_offset = DESK_CENTER @ DESK_NORMAL
    uppers = {b for _, b in CONTACTS[name]} if name == "stacked" else set()
    for k, shape in enumerate(shapes[1:], start=1):
        if k not in uppers:  # everything else stands on the desk
            assert abs(-shape.support(-DESK_NORMAL) - desk_offset) < 1e-9
    for i, j in itertools.combinations(range(1, len(shapes)), 2):
        gap, u = _separation(shapes[i], shapes[j])
        if (i, j) in CONTACTS[name]:
            # A separating plane at distance 0, and a common point on it: the projection
            # of j's centre onto the plane lies on both surfaces.
            assert abs(gap) < 1e-9, (i, j, gap)
            p = shapes[j].center - (shapes[j].center @ u - shapes[i].support(u)) * u
            assert abs(shapes[i].signed_distance(p[None])[0]) < 1e-9
            assert abs(shapes[j].signed_distance(p[None])[0]) < 1e-9
        else:
            assert gap > 5 * MM, (i, j, gap)


def test_stacked_objects_are_centred_on_the_top_face():
    scene = render_scene("stacked")
    _, shapes = scene_geometry("stacked")
    for lo, up in CONTACTS["stacked"]:
        # bottom on top, centred (no offset along the desk)
        assert abs(-shapes[up].support(-DESK_NORMAL) - shapes[lo].support(DESK_NORMAL)) < 1e-9
        delta = shapes[up].center - shapes[lo].center
        assert np.linalg.norm(delta - (delta @ DESK_NORMAL) * DESK_NORMAL) < 1e-9
    # The big box's top face is visible on all four sides of the box standing on it.
    lower, upper = shapes[1], shapes[2]
    pts = scene.points[scene.labels == 1]
    top = pts[np.abs(pts @ DESK_NORMAL - lower.support(DESK_NORMAL)) < 1e-9]
    loc = (top - upper.center) @ upper.rotation
    margin = 2 * MM
    assert (loc[:, 0] > upper.length / 2 + margin).sum() > 50
    assert (loc[:, 0] < -upper.length / 2 - margin).sum() > 50
    assert (loc[:, 1] > upper.width / 2 + margin).sum() > 50
    assert (loc[:, 1] < -upper.width / 2 - margin).sum() > 50


# Valid points per object (desk first): touching [25213, 2513, 1159, 1898],
# stacked [24359, 2612, 1542, 1339, 1152], occluded [27482, 3087, 717],
# apart [26033, 2125, 1893, 926]; each scene renders in 0.01-0.03 s.
@pytest.mark.parametrize("name", SEGMENTATION_SCENE_NAMES)
def test_scene_ground_truth_and_point_counts(name):
    scene = render_scene(name)
    assert scene.organized.shape == (181, 320, 3)
    assert [o.type for o in scene.objects] == EXPECTED_TYPES[name]
    assert [o.id for o in scene.objects] == list(range(len(scene.objects)))
    counts = np.bincount(scene.labels, minlength=len(scene.objects))
    assert len(counts) == len(scene.objects)
    assert counts.min() >= 500, counts
    # every object is one connected region of the image
    for obj in scene.objects[1:]:
        _, parts = ndimage.label(scene.label_image == obj.id, structure=np.ones((3, 3)))
        assert parts == 1, (obj.id, parts)


def test_occluded_cylinder_is_about_half_visible():
    camera, shapes = scene_geometry("occluded")
    scene = render_scene("occluded")
    _, alone = camera.render([shapes[0], shapes[2]], ids=[0, 2])
    visible = (scene.label_image == 2).sum() / (alone == 2).sum()
    assert 0.4 <= visible <= 0.6, visible  # measured 0.505
    # the box really is in front: some cylinder pixels of the lone render show the box
    assert np.any((alone == 2) & (scene.label_image == 1))


# ---------------------------------------------------------------------------------------
# Segmentation of the synthetic scenes
# ---------------------------------------------------------------------------------------

def _check_one_segment_per_object(scene, labels: np.ndarray) -> dict:
    gt = scene.label_image.ravel()
    assert labels.shape == gt.shape and labels.dtype == np.int64
    ids = [o.id for o in scene.objects]
    scores = _scores(labels, gt, ids)
    report = _iou_report(scores)
    segments = np.unique(labels[labels >= 0])
    assert len(segments) == len(ids), f"{len(segments)} segments for {len(ids)} objects; {report}"
    for s in scores.values():
        assert s.iou >= 0.8, report
        assert not s.under, report
    # IoU > 0.5 makes the best matches distinct: one segment per object, none left over.
    best = {int(np.bincount(labels[(gt == i) & (labels >= 0)]).argmax()) for i in ids}
    assert best == set(segments.tolist())
    return scores


# Measured IoUs (desk first), clean / SENSOR_NOISE with rng 0:
#   touching  0.993 0.940 0.955 0.926 / 0.993 0.939 0.954 0.921
#   stacked   0.992 0.944 0.980 0.930 0.984 / 0.992 0.943 0.980 0.927 0.980
#   occluded  0.998 0.988 0.976 / 0.998 0.984 0.979
#   apart     0.994 0.959 0.967 1.000 / 0.994 0.959 0.968 1.000
# (Noisy, seeds 0-9: smallest object IoU 0.919 touching, 0.920 stacked, 0.973 occluded,
# 0.955 apart.)
@pytest.mark.parametrize("noisy", [False, True], ids=["clean", "noisy"])
@pytest.mark.parametrize("name", SEGMENTATION_SCENE_NAMES)
def test_synthetic_scene_one_segment_per_object(name, noisy):
    if noisy:
        scene = render_scene(name, noise=SENSOR_NOISE, rng=0)
        params = load_params_file(CONFIG / "sensor_noise.yaml")
    else:
        scene = render_scene(name)
        params = ModelingParams()
    seg = segment_scene(scene.organized, params)
    _check_one_segment_per_object(scene, seg.labels)
    assert seg.support_ids == [0]
    # the desk is the support plane, its normal towards the sensor
    normal, d = seg.support_planes[0]
    assert normal @ DESK_NORMAL > np.cos(np.radians(1.0))
    assert abs(d + DESK_NORMAL @ DESK_CENTER) < 1 * MM


# ---------------------------------------------------------------------------------------
# End to end on the stacked scene
# ---------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=None)
def _stacked_model():
    scene = render_scene("stacked")
    labels, result = model_scene(scene.organized.reshape(-1, 3), ModelingParams())
    return scene, labels, result


# Measured size errors [mm] (clean): box 1 +0.12 / +0.01 / +0.06, box 3 +0.02 / +0.04 /
# +0.05, cylinder 4 radius -0.02, height +1.12; box 2 (on box 1) +0.01 / +1.01 / -0.04 (its
# segment held 9 points of box 1's top face along the crease, +2.40 mm in height, until the
# segmentation split patches at steps).
@pytest.mark.parametrize("gt_id", [1, 2, 3, 4])
def test_model_scene_stacked_sizes_within_2_mm(gt_id):
    scene, labels, result = _stacked_model()
    assert labels.shape == (scene.organized.shape[0] * scene.organized.shape[1],)
    gt = scene.label_image.ravel()
    segment = int(np.bincount(labels[(gt == gt_id) & (labels >= 0)]).argmax())
    est = {o.id: o for o in result.objects}[segment]
    truth = scene.objects[gt_id]
    assert est.type == truth.type, est.reason
    errors = dimension_errors(est, truth)
    assert len(errors) == len(truth.dimensions)
    assert sorted(e.true for e in errors) == pytest.approx(sorted(truth.dimensions.values()))
    worst = max(abs(e.error) for e in errors)
    assert worst <= 2 * MM, [(e.name, e.true, e.estimate) for e in errors]


# ---------------------------------------------------------------------------------------
# Real Kinect scenes (osd_learn)
# ---------------------------------------------------------------------------------------

def _osd(k: int):
    return data_dir() / "osd_learn" / f"learn{k}.pcd"


# Measured per-object IoU with config/kinect.yaml (objects 2, 3, ...; the table 0.988-0.996):
#   learn13 (boxes)     0.990 0.959 0.994
#   learn22 (stacked)   0.936 0.959 0.994
#   learn26 (occluded)  0.997 0.978
#   learn43 (cylinders) 0.985 0.969 0.984
OSD_CASES = [
    pytest.param("boxes", 13, id="boxes-learn13"),
    pytest.param("stacked", 22, id="stacked-learn22"),
    # learn18: the two stacked boxes were under-segmented (IoU 0.714 and 0.255) until
    # links across a step stopped joining patches.
    pytest.param("stacked", 18, id="stacked-learn18"),
    pytest.param("occluded", 26, id="occluded-learn26"),
    # learn28: the occluded object is seen as two disjoint parts, joined across the
    # occluder (objects 0.997 0.975).
    pytest.param("occluded", 28, id="occluded-learn28"),
    pytest.param("cylinders", 43, id="cylinders-learn43"),
    # learn37: object 4 (a cup) was over-segmented (IoU 0.535) until a container's own
    # floor in the desk's band stayed the container's (objects 0.993 0.954 0.923).
    pytest.param("cylinders", 37, id="cylinders-learn37"),
]
# Over all 45 learn scenes no boxes scene (learn0-16) misses 0.8, so that group has no
# failing case.


@pytest.mark.parametrize("group, k", OSD_CASES)
def test_osd_learn_objects_iou(group, k):
    path = require(_osd(k))
    from geomodel_ros.tools.io import load_osd

    assert k in OSD_GROUPS[group]
    points, gt = load_osd(path)
    seg = segment_scene(points.reshape(480, 640, 3), load_params_file(CONFIG / "kinect.yaml"))
    assert seg.labels.shape == gt.shape
    assert np.all(seg.labels[~np.all(np.isfinite(points), axis=1)] == -1)
    objects = [int(g) for g in np.unique(gt) if g >= 2]
    assert objects
    scores = _scores(seg.labels, gt, [0] + objects)
    report = _iou_report(scores)
    assert scores[0].iou >= 0.8, report  # the table
    for g in objects:
        assert scores[g].iou >= 0.8, report


def _modeled_osd_object(k: int, gt_id: int):
    """Segment and model learn<k> with config/kinect.yaml.

    Returns the labelled object's own finite points, the primitive of the segment that
    holds most of them, and the whole result (see data_helpers.require when the data
    folder is missing).
    """
    path = require(_osd(k))
    from geomodel_ros.tools.io import load_osd

    points, gt = load_osd(path)
    labels, result = model_scene(points, load_params_file(CONFIG / "kinect.yaml"))
    by_id = {o.id: o for o in result.objects}
    mask = gt == gt_id
    ids, counts = np.unique(labels[mask & (labels >= 0)], return_counts=True)
    obj = by_id[int(ids[np.argmax(counts)])]
    return points[mask & np.all(np.isfinite(points), axis=1)], obj, result


#: Margins [mm] of the box sides against the extent of the box's own labelled points along
#: the cuboid's axes: no side longer than the points reach (min to max) plus LONGER_MM,
#: none shorter than their 1st-99th percentile extent minus SHORTER_MM. Measured (side
#: minus extent, worst of the 11 boxes): +2.1 mm over the full extent (learn17 box 3),
#: -3.9 mm under the percentile extent (learn25 box 2), except learn17 box 2 below.
LONGER_MM = 3.0
SHORTER_MM = 5.0


@pytest.mark.parametrize("k, box, shorter_mm", [
    (9, 3, SHORTER_MM), (12, 3, SHORTER_MM), (14, 3, SHORTER_MM), (7, 3, SHORTER_MM),
    (16, 4, SHORTER_MM), (20, 2, SHORTER_MM), (25, 2, SHORTER_MM),
    # learn17 box 2: its faces meet 9-10 degrees off square (config/kinect.yaml's
    # angle_tolerance is 9.7 degrees). Its segment lost 22 points along the contact with
    # the table (19 of them table points) when the segmentation began to split patches at
    # steps; without them no three orthogonal axes are found (with them the width came
    # out 54.1 mm for a 64.9 mm spread of its points).
    pytest.param(17, 2, 13.0, marks=pytest.mark.xfail(strict=True, reason=(
        "learn17 box 2 comes out unknown: planar faces not aligned with three orthogonal "
        "axes (faces 9-10 degrees off square)"))),
    (19, 2, SHORTER_MM), (15, 4, SHORTER_MM), (17, 3, SHORTER_MM),
])
def test_osd_learn_boxes_come_out_as_cuboids_of_their_size(k, box, shorter_mm):
    # Boxes whose sides region growing joined (normals turning gradually across an edge)
    # or that depth noise bent beyond the plane test (learn9, 12, 14), or whose faces
    # hold flying pixels far behind them that tilted a least-squares plane and stretched
    # the box (learn7, 16, stacked learn20, occluded learn25), or whose faces meet 9-10
    # degrees off square (stacked learn17, 19: config/kinect.yaml's angle_tolerance), or
    # whose two sides grown into one face hold 79.7 % of it (learn15) or spread only
    # 5.9 mm about one plane (learn17 box 3); each used to come out `unknown`.
    own, obj, result = _modeled_osd_object(k, box)
    assert obj.type == "cuboid", obj.reason
    # Its sides match the extent of the box's own labelled points along its axes; a side
    # completed down to the table (the box stands behind another one: learn7, learn16)
    # reaches beyond its points, and its lower face lies on the table plane.
    names = ("length", "width", "height")
    local = (own - obj.center) @ obj.rotation
    lo, hi = np.percentile(local, [1.0, 99.0], axis=0)
    reach = local.max(axis=0) - local.min(axis=0)
    dims = np.array([obj.dimensions[n] for n in names])
    observed = np.array([n not in obj.completed for n in names])
    report = (np.round(dims / MM, 1), np.round((hi - lo) / MM, 1), np.round(reach / MM, 1),
              obj.completed)
    assert np.all((dims <= reach + LONGER_MM * MM) | ~observed), report
    assert np.all(dims >= (hi - lo) - shorter_mm * MM), report
    for a in np.flatnonzero(~observed):
        n, d = next(iter(result.supports.values()))
        ends = [obj.center + s * obj.rotation[:, a] * dims[a] / 2 for s in (-1, 1)]
        assert min(abs(float(n @ e + d)) for e in ends) < 1e-9, report
        assert dims[a] > reach[a] + LONGER_MM * MM, report


@pytest.mark.parametrize("k", [33, 41])
def test_osd_learn_lidded_containers_come_out_as_upright_cylinders(k):
    # A container whose flat lid meets its side in a rounded edge: lid and side grow
    # into one curved face, and a free RANSAC fit prefers a huge cylinder through the
    # lid (both used to come out `unknown`). learn33: on the table; learn41: on a tin.
    own, obj, result = _modeled_osd_object(k, 3)
    assert obj.type == "cylinder", obj.reason
    table = max((o for o in result.objects if o.type == "plane"), key=lambda o: o.point_count)
    axis = obj.rotation[:, 2]
    assert abs(axis @ table.rotation[:, 2]) >= np.cos(np.radians(8.0))
    # The container's own points: most of them lie on its side, at about the radius
    # (measured: 1.5 and 3.7 mm off); its height is about their extent along the axis:
    # no longer than they reach (measured: 28.2 and 6.5 mm shorter), and at most 22 mm
    # shorter than their 1st-99th percentile extent (measured: learn33 18.9 mm shorter,
    # learn41 3.8 mm longer).
    own = own - obj.center
    along = own @ axis
    radial = np.linalg.norm(own - np.outer(along, axis), axis=1)
    assert abs(np.median(radial) - obj.dimensions["radius"]) <= 5 * MM
    lo, hi = np.percentile(along, [1.0, 99.0])
    height = obj.dimensions["height"]
    assert (hi - lo) - 22 * MM <= height <= along.max() - along.min() + 3 * MM


# ---------------------------------------------------------------------------------------
# Degenerate and malformed input
# ---------------------------------------------------------------------------------------

def test_all_nan_organized_cloud_gives_no_segments():
    seg = segment_scene(np.full((181, 320, 3), np.nan), ModelingParams())
    assert seg.labels.shape == (181 * 320,) and seg.labels.dtype == np.int64
    assert np.all(seg.labels == -1)
    assert seg.support_ids == [] and seg.support_planes == {} and len(seg.object_ids) == 0


def test_bare_desk_is_one_support_and_no_object():
    # Every working point in the support, none left for objects (this used to raise
    # IndexError).
    organized, gt = SEGMENTATION_CAMERA.render([_desk()], ids=[0])
    valid = gt.ravel() == 0
    assert valid.sum() > 20000
    seg = segment_scene(organized, ModelingParams())
    assert seg.support_ids == [0]
    np.testing.assert_array_equal(seg.labels[valid], 0)
    np.testing.assert_array_equal(seg.labels[~valid], -1)
    normal, d = seg.support_planes[0]
    assert normal @ DESK_NORMAL > np.cos(np.radians(0.5))
    assert abs(d + DESK_NORMAL @ DESK_CENTER) < 0.5 * MM


@pytest.mark.parametrize("shape", [(0, 3), (0, 0, 3), (4, 0, 3)])
def test_empty_cloud(shape):
    seg = segment_scene(np.zeros(shape), ModelingParams())
    assert seg.labels.shape == (0,) and seg.labels.dtype == np.int64
    assert seg.support_ids == []
    labels, result = model_scene(np.zeros((0, 3)))
    assert labels.shape == (0,) and result.objects == []


@pytest.mark.parametrize("n", [1, 2, 3])
def test_one_to_three_points_are_noise(n):
    pts = np.random.default_rng(n).normal(0.0, 0.1, size=(n, 3)) + [0, 0, 0.5]
    seg = segment_scene(pts, ModelingParams())
    np.testing.assert_array_equal(seg.labels, np.full(n, -1))
    with_nan = np.vstack([pts, np.full((2, 3), np.nan)])
    np.testing.assert_array_equal(segment_scene(with_nan).labels, np.full(n + 2, -1))


# Measured: IoU 1.000 for each (1179, 1983 and 1546 points).
@pytest.mark.parametrize("shape", [
    Sphere(35 * MM, **_standing(0, 0, 0)),
    Box(80 * MM, 60 * MM, 50 * MM, **_standing(0, 0, 25)),
    Cylinder(30 * MM, 70 * MM, **_standing(0, 0, 0)),
], ids=["sphere", "box", "cylinder"])
def test_single_object_without_desk_is_one_segment(shape):
    organized, gt = SEGMENTATION_CAMERA.render([_rest_on_desk(shape)], ids=[1])
    assert (gt == 1).sum() > 1000
    seg = segment_scene(organized, ModelingParams())
    assert seg.support_ids == []  # a box face is far smaller than a support surface
    assert len(seg.object_ids) == 1
    score = _scores(seg.labels, gt.ravel(), [1])[1]
    assert score.iou >= 0.8 and not score.over


@pytest.mark.parametrize("shape", [(10, 2), (10,), (10, 4), (4, 4, 2), (2, 3, 3, 1), ()])
def test_malformed_shape_raises_input_error(shape):
    expected = r"points must be \(N, 3\) or \(H, W, 3\), got shape " + re.escape(str(shape))
    with pytest.raises(InputError, match=expected):
        segment_scene(np.zeros(shape), ModelingParams())


def test_model_scene_malformed_shape_raises_input_error():
    shape = r"points must be \(N, 3\) or \(H, W, 3\), got shape \(10, 2\)"
    with pytest.raises(InputError, match=shape):
        model_scene(np.zeros((10, 2)))


def test_non_numeric_points_raise_input_error():
    with pytest.raises(InputError, match="numeric"):
        segment_scene(np.array([["a", "b", "c"]] * 5))


def test_labels_keep_input_length_and_order():
    scene = render_scene("touching")
    params = ModelingParams()
    organized = segment_scene(scene.organized, params).labels
    valid = scene.valid_mask.ravel()
    assert organized.shape == valid.shape
    assert np.all(organized[~valid] == -1)
    # (N, 3) rows of the valid points: the same labels, in the same order
    points = segment_scene(scene.points, params).labels
    np.testing.assert_array_equal(points, organized[valid])
    # NaN rows injected at known indices are -1 and shift nothing
    rng = np.random.default_rng(7)
    bad = np.sort(rng.choice(len(scene.points) + 500, size=500, replace=False))
    mixed = np.empty((len(scene.points) + 500, 3))
    keep = np.ones(len(mixed), dtype=bool)
    keep[bad] = False
    mixed[keep] = scene.points
    mixed[bad] = np.nan
    labels = segment_scene(mixed, params).labels
    assert labels.shape == (len(mixed),)
    assert np.all(labels[bad] == -1)
    np.testing.assert_array_equal(labels[keep], points)
    # shuffled rows: labels follow their points
    perm = rng.permutation(len(scene.points))
    np.testing.assert_array_equal(segment_scene(scene.points[perm], params).labels, points[perm])


def test_reproducible_with_the_same_seed():
    scene = render_scene("stacked", noise=SENSOR_NOISE, rng=3)
    params = ModelingParams(seed=11)
    a = segment_scene(scene.organized, params)
    b = segment_scene(scene.organized, params)
    np.testing.assert_array_equal(a.labels, b.labels)
    assert a.support_ids == b.support_ids
    for sid in a.support_ids:
        np.testing.assert_array_equal(a.support_planes[sid][0], b.support_planes[sid][0])
        assert a.support_planes[sid][1] == b.support_planes[sid][1]
    # an explicit rng: the same seed or a generator seeded alike gives the same labels
    c = segment_scene(scene.organized, params, rng=5)
    d = segment_scene(scene.organized, params, rng=np.random.default_rng(5))
    np.testing.assert_array_equal(c.labels, d.labels)
    # and the input is not modified
    again = render_scene("stacked", noise=SENSOR_NOISE, rng=3)
    np.testing.assert_array_equal(scene.organized, again.organized)
