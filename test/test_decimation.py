"""Decimation of organized clouds (``decimation``): the samples and the labels spread back.

Modules: core.decimation (decimate, spread_labels), core.modeling (``model_scene`` with
``decimation``), core.params.

The images below are built by hand (planes at known depths, a depth step, holes), so each
expected sample position and label follows from the definitions: samples at the block
centres ``d // 2 + d * i``; a pixel takes the label of its block's sample when within
``seg_max_edge_factor`` times the larger of the voxel and the sample's spacing (its reach),
else that of the nearest sample of the eight blocks around whose reach holds it, else -1.
"""

from __future__ import annotations

import numpy as np
import pytest

from geomodel_ros.core.decimation import decimate, spread_labels
from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import ModelingParams, ParameterError
from geomodel_ros.tools.evaluation import segmentation_scores
from geomodel_ros.tools.synth.clutter import render_clutter

PITCH = 0.002  # [m] between neighbouring pixels of the hand-built images
VOXEL, FACTOR = 0.004, 2.5


def plane_image(h: int, w: int, depth: float = 1.0) -> np.ndarray:
    """(h, w, 3) points of a fronto-parallel plane at ``depth`` with PITCH between pixels."""
    ys, xs = np.mgrid[0:h, 0:w].astype(float)
    return np.dstack([xs * PITCH, ys * PITCH, np.full((h, w), depth)])


@pytest.mark.parametrize("step, rows, cols", [(2, [1, 3], [1, 3, 5]),
                                              (3, [1, 4], [1, 4]),
                                              (4, [2], [2, 6])])
def test_samples_are_the_block_centres(step, rows, cols):
    image = plane_image(5, 7)
    dec = decimate(image.reshape(-1, 3), (5, 7), step)
    assert dec.shape == (len(rows), len(cols))
    np.testing.assert_array_equal(dec.rows, rows)
    np.testing.assert_array_equal(dec.cols, cols)
    np.testing.assert_array_equal(dec.points.reshape(*dec.shape, 3),
                                  image[np.ix_(rows, cols)])


def test_an_image_narrower_than_half_a_block_keeps_its_first_row():
    dec = decimate(plane_image(1, 9).reshape(-1, 3), (1, 9), 4)
    np.testing.assert_array_equal(dec.rows, [0])
    np.testing.assert_array_equal(dec.cols, [2, 6])


def test_every_pixel_of_one_plane_takes_its_samples_label():
    image = plane_image(8, 10)
    dec = decimate(image.reshape(-1, 3), (8, 10), 2)
    labels = spread_labels(image.reshape(-1, 3), (8, 10), dec,
                           np.full(dec.shape[0] * dec.shape[1], 7), VOXEL, FACTOR)
    np.testing.assert_array_equal(labels, 7)


def test_a_depth_step_keeps_each_side_its_own_label_and_holes_none():
    # Columns 0-4 at 1.0 m (label 1), 5-9 at 1.3 m (label 2); a hole at a sample (3, 7) and
    # one at a pixel that is none (6, 2). Blocks of 2 x 2 pixels, samples at odd rows/cols.
    image = plane_image(8, 10)
    image[:, 5:, 2] = 1.3
    image[3, 7] = np.nan
    image[6, 2] = np.nan
    flat = image.reshape(-1, 3)
    dec = decimate(flat, (8, 10), 2)
    side = np.where(dec.cols < 5, 1, 2)
    sample_labels = np.tile(side, dec.shape[0])
    labels = spread_labels(flat, (8, 10), dec, sample_labels, VOXEL, FACTOR).reshape(8, 10)
    # Column 4's block sample (column 5) lies across the 30 cm step: its pixels take the
    # sample of the block to their left (column 3, 4 mm away). The block whose sample has
    # no return takes its neighbours' samples (same side). Only the holes stay -1.
    expected = np.where(np.arange(10) < 5, 1, 2)[None, :].repeat(8, axis=0)
    expected[3, 7] = expected[6, 2] = -1
    np.testing.assert_array_equal(labels, expected)


def test_an_edge_pixel_takes_the_nearest_sample_on_its_own_side():
    # A 3-pixel-wide near strip (columns 3-5 at 1.0 m, label 5) in a far plane (1.4 m,
    # label 6). Samples at odd columns: column 2's block sample (3) is near, its pixel far;
    # column 6's sample (7) far, and column 5 a near sample itself.
    image = plane_image(6, 9, depth=1.4)
    image[:, 3:6, 2] = 1.0
    flat = image.reshape(-1, 3)
    dec = decimate(flat, (6, 9), 2)
    sample_labels = np.tile(np.where((dec.cols >= 3) & (dec.cols <= 5), 5, 6), dec.shape[0])
    labels = spread_labels(flat, (6, 9), dec, sample_labels, VOXEL, FACTOR).reshape(6, 9)
    expected = np.where((np.arange(9) >= 3) & (np.arange(9) <= 5), 5, 6)[None, :]
    np.testing.assert_array_equal(labels, expected.repeat(6, axis=0))


def test_a_pixel_beyond_a_link_of_every_sample_is_unlabelled():
    # A lone pixel 5 cm in front of a plane whose samples are 4 mm apart (link 10 mm).
    image = plane_image(6, 6)
    image[2, 2, 2] = 0.95  # not a sample (samples at rows/cols 1, 3, 5)
    flat = image.reshape(-1, 3)
    dec = decimate(flat, (6, 6), 2)
    labels = spread_labels(flat, (6, 6), dec, np.full(9, 4), VOXEL, FACTOR).reshape(6, 6)
    assert labels[2, 2] == -1
    assert np.count_nonzero(labels == 4) == 35


def test_unlabelled_samples_spread_no_label():
    image = plane_image(6, 6)
    flat = image.reshape(-1, 3)
    dec = decimate(flat, (6, 6), 2)
    sample_labels = np.full(9, -1)
    sample_labels[0] = 3  # the sample at (1, 1)
    labels = spread_labels(flat, (6, 6), dec, sample_labels, VOXEL, FACTOR).reshape(6, 6)
    expected = np.full((6, 6), -1)
    expected[:2, :2] = 3  # the block of the sample at (1, 1)
    np.testing.assert_array_equal(labels, expected)


def test_the_reach_grows_with_the_samples_spacing():
    # A far plane: 12 mm between pixels, 24 mm between samples, above the 10 mm link of
    # the voxel: every pixel still takes the label (the spacing sets the reach).
    ys, xs = np.mgrid[0:6, 0:6].astype(float)
    image = np.dstack([xs * 0.012, ys * 0.012, np.full((6, 6), 6.0)])
    flat = image.reshape(-1, 3)
    dec = decimate(flat, (6, 6), 2)
    labels = spread_labels(flat, (6, 6), dec, np.full(9, 1), VOXEL, FACTOR)
    np.testing.assert_array_equal(labels, 1)


@pytest.mark.parametrize("value", [0, 9, 1.5])
def test_decimation_outside_its_range_is_rejected(value):
    with pytest.raises(ParameterError, match="decimation"):
        ModelingParams(decimation=value)


def test_unorganized_clouds_are_modeled_as_given():
    scene = render_clutter(0, None)
    points = scene.organized.reshape(-1, 3)
    labels1, result1 = model_scene(points, ModelingParams())
    labels2, result2 = model_scene(points, ModelingParams(decimation=2))
    np.testing.assert_array_equal(labels1, labels2)
    assert [o.to_dict() for o in result1.objects] == [o.to_dict() for o in result2.objects]


def test_a_decimated_clutter_scene_keeps_its_objects_apart():
    scene = render_clutter(0, None)
    h, w = scene.label_image.shape
    labels, result = model_scene(scene.organized.reshape(-1, 3), ModelingParams(decimation=2),
                                 organized_shape=(h, w))
    assert labels.shape == (h * w,)
    assert "decimation_s" in result.timing
    # Every object counts the pixels that carry its label (more than its samples).
    for o in result.objects:
        assert o.point_count == np.count_nonzero(labels == o.id) > 0
    gt = scene.label_image.ravel()
    counts = np.bincount(gt[gt >= 0], minlength=len(scene.kinds))
    ids = [i for i in range(1, len(scene.kinds)) if counts[i] >= 200]
    scores = segmentation_scores(labels, gt, ids)
    # Every object of the scene is found at IoU >= 0.8 (as on every pixel: the same
    # criterion as the clutter benchmark's) and none shares its segment with another.
    assert [s.gt_id for s in scores if s.iou < 0.8 or s.under] == []
    # No pixel holds the label of a segment that is mostly another object.
    seen = (labels >= 0) & (gt >= 0)
    lab, truth = labels[seen], gt[seen]
    n_truth = int(truth.max()) + 1
    table = np.bincount(lab * n_truth + truth, minlength=(lab.max() + 1) * n_truth)
    owner = table.reshape(-1, n_truth).argmax(axis=1)
    assert np.count_nonzero(owner[lab] != truth) <= 0.01 * len(lab)
