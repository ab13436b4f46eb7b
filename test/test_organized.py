"""Organized fast path of the segmentation (``geomodel_ros.core.organized``).

Unit level on hand-built organized planes (pixel spacing, block size, stencil, working
points, links and normals worked out by hand), then the two paths of ``segment_scene`` /
``model_scene`` against each other on rendered organized scenes and their unorganized
copies, and on real Kinect frames (touching objects the fast path once merged); the
crease test per length of the fast path's smooth patches on hand-built strips.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from data_helpers import require

from geomodel_ros.core import faces
from geomodel_ros.core.errors import InputError
from geomodel_ros.core.faces import WorkingCloud, _link_angle_limits
from geomodel_ros.core.fastmath import rows_finite
from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.organized import (BLOCK_SPACING_SHARE, _stencil_links, block_size,
                                         grid_cloud, stencil_offsets)
from geomodel_ros.core.params import ModelingParams, load_params_file
from geomodel_ros.core.segmentation import segment_scene
from geomodel_ros.tools.benchmark import data_dir
from geomodel_ros.tools.evaluation import segmentation_scores
from geomodel_ros.tools.io import load_osd
from geomodel_ros.tools.paths import CONFIG_DIR
from geomodel_ros.tools.synth import SENSOR_NOISE, render_scene

FAST = ModelingParams(organized_fast_path=True)
#: Focal length [px] of the hand-built images: at 1 m a pixel is 1 mm wide.
FOCAL = 1000.0


def _plane_image(depth: np.ndarray) -> np.ndarray:
    """Organized (H, W, 3) cloud of a pinhole camera (f = FOCAL) seeing ``depth`` (H, W) [m].

    Pixel (v, u) looks along ((u - cx) / f, (v - cy) / f, 1); NaN depth gives a NaN row.
    """
    h, w = depth.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    x = (u - (w - 1) / 2.0) / FOCAL
    y = (v - (h - 1) / 2.0) / FOCAL
    return np.stack([x * depth, y * depth, depth], axis=2)


def _cloud(image: np.ndarray, params: ModelingParams = FAST):
    flat = image.reshape(-1, 3)
    finite = np.flatnonzero(rows_finite(flat))
    return grid_cloud(flat, image.shape[:2], finite, params), flat, finite


# ------------------------------------------------------------------ stencil and block size

def test_stencil_links_follow_the_offsets_on_the_block_grid_and_skip_empty_blocks():
    # A 3 x 4 block grid with blocks (0, 1) and (2, 3) empty; working point i sits at
    # (column, row, 0.1 * i) [m], so a link's squared length is dc^2 + dr^2 + (0.1 di)^2.
    grid = np.array([[0, -1, 1, 2], [3, 4, 5, 6], [7, 8, 9, -1]])
    used = np.flatnonzero(grid.ravel() >= 0)
    rows, cols = used // 4, used % 4
    wp = np.column_stack([cols, rows, 0.1 * np.arange(len(used))]).astype(np.float64)
    offsets = np.array([[0, 0], [0, 1], [1, 0], [-1, -1], [0, -2]])
    nb, sq = _stencil_links(wp, grid, used, offsets)
    assert nb.shape == sq.shape == (10, 5) and nb.dtype == np.int64
    # Point 4 at block (1, 1): itself, (1, 2) -> 5, (2, 1) -> 8, (0, 0) -> 0, (1, -1): none.
    np.testing.assert_array_equal(nb[4], [4, 5, 8, 0, -1])
    np.testing.assert_allclose(sq[4, :4], [0.0, 1.01, 1.16, 2.16], rtol=0, atol=1e-12)
    assert sq[4, 4] == np.inf
    # Point 0 at block (0, 0): right of it the empty block, below it point 3; nothing at
    # (-1, -1) nor (0, -2) (outside the grid).
    np.testing.assert_array_equal(nb[0], [0, -1, 3, -1, -1])
    assert np.isinf(sq[0, [1, 3, 4]]).all() and sq[0, 2] == pytest.approx(1.09, abs=1e-12)
    # Point 9 at block (2, 2): (2, 3) is empty, (3, 2) outside, (1, 1) -> 4, (2, 0) -> 7.
    np.testing.assert_array_equal(nb[9], [9, -1, -1, 4, 7])
    np.testing.assert_allclose(sq[9, [3, 4]], [2.25, 4.04], rtol=0, atol=1e-12)
    # Every link's length is the distance of its two points, every missing link inf.
    ok = nb >= 0
    d = wp[nb[ok]] - np.repeat(wp, 5, axis=0)[ok.ravel()]
    np.testing.assert_array_equal(sq[ok], (d[:, 0] ** 2 + d[:, 1] ** 2) + d[:, 2] ** 2)
    assert np.isinf(sq[~ok]).all()


def test_stencil_is_the_smallest_disc_with_enough_offsets():
    # r^2 <= 4 holds 1 + 4 + 4 + 4 = 13 offsets, r^2 <= 5 adds the 8 knight moves: 21 >= 16.
    off = stencil_offsets(16)
    assert len(off) == 21
    assert tuple(off[0]) == (0, 0)
    assert {tuple(o) for o in off[1:5]} == {(0, 1), (1, 0), (0, -1), (-1, 0)}
    sq = (off * off).sum(axis=1)
    assert sq.max() == 5 and np.all(np.diff(sq) >= 0)
    assert {tuple(o) for o in off} == {tuple(-o) for o in off}   # symmetric
    assert len(stencil_offsets(9)) == 9    # the 3 x 3 window
    assert len(stencil_offsets(5)) == 5    # the 4-neighbourhood and the point


@pytest.mark.parametrize("voxel, expected", [(0.004, 3), (0.006, 5), (0.0005, 1)])
def test_block_size_from_the_pixel_spacing(voxel, expected):
    # Fronto-parallel plane at 1 m, f = 1000 px: adjacent pixels are 1 mm apart; the block
    # edge is round(voxel * sqrt(2/3) / 1 mm): 3.27 -> 3, 4.90 -> 5, 0.41 -> 1 (never 0).
    assert BLOCK_SPACING_SHARE == pytest.approx(math.sqrt(2.0 / 3.0))
    image = _plane_image(np.ones((40, 60)))
    assert block_size(image, voxel) == expected


def test_block_size_needs_adjacent_finite_pixels():
    # A checkerboard of holes: no two adjacent pixels are finite -> no spacing, voxel path.
    depth = np.ones((20, 20))
    depth[(np.add.outer(np.arange(20), np.arange(20)) % 2) == 1] = np.nan
    assert block_size(_plane_image(depth), 0.004) is None
    grid, _, _ = _cloud(_plane_image(depth))
    assert grid is None


# ------------------------------------------------------------------ working cloud of a plane

def test_plane_blocks_links_and_normals():
    # 60 x 80 pixels at 1 m, 1 mm apart; blocks of 3 x 3 -> 20 x 27 working points (the last
    # column of blocks holds 2 pixel columns).
    grid, flat, finite = _cloud(_plane_image(np.ones((60, 80))))
    assert grid.block == 3
    assert len(grid.points) == 20 * 27
    assert grid.counts.sum() == 60 * 80
    assert set(np.unique(grid.counts)) == {6, 9}
    np.testing.assert_array_equal(np.bincount(grid.inverse), grid.counts)
    # Every pixel's working point is the mean of its own 3 x 3 block.
    v, u = finite // 80, finite % 80
    np.testing.assert_array_equal(grid.inverse, (v // 3) * 27 + u // 3)
    np.testing.assert_allclose(grid.points[:, 2], 1.0, atol=1e-12)
    # Normals face the sensor (-z) and the plane has no variation.
    np.testing.assert_allclose(grid.normals, np.tile([0.0, 0.0, -1.0], (len(grid.points), 1)),
                               atol=1e-9)
    assert grid.variation.max() < 1e-9
    # Self first at distance 0; the right neighbour of an interior block is 3 mm away.
    np.testing.assert_array_equal(grid.neighbors[:, 0], np.arange(len(grid.points)))
    np.testing.assert_array_equal(grid.sqdist[:, 0], 0.0)
    interior = 5 * 27 + 5
    right = list(map(tuple, stencil_offsets(16))).index((0, 1))
    assert grid.neighbors[interior, right] == interior + 1
    assert grid.sqdist[interior, right] == pytest.approx(0.003 ** 2, rel=1e-9)
    # Nearest offsets first: the four 1-block links are the shortest kept ones.
    assert np.all(grid.sqdist[interior, 1:5] <= grid.sqdist[interior, 5:].min())


def test_holes_get_no_working_point_and_missing_links_are_marked():
    depth = np.ones((30, 30))
    depth[9:18, 9:18] = np.nan          # exactly the blocks (3..5, 3..5)
    grid, _, finite = _cloud(_plane_image(depth))
    assert len(grid.points) == 100 - 9
    assert grid.counts.sum() == len(finite) == 900 - 81
    missing = ~np.isfinite(grid.sqdist)
    # A removed link holds the point itself.
    rows = np.nonzero(missing)[0]
    np.testing.assert_array_equal(grid.neighbors[missing], rows)
    assert missing.any()


def test_depth_step_is_never_bridged():
    # Left half at 1.0 m, right half at 1.1 m; the step (column 40) cuts through the blocks
    # of columns 39-41. A 10 cm step is far beyond a jump of 2.5 voxels (10 mm).
    depth = np.ones((45, 81))
    depth[:, 40:] = 1.1
    image = _plane_image(depth)
    grid, flat, finite = _cloud(image)
    near = np.abs(grid.points[:, 2] - 1.0) < 1e-9
    far = np.abs(grid.points[:, 2] - 1.1) < 1e-9
    # No working point floats between the two planes ...
    assert np.all(near | far)
    # ... every pixel's working point lies on the pixel's own plane ...
    np.testing.assert_allclose(grid.points[grid.inverse, 2], flat[finite, 2], atol=1e-9)
    # ... no kept link joins the planes, and the normals stay those of the planes.
    kept = np.isfinite(grid.sqdist)
    i = np.repeat(np.arange(len(grid.points)), grid.neighbors.shape[1])[kept.ravel()]
    j = grid.neighbors[kept]
    assert np.all(near[i] == near[j])
    np.testing.assert_allclose(np.abs(grid.normals[:, 2]), 1.0, atol=1e-9)
    assert grid.variation.max() < 1e-9


def test_restricted_neighbourhoods_stay_in_the_subset():
    depth = np.ones((45, 81))
    depth[:, 40:] = 1.1
    grid, _, _ = _cloud(_plane_image(depth))
    subset = np.flatnonzero(np.abs(grid.points[:, 2] - 1.1) < 1e-9)
    normals, variation, nb, sq = grid.restricted(subset)
    assert nb.shape == (len(subset), grid.neighbors.shape[1])
    assert nb.min() >= 0 and nb.max() < len(subset)
    np.testing.assert_array_equal(nb[:, 0], np.arange(len(subset)))
    # The same links as the full cloud, renumbered.
    full = grid.neighbors[subset]
    kept = np.isfinite(sq)
    np.testing.assert_array_equal(subset[nb[kept]], full[kept])
    np.testing.assert_allclose(sq[kept], grid.sqdist[subset][kept])
    np.testing.assert_allclose(np.abs(normals[:, 2]), 1.0, atol=1e-9)


# ------------------------------------------------------------------ the two paths

def test_fast_path_off_keeps_the_voxel_path_exactly():
    scene = render_scene("apart")
    params = ModelingParams()
    assert params.organized_fast_path is False
    organized = segment_scene(scene.organized, params).labels
    flat = segment_scene(scene.organized.reshape(-1, 3), params).labels
    shaped = segment_scene(scene.organized.reshape(-1, 3), params,
                           organized_shape=scene.organized.shape[:2]).labels
    np.testing.assert_array_equal(organized, flat)
    np.testing.assert_array_equal(shaped, flat)


def test_unorganized_input_ignores_the_fast_path():
    scene = render_scene("apart")
    flat = scene.organized.reshape(-1, 3)
    np.testing.assert_array_equal(segment_scene(flat, FAST).labels,
                                  segment_scene(flat, ModelingParams()).labels)


def test_organized_shape_must_match_the_points():
    with pytest.raises(InputError, match=r"organized_shape \(10, 10\) does not match 99"):
        segment_scene(np.zeros((99, 3)), FAST, organized_shape=(10, 10))


def _objects(name: str, noise, params: ModelingParams):
    scene = render_scene(name, noise=noise, rng=1)
    shape = scene.organized.shape[:2]
    labels, result = model_scene(scene.organized.reshape(-1, 3), params, organized_shape=shape)
    return scene, labels, result


def _matched(labels_a, labels_b):
    """Pairs (a, b) of segments of the two labelings that overlap with IoU >= 0.9."""
    pairs = []
    for a in np.unique(labels_a[labels_a >= 0]):
        in_a = labels_a == a
        b = np.bincount(labels_b[in_a & (labels_b >= 0)]).argmax() if (in_a & (labels_b >= 0)
                                                                      ).any() else -1
        in_b = labels_b == b
        iou = (in_a & in_b).sum() / (in_a | in_b).sum()
        pairs.append((int(a), int(b), float(iou)))
    return pairs


#: Noise-free, the voxel path cuts a chip of 14 working points (34 input points) off the
#: occluded scene's box whose one border to the box votes 11 convex of 22: a tie, which no
#: longer joins (:func:`geomodel_ros.core.joins.merge_patches`); the chip is too small for
#: an object and the box's height comes out 60.5 mm (true 60 mm) instead of 63.5 mm, while
#: the organized path has no such chip and keeps 63.5 mm: 3 mm apart.
_VOXEL_CHIP = pytest.mark.xfail(strict=True, reason="voxel-path chip (see _VOXEL_CHIP)")


@pytest.mark.parametrize("name, noisy", [("apart", False), ("apart", True),
                                         pytest.param("occluded", False, marks=_VOXEL_CHIP),
                                         ("occluded", True)])
def test_both_paths_give_the_same_objects(name, noisy):
    noise = SENSOR_NOISE if noisy else None
    voxel = dataclasses.replace(FAST, organized_fast_path=False)
    _, lab_v, res_v = _objects(name, noise, voxel)
    scene, lab_g, res_g = _objects(name, noise, FAST)
    assert len(res_g.objects) == len(res_v.objects)
    pairs = _matched(lab_v, lab_g)
    assert len(pairs) == len(res_v.objects)
    assert len({b for _, b, _ in pairs}) == len(pairs)       # one to one
    assert min(iou for *_, iou in pairs) >= 0.9
    by_id_v = {o.id: o for o in res_v.objects}
    by_id_g = {o.id: o for o in res_g.objects}
    for a, b, _ in pairs:
        ov, og = by_id_v[a], by_id_g[b]
        assert og.type == ov.type
        # Sizes come from all points of nearly the same segments: within a millimetre. (A
        # box's two edges of nearly one direction may swap names, so the edges are compared
        # as sorted values.)
        assert og.dimensions.keys() == ov.dimensions.keys()
        np.testing.assert_allclose(sorted(og.dimensions.values()),
                                   sorted(ov.dimensions.values()), atol=1e-3)


def test_stacked_scene_same_types_on_both_paths():
    voxel = dataclasses.replace(FAST, organized_fast_path=False)
    types_v = sorted(o.type for o in _objects("stacked", None, voxel)[2].objects)
    types_g = sorted(o.type for o in _objects("stacked", None, FAST)[2].objects)
    assert types_g == types_v == ["cuboid", "cuboid", "cuboid", "cylinder", "plane"]


def test_model_scene_hands_the_shape_to_the_segmentation(monkeypatch):
    import geomodel_ros.core.modeling as modeling
    import geomodel_ros.core.segmentation as segmentation

    calls = []

    def spy(points, shape, finite, params):
        calls.append(tuple(shape))
        return grid_cloud(points, shape, finite, params)

    monkeypatch.setattr(segmentation, "grid_cloud", spy)
    # The labels are the segmentation's but for the support points given back to the
    # objects afterwards (band_claim, tested on its own): left out here.
    monkeypatch.setattr(modeling, "give_back_band_points", lambda _pts, labels, *_: labels)
    scene = render_scene("occluded")
    shape = scene.organized.shape[:2]
    labels, _ = model_scene(scene.organized.reshape(-1, 3), FAST, organized_shape=shape)
    assert calls == [shape]
    np.testing.assert_array_equal(labels, segment_scene(scene.organized, FAST).labels)
    # Without the shape, or with the fast path off, the image grid is not used.
    model_scene(scene.organized.reshape(-1, 3), FAST)
    model_scene(scene.organized.reshape(-1, 3), ModelingParams(), organized_shape=shape)
    assert calls == [shape, shape]


def test_touching_scene_same_objects_on_both_paths():
    # Box face to face with a box, cylinder against a box: the concave creases and the
    # steps keep all three apart on both paths.
    voxel = dataclasses.replace(FAST, organized_fast_path=False)
    types_v = sorted(o.type for o in _objects("touching", None, voxel)[2].objects)
    types_g = sorted(o.type for o in _objects("touching", None, FAST)[2].objects)
    assert types_g == types_v == ["cuboid", "cuboid", "cylinder", "plane"]


@pytest.mark.parametrize("frame, config", [(17, None), (17, "kinect.yaml"), (42, None)])
def test_real_kinect_touching_objects_apart(frame, config):
    # learn17: a box stacked on a box; learn42: two cans side by side. Before the crease
    # test per length the fast path grew one smooth patch over the concave crease between
    # them in small turns on its ~3 mm links (one segment each, IoU 0.29-0.68). Each labelled
    # object must now be its own segment (IoU >= 0.9: measured 0.94-0.99) and none merged.
    path = require(data_dir() / "osd_learn" / f"learn{frame}.pcd")
    points, gt = load_osd(path)
    base = ModelingParams() if config is None else load_params_file(CONFIG_DIR / config)
    params = dataclasses.replace(base, organized_fast_path=True)
    seg = segment_scene(points.reshape(480, 640, 3), params)
    objects = [int(g) for g in np.unique(gt) if g >= 2]
    assert len(objects) == 2
    scores = segmentation_scores(seg.labels, gt, objects)
    assert min(s.iou for s in scores) >= 0.9
    assert not any(s.under for s in scores)


def test_real_kinect_frame_two_boxes():
    # learn0: two boxes on a table, 640 x 480, config/kinect.yaml; both paths segment each
    # box with IoU >= 0.95 (measured: voxel 0.98 / 0.98, fast path 0.98 / 0.97).
    path = require(data_dir() / "osd_learn" / "learn0.pcd")
    points, gt = load_osd(path)
    params = dataclasses.replace(load_params_file(CONFIG_DIR / "kinect.yaml"),
                                 organized_fast_path=True)
    seg = segment_scene(points.reshape(480, 640, 3), params)
    objects = [int(g) for g in np.unique(gt) if g >= 2]
    assert len(objects) == 2
    scores = segmentation_scores(seg.labels, gt, objects)
    assert min(s.iou for s in scores) >= 0.95
    assert not any(s.under for s in scores)


# ------------------------------------------------------------------ crease test per length

def _strip(step: float, turn_start: float, turn_end: float, total_turn: float,
           length: float = 0.05, rows: int = 3) -> WorkingCloud:
    """Working cloud of a strip of ``rows`` x (length / step) points ``step`` [m] apart.

    The points lie on the plane z = 1 m; only the normals are set by hand (so that the
    turns along each link are known exactly): (0, 0, -1) for x < ``turn_start``, turning
    about the y axis at a constant rate to ``total_turn`` [rad] at ``turn_end`` [m] and
    constant beyond. Each point links to its 4-neighbours (and itself, first).
    """
    nx = int(round(length / step)) + 1
    x = np.arange(nx) * step
    angle = total_turn * np.clip((x - turn_start) / (turn_end - turn_start), 0.0, 1.0)
    idx = np.arange(rows * nx).reshape(rows, nx)
    pts = np.column_stack([np.tile(x, rows), np.repeat(np.arange(rows) * step, nx),
                           np.ones(rows * nx)])
    normals = np.column_stack([np.tile(np.sin(angle), rows), np.zeros(rows * nx),
                               -np.tile(np.cos(angle), rows)])
    pad = np.pad(idx, 1, constant_values=-1)
    shifts = [(0, 0), (0, 1), (0, -1), (1, 0), (-1, 0)]
    nb = np.stack([pad[1 + dr:1 + dr + rows, 1 + dc:1 + dc + nx].ravel()
                   for dr, dc in shifts], axis=1)
    nb = np.where(nb >= 0, nb, idx.ravel()[:, None])
    d = pts[nb] - pts[:, None, :]
    sq = np.einsum("mkj,mkj->mk", d, d)
    sq[(nb == idx.ravel()[:, None]) & (np.arange(5) > 0)] = np.inf   # missing links
    return WorkingCloud(pts, normals, np.zeros(rows * nx), nb,
                        np.ones(rows * nx, dtype=np.int64), np.arange(rows * nx), sq)


THRESHOLD = 0.2      # rad, the default face_angle_threshold (11.5 deg)


def test_link_angle_limits_scale_with_the_link_length():
    # Links of 1, 2, 4 and 8 mm and a removed one, crease_length 4 mm: turns of a quarter,
    # a half and all of the 0.2 rad threshold; a link of a voxel or more keeps 0.2 rad.
    sq = np.array([[0.001 ** 2, 0.002 ** 2, 0.004 ** 2, 0.008 ** 2, np.inf]])
    limits = _link_angle_limits(sq, THRESHOLD, 0.004)
    np.testing.assert_allclose(limits, np.cos([[0.05, 0.1, 0.2, 0.2, 0.2]]), rtol=0,
                               atol=1e-15)


def test_crease_crossed_in_small_turns_splits_only_per_length():
    # A crease the normals round over 15 mm (90 deg from x = 10 to 25 mm), points 1 mm apart:
    # each link turns 6 deg, half the 11.5 deg threshold, so the link-by-link test grows one
    # face over the crease; per 4 mm of surface the turn is 24 deg: two faces.
    cloud = _strip(0.001, 0.010, 0.025, math.pi / 2)
    assert faces.split_faces(cloud, THRESHOLD, 0.04, 12, 0.01).count == 1
    split = faces.split_faces(cloud, THRESHOLD, 0.04, 12, 0.01, crease_length=0.004)
    assert split.count == 2
    x = cloud.points[:, 0]
    left, right = split.labels[x <= 0.010], split.labels[x >= 0.025]
    assert len(set(left)) == 1 and len(set(right)) == 1 and left[0] != right[0]
    assert split.adjacency[0, 1] and split.adjacency[1, 0]


def test_gently_curved_surface_stays_one_face_per_length():
    # Negative case: a cylinder of radius 5 cm turns 1.15 deg per mm (4.6 deg per 4 mm),
    # within the threshold per 4 mm: one face with and without the per-length test. (Faces
    # of 3 points count, so a test too strict for this curvature would show as one face per
    # column of the strip.)
    cloud = _strip(0.001, 0.0, 0.05, 0.05 / 0.05)
    assert faces.split_faces(cloud, THRESHOLD, 0.04, 3, 0.01).count == 1
    assert faces.split_faces(cloud, THRESHOLD, 0.04, 3, 0.01, crease_length=0.004).count == 1


def test_links_of_a_voxel_or_more_keep_the_whole_threshold():
    # Points 5 mm apart turning 10 deg per link (< 11.5 deg): one face with crease_length
    # 4 mm (the links are longer than it); 13 deg per link (> 11.5 deg) splits each link.
    gentle = _strip(0.005, 0.0, 0.2, math.radians(10.0) * 40, length=0.2)
    assert faces.split_faces(gentle, THRESHOLD, 0.04, 12, 0.01,
                             crease_length=0.004).count == 1
    sharp = _strip(0.005, 0.0, 0.2, math.radians(13.0) * 40, length=0.2)
    labels = faces.split_faces(sharp, THRESHOLD, 0.04, 3, 0.01, crease_length=0.004).labels
    # No link along x survives: every column of 3 points is a face of its own.
    assert len(np.unique(labels)) == 41
