"""Scoring helpers used by the benchmarks (geomodel_ros.evaluation)."""

import numpy as np
import pytest

from geomodel_ros.evaluation import segmentation_scores


def test_perfect_segmentation():
    gt = np.array([0] * 5 + [1] * 4 + [2] * 3 + [-1] * 2)
    pred = np.array([7] * 5 + [3] * 4 + [9] * 3 + [-1] * 2)
    scores = segmentation_scores(pred, gt, [1, 2])
    assert [(s.gt_id, s.iou, s.under, s.over, s.parts_iou) for s in scores] == [
        (1, 1.0, False, False, 1.0), (2, 1.0, False, False, 1.0)]


def test_under_segmentation_merges_two_objects():
    gt = np.array([1] * 10 + [2] * 10)
    pred = np.zeros(20, dtype=int)
    s1, s2 = segmentation_scores(pred, gt, [1, 2])
    assert s1.iou == pytest.approx(0.5) and s1.under and s2.under
    assert not s1.over


def test_disjoint_parts_count_as_over_segmentation_but_full_parts_iou():
    gt = np.array([1] * 10 + [2] * 10)
    pred = np.array([5] * 5 + [6] * 5 + [7] * 10)
    s1, s2 = segmentation_scores(pred, gt, [1, 2])
    assert s1.iou == pytest.approx(0.5) and s1.over and s1.parts_iou == pytest.approx(1.0)
    assert s2.iou == 1.0 and not s2.over


def test_object_lost_to_noise_scores_zero():
    gt = np.array([1] * 5 + [2] * 5)
    pred = np.array([-1] * 5 + [4] * 5)
    s1, _ = segmentation_scores(pred, gt, [1, 2])
    assert (s1.iou, s1.parts_iou, s1.under, s1.over) == (0.0, 0.0, False, False)
