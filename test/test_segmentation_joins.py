"""Segmentation joins: parts of different objects must NOT be joined.

The joins that put parts of one object together need their evidence.

Scenes are rendered with the synthetic camera of the segmentation tests on the tilted
desk; the expected labels are the renderer's ground truth. Each scene also checks the
geometric fact it was built for (a gap of bare desk, a contact, a hidden middle), from
the shapes' analytic support functions and the ground-truth image, so that a test cannot
pass on a scene that is not what its name says. The join helpers
(:mod:`geomodel_ros.core.joins`) are tested directly on hand-made inputs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage
from scipy.spatial import cKDTree

from geomodel_ros.core.joins import (GAP_DIRECT_POINTS, DisjointSets, _closest_gap, _Gap,
                                     _gap_candidates, _one_round_surface, _round_footprint,
                                     _Segments, join_occluded_parts, merge_patches,
                                     segment_members)
from geomodel_ros.core.params import ModelingParams, load_params_file
from geomodel_ros.core.segmentation import segment_scene
from geomodel_ros.tools.synth import SENSOR_NOISE, Box, Cylinder, Sphere, apply_noise
from geomodel_ros.tools.synth.scenes import (DESK_NORMAL, SEGMENTATION_CAMERA, _desk, _lying,
                                             _next_to, _rest_on, _rest_on_desk, _standing,
                                             desk_frame)

CONFIG = Path(__file__).resolve().parent.parent / "config"
MM = 1e-3
#: Desk x axis (the ``u`` of ``_standing``), along which the objects are lined up.
DESK_U = desk_frame()[:, 0]


def _mm(*values: float) -> list[float]:
    return [v * MM for v in values]


def _render(shapes: list) -> tuple[np.ndarray, np.ndarray]:
    """Render the desk (id 0) and ``shapes`` (ids 1, 2, ...).

    Returns the organized cloud (H, W, 3) [m] and the ground-truth image (H, W).
    """
    return SEGMENTATION_CAMERA.render([_desk(), *shapes], ids=list(range(len(shapes) + 1)))


def _segment(shapes: list, noisy: bool = False,
             params: ModelingParams | None = None) -> tuple[np.ndarray, np.ndarray]:
    organized, gt = _render(shapes)
    if noisy:
        organized, gt = apply_noise(organized, gt, SENSOR_NOISE, rng=0)
        params = params or load_params_file(CONFIG / "sensor_noise.yaml")
    seg = segment_scene(organized, params or ModelingParams())
    return seg.labels, gt.ravel()


def _iou(labels: np.ndarray, gt: np.ndarray, g: int) -> float:
    """IoU of object ``g`` with the segment that holds most of its points."""
    mine = gt == g
    held = labels[mine & (labels >= 0)]
    if not len(held):
        return 0.0
    best = labels == np.bincount(held).argmax()
    return float((mine & best).sum() / (mine | best).sum())


def _assert_one_segment_per_object(labels: np.ndarray, gt: np.ndarray, n_objects: int):
    ids = range(n_objects + 1)  # the desk and the objects
    segments = np.unique(labels[labels >= 0])
    report = {g: round(_iou(labels, gt, g), 3) for g in ids}
    # No segment covers two objects: none holds more than a fifth of two objects' points.
    for s in segments:
        covered = [g for g in ids if ((labels == s) & (gt == g)).sum() > 0.2 * (gt == g).sum()]
        assert len(covered) <= 1, f"segment {s} covers objects {covered}; IoU {report}"
    assert all(iou >= 0.8 for iou in report.values()), report
    assert len(segments) == n_objects + 1, f"{len(segments)} segments; IoU {report}"


def _gap_along_u(left, right) -> float:
    """Distance [m] between two shapes along the desk's u axis (left one at smaller u)."""
    return -right.support(-DESK_U) - left.support(DESK_U)


def _height(shape) -> float:
    """Height [m] of a shape's top above the desk plane it stands on."""
    return shape.support(DESK_NORMAL) + shape.support(-DESK_NORMAL)


def _on_desk(*shapes) -> list:
    return [_rest_on_desk(s) for s in shapes]


# ---------------------------------------------------------------------------------------
# Parts that must not be joined
# ---------------------------------------------------------------------------------------

def _boxes_apart(gap_mm: float) -> list:
    half = 35.0 + gap_mm / 2.0
    return _on_desk(Box(*_mm(70, 60, 50), **_standing(-half, 0, 0)),
                    Box(*_mm(70, 60, 50), **_standing(half, 0, 0)))


@pytest.mark.parametrize("noisy", [False, True], ids=["clean", "noisy"])
@pytest.mark.parametrize("gap_mm", [50.0, 70.0, 100.0])
def test_two_boxes_apart_with_bare_desk_between_stay_two(gap_mm, noisy):
    shapes = _boxes_apart(gap_mm)
    assert _gap_along_u(*shapes) == pytest.approx(gap_mm * MM, abs=1e-9)
    # Bare desk is seen between them: desk pixels whose points lie in the gap, alongside
    # the boxes (desk v within their 60 mm depth).
    organized, gt = _render(shapes)
    desk = organized[gt == 0]
    u = (desk - _desk().center) @ DESK_U
    v = (desk - _desk().center) @ desk_frame()[:, 1]
    assert np.sum((np.abs(u) < gap_mm * MM / 2 - 5 * MM) & (np.abs(v) < 30 * MM)) > 50
    _assert_one_segment_per_object(*_segment(shapes, noisy), 2)


def _flat_boxes(gap_mm: float) -> list:
    half = 45.0 + gap_mm / 2.0
    return _on_desk(Box(*_mm(90, 70, 12), **_standing(-half, 0, 0)),
                    Box(*_mm(90, 70, 12), **_standing(half, 0, 0)))


# Without the occlusion join's evidence (the gap hidden behind nearer points) each of
# these pairs is joined into one segment (measured: IoU 0.48 for both boxes, under):
# their closest points are farther apart than a link and closer than
# seg_max_occlusion_gap, and the surfaces at both ends are parallel and run across the
# gap, just as the two visible parts of one occluded surface would.
@pytest.mark.parametrize("shapes", [
    pytest.param(_flat_boxes(40.0), id="flat-boxes-40mm"),
    pytest.param(_flat_boxes(60.0), id="flat-boxes-60mm"),
    pytest.param(_flat_boxes(80.0), id="flat-boxes-80mm"),
    pytest.param(_boxes_apart(70.0), id="boxes-70mm"),
])
def test_occlusion_join_needs_the_gap_hidden(shapes):
    params = ModelingParams()
    link = params.seg_max_edge_factor * params.seg_voxel_size
    gap = _gap_along_u(*shapes)
    assert link < gap < params.seg_max_occlusion_gap
    # the same shape and orientation, at the same height on the desk: parallel faces at
    # nearly the same depth
    assert _height(shapes[0]) == pytest.approx(_height(shapes[1]), abs=1e-9)
    np.testing.assert_allclose(shapes[0].rotation, shapes[1].rotation, atol=1e-12)
    _assert_one_segment_per_object(*_segment(shapes, params=params), 2)


def _behind_pole(back) -> list:
    # A thin pole in front (desk v = -80 mm, nearer to the sensor) hides the middle of a
    # long low object behind it.
    return _on_desk(Box(*_mm(22, 22, 125), **_standing(0, -80, 0)), back)


OCCLUDED = {
    "box-behind-pole": _behind_pole(Box(*_mm(200, 40, 40), **_standing(0, 40, 0))),
    "lying-can-behind-pole": _behind_pole(Cylinder(*_mm(20, 200), **_lying(0, 40, 0))),
}


@pytest.mark.parametrize("name", list(OCCLUDED))
def test_object_split_by_an_occluder_is_joined(name):
    shapes = OCCLUDED[name]
    organized, gt = _render(shapes)
    # The object behind is seen as two separate image regions, left and right of the pole,
    # which is nearer to the sensor.
    _, parts = ndimage.label(gt == 2, structure=np.ones((3, 3)))
    assert parts == 2
    depth = np.linalg.norm(organized, axis=2)
    assert depth[gt == 1].mean() < depth[gt == 2].mean()
    labels, gt = _segment(shapes)
    _assert_one_segment_per_object(labels, gt, 2)
    # ... and without the occlusion join it stays two segments: the join made it one.
    apart, _ = _segment(shapes, params=ModelingParams(seg_max_occlusion_gap=0.0))
    held = np.bincount(apart[(gt == 2) & (apart >= 0)])
    assert np.sum(held > 0.2 * (gt == 2).sum()) == 2, held


def _crease(slide_mm: float) -> list:
    # A tall box and a lower one face to face (the lower one's -u face on the tall one's
    # +u face), the lower one slid back by ``slide_mm`` along that face.
    return _on_desk(Box(*_mm(70, 60, 90), **_standing(-35, 0, 0)),
                    Box(*_mm(70, 60, 50), **_standing(35, slide_mm, 0)))


def _crease_turned() -> list:
    u, v = _next_to(-30, 0, 30, 35 + 35, 15)
    return _on_desk(Box(*_mm(70, 60, 90), **_standing(-30, 0, 30)),
                    Box(*_mm(70, 60, 50), **_standing(u, v, 30)))


@pytest.mark.parametrize("noisy", [False, True], ids=["clean", "noisy"])
@pytest.mark.parametrize("shapes", [
    pytest.param(_crease(10.0), id="slid-10mm"),
    pytest.param(_crease(20.0), id="slid-20mm"),
    pytest.param(_crease_turned(), id="turned-30deg"),
    pytest.param(_crease(0.0), id="fronts-flush", marks=pytest.mark.xfail(strict=True, reason=(
        "front faces flush: the two fronts are one plane, grown into one smooth patch "
        "across the contact, so local convexity sees no crease there; measured IoU 0.612 "
        "(tall box) and 0.379 (low box), both under-segmented"))),
])
def test_touching_boxes_of_different_heights_stay_two(shapes, noisy):
    low, tall = sorted(shapes, key=_height)
    assert _height(tall) - _height(low) == pytest.approx(40 * MM, abs=1e-9)
    # face to face: the gap along the tall box's x axis is zero
    x = tall.rotation[:, 0]
    assert -low.support(-x) - tall.support(x) == pytest.approx(0.0, abs=1e-9)
    _assert_one_segment_per_object(*_segment(shapes, noisy), 2)


@pytest.mark.parametrize("noisy", [False, True], ids=["clean", "noisy"])
@pytest.mark.parametrize("gap_mm, yaw, v_mm", [(0.0, 0.0, 0.0), (5.0, 0.0, 0.0),
                                               (0.0, 20.0, -20.0)])
def test_can_standing_next_to_a_box_stays_separate(gap_mm, yaw, v_mm, noisy):
    box = Box(*_mm(70, 60, 60), **_standing(-35, 0, yaw))
    # the can's side at u = gap along the box's x axis, shifted v_mm along its face
    u, v = _next_to(-35, 0, yaw, 35 + gap_mm + 30, v_mm)
    can = Cylinder(*_mm(30, 80), **_standing(u, v, 0))
    shapes = _on_desk(box, can)
    x = shapes[0].rotation[:, 0]
    assert -shapes[1].support(-x) - shapes[0].support(x) == pytest.approx(gap_mm * MM, abs=1e-9)
    _assert_one_segment_per_object(*_segment(shapes, noisy), 2)


def _stack(base_mm: tuple, yaw: float, top_shape, offset_mm: tuple, top_yaw: float) -> list:
    """Stack ``top_shape(**pose)`` on a box of sides ``base_mm``.

    The box stands on the desk at (0, 0) turned by ``yaw`` [deg]; the top shape rests on
    its top at ``offset_mm`` (desk u, v), turned by ``top_yaw``.
    """
    base = _rest_on_desk(Box(*_mm(*base_mm), **_standing(0, 0, yaw)))
    return [base, _rest_on(top_shape(**_standing(*offset_mm, top_yaw)), base)]


STACKS = {
    "box-on-box-off-centre": _stack((120, 100, 50), 10,
                                    lambda **k: Box(*_mm(50, 40, 40), **k), (20, 10), 40),
    "can-on-box": _stack((120, 100, 40), -10,
                         lambda **k: Cylinder(*_mm(25, 60), **k), (-20, 0), 0),
    "ball-on-box": _stack((100, 100, 40), 15, lambda **k: Sphere(*_mm(30), **k), (0, 0), 0),
}


@pytest.mark.parametrize("noisy", [False, True], ids=["clean", "noisy"])
@pytest.mark.parametrize("name", list(STACKS))
def test_small_object_on_a_large_one_stays_separate(name, noisy):
    base, top = STACKS[name]
    # it rests on the base's top face, which shows around it
    assert -top.support(-DESK_NORMAL) == pytest.approx(base.support(DESK_NORMAL), abs=1e-9)
    organized, gt = _render([base, top])
    base_pts = organized[gt == 1]
    assert np.sum(np.abs(base_pts @ DESK_NORMAL - base.support(DESK_NORMAL)) < 1e-6) > 200
    _assert_one_segment_per_object(*_segment([base, top], noisy), 2)


# ---------------------------------------------------------------------------------------
# The join helpers on hand-made input
# ---------------------------------------------------------------------------------------

def test_disjoint_sets_keep_the_label_of_the_first_group():
    sets = DisjointSets([3, 5, 8, 9])
    sets.union(8, 9)
    sets.union(5, 9)  # 9's group (root 8) goes under 5
    assert [sets.find(i) for i in (3, 5, 8, 9)] == [3, 5, 5, 5]
    comp = np.array([-1, 3, 5, 8, 9, 9, 2])
    valid = np.array([False, True, True, True, True, True, False])
    # valid entries get their group's label, the others keep theirs
    np.testing.assert_array_equal(sets.relabel(comp, valid), [-1, 3, 5, 5, 5, 5, 2])


def test_merge_patches_refuses_a_join_across_a_crease():
    # Patches 0-1 share a convex border (40 of 40 votes), 1-2 a weaker convex one (25 of
    # 30), 0-2 a clear crease (2 of 30 votes convex). Strongest first: 0+1, then 1-2
    # would put 2 in a group with 0, which meets 2 at the crease: refused.
    a, b = np.array([0, 0, 1]), np.array([1, 2, 2])
    votes, yes = np.array([40, 30, 30]), np.array([40.0, 2.0, 25.0])
    np.testing.assert_array_equal(merge_patches(3, a, b, votes, yes), [0, 0, 1])
    # Without the crease (the 0-2 border convex too) all three are one object.
    np.testing.assert_array_equal(merge_patches(3, a, b, votes, np.array([40.0, 28.0, 25.0])),
                                  [0, 0, 0])
    # A concave border of too few votes (10) is no crease: nothing is refused.
    np.testing.assert_array_equal(
        merge_patches(3, a, b, np.array([40, 10, 30]), np.array([40.0, 1.0, 25.0])), [0, 0, 0])


def test_merge_patches_needs_half_the_votes_convex():
    a, b = np.array([0, 1]), np.array([1, 2])
    # 0-1: exactly half convex (joined); 1-2: just under half (not joined, not a crease)
    np.testing.assert_array_equal(
        merge_patches(3, a, b, np.array([10, 10]), np.array([5.0, 4.0])), [0, 0, 1])


def _arc(center, r, degrees, n=200):
    ang = np.radians(np.linspace(0.0, degrees, n))
    radial = np.column_stack([np.cos(ang), np.sin(ang)])
    return np.asarray(center) + r * radial, radial


#: Heights [m] of the points of :func:`_arc` (a wall 10 cm high, visited bottom to top
#: 7 times along the arc, so height and angle are not tied).
_ARC_HEIGHTS = np.tile(np.linspace(0.0, 0.1, 29), 7)[:200]


def test_round_footprint_finds_a_container_wall():
    xy, radial = _arc([0.3, -0.1], 0.05, 180.0)
    wall = _round_footprint(xy, radial, _ARC_HEIGHTS)
    assert wall is not None
    np.testing.assert_allclose(wall.center, [0.3, -0.1], atol=1e-9)
    assert wall.radius == pytest.approx(0.05, abs=1e-9)
    assert wall.taper == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("case", ["short-arc", "too-large", "normals-not-radial", "scattered",
                                  "box"])
def test_round_footprint_rejects_what_is_no_container_wall(case):
    # Each case but the box breaks one of the tests of a wall of revolution only.
    if case == "short-arc":  # 55 degrees of arc fit circles of any radius
        xy, n_xy = _arc([0.0, 0.0], 0.05, 55.0)
    elif case == "too-large":  # a 30 cm radius is no cup, bowl or pot
        xy, n_xy = _arc([0.0, 0.0], 0.30, 180.0)
    elif case == "normals-not-radial":  # tangent normals: not a wall of revolution
        xy, radial = _arc([0.0, 0.0], 0.05, 180.0)
        n_xy = radial[:, ::-1] * [1.0, -1.0]
    elif case == "scattered":  # points alternately 20 % inside and outside the circle
        xy, n_xy = _arc([0.0, 0.0], 0.05, 180.0)
        xy = xy * np.where(np.arange(len(xy)) % 2 == 0, 0.8, 1.2)[:, None]
    else:  # two faces of a box meeting at a corner: two normal directions only
        t = np.linspace(0.0, 0.06, 100)
        xy = np.vstack([np.column_stack([t, np.zeros_like(t)]),
                        np.column_stack([np.zeros_like(t), t])])
        n_xy = np.vstack([np.tile([0.0, -1.0], (100, 1)), np.tile([-1.0, 0.0], (100, 1))])
    assert _round_footprint(xy, n_xy, _ARC_HEIGHTS) is None


# ---------------------------------------------------------------------------------------
# Steps and creases between patches (segmentation._step_free, _cut_steps, _patch_normals)
# ---------------------------------------------------------------------------------------

UP = np.array([0.0, 0.0, 1.0])


@pytest.mark.parametrize("p_j, n_j, convex, step", [
    # Same plane: on each other's tangent plane.
    ((0.005, 0.0, 0.0), (0.0, 0.0, 1.0), 0.0, False),
    # Parallel faces 3 mm apart in height: one end 3 mm above the other's plane.
    ((0.005, 0.0, 0.003), (0.0, 0.0, 1.0), 0.0, True),
    # Convex edge (top face and a side facing +x): each end 5 mm below the other's plane.
    ((0.005, 0.0, -0.005), (1.0, 0.0, 0.0), 0.01, False),
    # Concave crease (floor and a wall facing -x): each end 5 mm above the other's plane.
    ((0.005, 0.0, 0.005), (-1.0, 0.0, 0.0), -0.01, True),
])
def test_step_free_tells_a_step_from_a_plane_and_an_edge(p_j, n_j, convex, step):
    from geomodel_ros.core.segmentation import _step_free

    points = np.array([[0.0, 0.0, 0.0], p_j])
    normals = np.array([UP, n_j])
    below_i, below_j, no_step = _step_free(points, normals, np.array([0]), np.array([1]),
                                           np.full(2, 0.001))
    assert below_i[0] + below_j[0] == pytest.approx(convex, abs=1e-12)
    assert bool(no_step[0]) is not step


def _grid(x0: float, x1: float, z: float, spacing: float = 0.004) -> np.ndarray:
    x, y = np.meshgrid(np.arange(x0, x1, spacing), np.arange(0.0, 0.06, spacing))
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])


@pytest.mark.parametrize("height, pieces", [(0.0, 1), (0.003, 2)])
def test_a_patch_is_cut_along_a_step_and_a_plane_is_not(height, pieces):
    from geomodel_ros.core.faces import estimate_normals
    from geomodel_ros.core.segmentation import _cut_steps

    # Two flat strips side by side, the second `height` higher, taken as one patch (as
    # the angle-only patch growing does: their normals are equal).
    points = np.vstack([_grid(-0.06, 0.0, 0.0), _grid(0.0, 0.06, height)])
    _, _, nbrs, sqdist = estimate_normals(points, 16, return_sqdist=True)
    normals = np.tile(UP, (len(points), 1))
    out = _cut_steps(points, normals, nbrs, sqdist, np.zeros(len(points), dtype=np.int64),
                     0.01, np.full(len(points), 0.001))
    assert len(np.unique(out)) == pieces
    if pieces == 2:  # cut exactly along the step
        assert len(np.unique(out[points[:, 0] < 0])) == 1
        assert len(np.unique(out[points[:, 0] >= 0])) == 1


def test_patch_normals_keep_each_face_apart_at_a_crease():
    from geomodel_ros.core.faces import estimate_normals
    from geomodel_ros.core.segmentation import _patch_normals

    # A floor (z = 0, x < 0) meeting a wall (x = 0, z > 0) that faces -x, seen from
    # (-1, 0, 1): the two faces are the two patches.
    floor = _grid(-0.06, -0.002, 0.0)
    wall = _grid(-0.06, -0.002, 0.0)[:, [2, 1, 0]] * np.array([1.0, 1.0, -1.0])
    points = np.vstack([floor, wall]) - np.array([-1.0, 0.0, 1.0])  # sensor at the origin
    patches = np.r_[np.zeros(len(floor)), np.ones(len(wall))].astype(np.int64)
    raw, _, nbrs, _ = estimate_normals(points, 16, return_sqdist=True)
    refined = _patch_normals(points, raw, nbrs, patches, np.full(len(points), 0.001 / 3))
    exact = np.where(patches[:, None] == 0, UP, np.array([-1.0, 0.0, 0.0]))
    err = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", refined, exact), -1, 1)))
    raw_err = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", raw, exact), -1, 1)))
    assert raw_err.max() > 10.0  # the raw normals blend the faces along the crease
    assert err.max() < 1e-6



def test_patch_normals_replace_only_the_normals_whose_neighbourhood_is_off_its_plane():
    from geomodel_ros.core.faces import estimate_normals, smallest_eigenpairs
    from geomodel_ros.core.segmentation import PATCH_NORMAL_MIN_NEIGHBORS, _patch_normals

    # The floor-and-wall crease with 0.3 mm of noise along z: at the crease the
    # neighbourhoods straddle both faces (far off any plane) and take their own face's
    # normal, each the plane fit of its own-patch neighbours; inside the faces they lie
    # within the noise (given as 0.6 mm: twice the floor's) and keep the given normals
    # exactly.
    rng = np.random.default_rng(3)
    floor = _grid(-0.06, -0.002, 0.0)
    wall = _grid(-0.06, -0.002, 0.0)[:, [2, 1, 0]] * np.array([1.0, 1.0, -1.0])
    points = np.vstack([floor, wall]) - np.array([-1.0, 0.0, 1.0])
    points[:, 2] += rng.normal(0.0, 0.0003, len(points))
    patches = np.r_[np.zeros(len(floor)), np.ones(len(wall))].astype(np.int64)
    raw, _, nbrs, _ = estimate_normals(points, 16, return_sqdist=True)
    refined = _patch_normals(points, raw, nbrs, patches, np.full(len(points), 0.0006))
    changed = np.flatnonzero(np.any(refined != raw, axis=1))
    straddle = np.flatnonzero((patches[nbrs] != patches[:, None]).sum(axis=1) >= 4)
    assert len(straddle) and np.isin(straddle, changed).all()
    # Every replaced normal is the plane fit of its neighbours on its own patch (the point
    # itself counted in place of each one on the other), towards the sensor.
    for i in changed:
        same = patches[nbrs[i]] == patches[i]
        assert same.sum() >= PATCH_NORMAL_MIN_NEIGHBORS
        hood = points[np.where(same, nbrs[i], i)]
        q = hood - hood.mean(axis=0)
        _, v = smallest_eigenpairs((q.T @ q)[None] / len(hood))
        assert abs(abs(float(v[0] @ refined[i])) - 1.0) < 1e-9
        assert refined[i] @ points[i] < 0
    # Far from the crease (every neighbour on the own face) nothing changes.
    inside = np.flatnonzero((patches[nbrs] == patches[:, None]).all(axis=1)
                            & (np.abs(points[:, 0] + 1.0) > 0.02)
                            & (np.abs(points[:, 2] + 1.0) > 0.02))
    assert len(inside) > 100 and not np.isin(inside, changed).any()

class _QuadraticNoise:
    """Depth noise sigma = b z^2 [m] (a DepthNoise)."""

    def __init__(self, b: float) -> None:
        self.b = b

    def sigma(self, z):
        return self.b * np.square(z)


def test_working_noise_is_the_sensor_noise_at_the_range_over_the_root_of_the_count():
    from geomodel_ros.core.segmentation import working_noise

    points = np.array([[0.0, 0.0, 0.5], [0.0, 0.0, 2.0], [1.2, 0.0, 1.6]])  # ranges 0.5, 2, 2
    counts = np.array([1, 1, 4])  # input points averaged into each working point
    assert np.all(working_noise(points, counts) == 0.0)  # unknown
    # sigma = 2 mm x z^2: 0.5 mm at 0.5 m, 8 mm at 2 m, 4 mm for the mean of 4 points.
    assert working_noise(points, counts, _QuadraticNoise(0.002)) == pytest.approx(
        [0.0005, 0.008, 0.004], rel=1e-12)


def _cut_noisy_far_plane(height: float, noise_known: bool):
    from geomodel_ros.core.faces import estimate_normals
    from geomodel_ros.core.params import ModelingParams
    from geomodel_ros.core.segmentation import (STEP_NOISE_SIGMAS, STEP_SHARE, _cut_steps,
                                                working_noise)

    # A plane facing the sensor at 2 m, sampled every 8 mm, depth noise sigma = 0.5 mm x
    # z^2 = 2 mm along z (the difference of two neighbours' depths spreads 2.8 mm, beyond
    # the fixed 1 mm step; the step is STEP_NOISE_SIGMAS sigma with the noise known); the
    # half at x >= 0 is `height` nearer the sensor. Exact normals: the test is of the step,
    # not of normals.
    rng = np.random.default_rng(3)
    x, y = np.meshgrid(np.arange(-0.2, 0.2, 0.008), np.arange(-0.1, 0.1, 0.008))
    x, y = x.ravel(), y.ravel()
    z = 2.0 - np.where(x >= 0, height, 0.0) + rng.normal(0.0, 0.002, x.size)
    points = np.column_stack([x, y, z])
    _, _, nbrs, sqdist = estimate_normals(points, 16, return_sqdist=True)
    normals = np.tile(-UP, (len(points), 1))
    params = ModelingParams(seg_plane_threshold=0.004)
    noise = _QuadraticNoise(0.0005) if noise_known else None
    step = np.maximum(STEP_SHARE * params.seg_plane_threshold,
                      STEP_NOISE_SIGMAS * working_noise(points, np.ones(len(x)), noise))
    out = _cut_steps(points, normals, nbrs, sqdist, np.zeros(len(points), dtype=np.int64),
                     0.03, step)
    return x, out


def test_a_noisy_far_plane_loses_fewer_points_to_steps_with_its_noise_known():
    _, fixed = _cut_noisy_far_plane(0.0, False)
    _, known = _cut_noisy_far_plane(0.0, True)
    lost_fixed = len(fixed) - np.bincount(fixed).max()
    lost_known = len(known) - np.bincount(known).max()
    assert lost_known <= 0.03 * len(known)  # specks of points far off by noise at most
    assert lost_fixed >= 2 * lost_known


def test_a_noisy_far_plane_is_still_cut_at_a_step_well_above_its_noise():
    x, out = _cut_noisy_far_plane(0.02, True)  # 20 mm = 10 sigma
    left, right = np.bincount(out[x < 0]).argmax(), np.bincount(out[x >= 0]).argmax()
    assert left != right
    assert np.mean(out[x < 0] == left) > 0.95 and np.mean(out[x >= 0] == right) > 0.95


def test_patch_normals_keep_the_whole_neighbourhood_on_one_noisy_surface():
    from geomodel_ros.core.faces import estimate_normals
    from geomodel_ros.core.segmentation import _patch_normals

    # A noisy plane facing the sensor at 1 m (sigma 1 mm), cut into two patches at x = 0
    # as noisy normals cut one surface: its points lie off their neighbourhood's plane by
    # about the noise, so no crease is blended and the whole neighbourhood (16 points)
    # gives a better normal than the few on one side of the cut.
    rng = np.random.default_rng(5)
    x, y = np.meshgrid(np.arange(-0.06, 0.06, 0.004), np.arange(-0.06, 0.06, 0.004))
    x, y = x.ravel(), y.ravel()
    points = np.column_stack([x, y, 1.0 + rng.normal(0.0, 0.001, x.size)])
    patches = (x >= 0).astype(np.int64)
    raw, _, nbrs, _ = estimate_normals(points, 16, return_sqdist=True)
    gated = _patch_normals(points, raw, nbrs, patches, np.full(len(points), 0.001))
    one_sided = _patch_normals(points, raw, nbrs, patches, np.zeros(len(points)))
    border = np.abs(x) < 0.008

    def err(n):
        return np.degrees(np.arccos(np.clip(np.abs(n[border, 2]), -1.0, 1.0)))

    assert np.median(err(gated)) < np.median(err(one_sided))
    assert np.mean(np.all(gated == raw, axis=1)) > 0.5  # most keep the whole neighbourhood


def test_a_link_takes_the_smaller_step_of_its_two_ends():
    from geomodel_ros.core.segmentation import _step_free

    # Parallel faces 3 mm apart: a dense point (step 1 mm) and a sparse, noisy one (step
    # 10 mm). The sparse end's noise does not hide the step from the dense end.
    points = np.array([[0.0, 0.0, 0.0], [0.005, 0.0, 0.003]])
    normals = np.array([UP, UP])
    no_step = _step_free(points, normals, np.array([0, 1]), np.array([1, 0]),
                         np.array([0.001, 0.01]))[2]
    assert not no_step.any()
    # Both ends noisy (10 mm): 3 mm is within their noise.
    assert _step_free(points, normals, np.array([0]), np.array([1]), np.full(2, 0.01))[2][0]


def test_segment_members_are_each_segments_valid_rows_in_order():
    comp = np.array([3, 1, 3, -1, 1, 7, 3, 7])
    valid = np.array([True, True, True, False, False, True, True, True])
    got = segment_members(comp, valid)
    assert list(got) == [1, 3, 7]
    assert [g.tolist() for g in got.values()] == [[1], [0, 2, 6], [5, 7]]
    assert segment_members(comp, np.zeros(8, dtype=bool)) == {}


@pytest.mark.parametrize("seed", range(8))
def test_closest_gap_is_the_brute_force_nearest_pair(seed):
    # Two random blobs of grid points (coordinates on a 1 mm grid: many equal distances)
    # 2-20 cm apart, the smaller one large enough to be searched through its cells: the
    # gap's ends are the brute-force nearest pair, the first of the smaller segment's
    # points in its order among equally near ones, or no gap when the nearest pair is
    # within a link or beyond seg_max_occlusion_gap.
    rng = np.random.default_rng(seed)
    params = ModelingParams()
    n_a = GAP_DIRECT_POINTS + 200  # searched through its cells
    a = np.round(rng.normal(0.0, 0.03, (n_a, 3)), 3) + [0.0, 0.0, 1.0]
    b = np.round(rng.normal(0.0, 0.05, (900, 3)), 3) + [rng.uniform(0.1, 0.3), 0.0, 1.0]
    points = np.vstack([a, b])
    comp = np.repeat([0, 1], [n_a, 900])
    segs = _Segments(points, comp, np.ones(len(points), dtype=bool))
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    k = int(np.argmin(d.min(axis=1)))
    length = d[k].min()
    gap = _closest_gap(segs, 1, 0, params)
    link = params.seg_max_edge_factor * params.seg_voxel_size
    if length <= link or length > params.seg_max_occlusion_gap:
        assert gap is None
        return
    assert gap is not None and (gap.small, gap.big, gap.pa) == (0, 1, k)
    assert gap.length == pytest.approx(length, abs=1e-12)
    assert np.linalg.norm(points[gap.pb] - a[k]) == pytest.approx(length, abs=1e-12)


def test_gap_candidates_keep_every_equally_near_point():
    # A row of points 1 cm apart along x facing a single point 5 cm above the row's middle
    # pair: both middle points are equally near and both are candidates; the far ends of
    # the row (cells farther than the nearest cell's reach) are not.
    q = np.column_stack([np.arange(-0.105, 0.11, 0.01), np.zeros(22), np.zeros(22)])
    tree = cKDTree(np.array([[0.0, 0.05, 0.0]]))
    got, reached = _gap_candidates(q, tree, 0.02, 0.15)
    assert reached == pytest.approx(np.hypot(0.005, 0.05), abs=1e-12)
    assert {10, 11} <= set(got.tolist())
    assert 0 not in got and 21 not in got
    assert np.all(np.diff(got) > 0)
    # Nothing within the largest gap: no candidates.
    got, reached = _gap_candidates(q, tree, 0.02, 0.01)
    assert len(got) == 0 and reached == np.inf


def _gap_scene(occluder_label: int) -> tuple[np.ndarray, np.ndarray]:
    """Two parts of one plane 1 m in front of the sensor, 60 mm apart, and a strip in front.

    Part 0 spans x in [-100, -30] mm, part 1 [30, 100] mm, both y in [-30, 30] mm at z = 1 m
    (working points 4 mm apart, normals towards the sensor); the strip, 0.1 m nearer, covers
    the gap's rays. The strip's points get label ``occluder_label``. Returns the points
    (N, 3) [m] and their labels (N,).
    """
    step = 0.004
    y = np.arange(-0.03, 0.03 + 1e-9, step)
    parts = [np.arange(-0.1, -0.03 + 1e-9, step), np.arange(0.03, 0.1 + 1e-9, step)]
    pts, lab = [], []
    for label, x in enumerate(parts):
        gx, gy = np.meshgrid(x, y)
        pts.append(np.column_stack([gx.ravel(), gy.ravel(), np.ones(gx.size)]))
        lab.append(np.full(gx.size, label))
    # the strip on the rays of x in [-34, 34] mm at 1 m, seen at 0.9 m
    gx, gy = np.meshgrid(np.arange(-0.034, 0.034 + 1e-9, step) * 0.9, y * 0.9)
    pts.append(np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, 0.9)]))
    lab.append(np.full(gx.size, occluder_label))
    return np.vstack(pts), np.concatenate(lab)


@pytest.mark.parametrize("occluder, joined", [(2, True), (0, False), (1, False)],
                         ids=["third-object", "part-0-itself", "part-1-itself"])
def test_occlusion_join_needs_a_third_object_in_front_of_the_gap(occluder, joined):
    # The same gap, hidden by the same nearer points: a third object there hides the
    # plane's continuation (one surface seen on both sides of it), but one of the two parts
    # in front of the gap itself (a container's wall in front of its own floor) bounds the
    # other surface there: no evidence that it continues.
    points, comp = _gap_scene(occluder)
    normals = np.tile([0.0, 0.0, -1.0], (len(points), 1))
    params = ModelingParams()
    out = join_occluded_parts(points, normals, comp, np.ones(len(points), dtype=bool), params)
    left, right = out[comp == 0], out[comp == 1]
    assert len(np.unique(left)) == 1 and len(np.unique(right)) == 1
    assert (left[0] == right[0]) == joined
    # the strip in front is never joined to either part (it lies off their plane)
    if occluder == 2:
        assert not np.isin(out[comp == 2], out[comp < 2]).any()


def _can_front(x0: float, y0: float, y1: float, r: float = 0.04) -> np.ndarray:
    """Points 4 mm apart on the front (facing the sensor) of an upright can 1 m away."""
    theta = np.arange(-1.3, 1.3 + 1e-9, 0.004 / r)
    y = np.arange(y0, y1 + 1e-9, 0.004)
    t, yy = np.meshgrid(theta, y)
    return np.column_stack([x0 + r * np.sin(t.ravel()), yy.ravel(), 1.0 - r * np.cos(t.ravel())])


def _gap_of(parts: list[np.ndarray]) -> tuple[_Segments, _Gap]:
    points = np.vstack(parts)
    comp = np.repeat(np.arange(len(parts)), [len(p) for p in parts])
    segs = _Segments(points, comp, np.ones(len(points), dtype=bool))
    d, nearest = cKDTree(parts[1]).query(parts[0])
    pa = int(np.argmin(d))
    pb = len(parts[0]) + int(nearest[pa])
    u = points[pb] - points[pa]
    return segs, _Gap(0, 1, pa, pb, float(np.linalg.norm(u)), u / np.linalg.norm(u))


@pytest.mark.parametrize("case, one", [
    ("one-can-above-and-below-a-band", True),
    ("two-cans-side-by-side", False),
    ("a-small-can-piece-beside-a-can", False),
    ("two-flat-parts", True),
])
def test_a_round_part_joins_only_what_is_modeled_with_it_as_one_round_shape(case, one):
    # The model graph's own models decide: the two visible parts of one can (a band in
    # front hides its middle) are one cylinder together; two cans are no round shape; two
    # flat parts are no round parts, so their models ask nothing more. A piece of a thinner
    # can (r 30 mm, 160 points) 23 mm beside a can (837 points): the can's cylinder verifies
    # on the two together (the piece is under a fifth of them) but none of the piece's
    # points lie in its band, so the two are no one surface.
    parts = {
        "one-can-above-and-below-a-band": [_can_front(0.0, -0.06, -0.01),
                                           _can_front(0.0, 0.01, 0.06)],
        "two-cans-side-by-side": [_can_front(-0.05, -0.06, 0.06),
                                  _can_front(0.05, -0.06, 0.06)],
        "a-small-can-piece-beside-a-can": [_can_front(0.0, -0.06, 0.06),
                                           _can_front(0.09, 0.0, 0.028, r=0.03)],
        "two-flat-parts": [_grid(-0.1, -0.03, 1.0), _grid(0.03, 0.1, 1.0)],
    }[case]
    segs, gap = _gap_of(parts)
    assert _one_round_surface(segs, gap, ModelingParams()) == one
    if case != "two-flat-parts":  # each part alone is a can
        assert all(segs.model_types[s] == "cylinder" for s in (0, 1))
