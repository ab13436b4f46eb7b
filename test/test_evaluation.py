"""Scoring helpers used by the benchmarks (geomodel_ros.tools.evaluation)."""

import numpy as np
import pytest

from geomodel_ros.tools.evaluation import circle_along, scan_axis, segmentation_scores


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


def _half_cylinder_with_handle(axis, radius=0.04, height=0.1, n=6000, seed=0):
    """Return points on the front half of a cylinder about ``axis`` (through the origin).

    With 0.5 mm noise and a handle-like cluster of 10 % strays beside it.
    """
    rng = np.random.default_rng(seed)
    z = axis / np.linalg.norm(axis)
    e1 = np.cross(z, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(z, e1)
    phi = rng.uniform(0.0, np.pi, n)
    t = rng.uniform(0.0, height, n)
    r = radius + rng.normal(0.0, 0.0005, n)
    pts = np.outer(r * np.cos(phi), e1) + np.outer(r * np.sin(phi), e2) + np.outer(t, z)
    handle = rng.normal(0.0, 0.008, (n // 10, 3)) + (radius + 0.02) * e1 + 0.05 * z
    return np.vstack([pts, handle]), z


def _deg(a, b):
    return np.degrees(np.arccos(min(1.0, abs(float(a @ b)))))


def test_circle_along_the_true_axis_beats_a_tilted_one():
    pts, z = _half_cylinder_with_handle(np.array([0.1, -0.8, -0.6]))
    true = circle_along(pts, z, 0.003)
    assert true.radius == pytest.approx(0.04, abs=0.001)
    assert true.share > 0.85 and true.median_residual < 0.001
    tilt = z + np.tan(np.radians(10.0)) * np.cross(z, [1.0, 0.0, 0.0]) / \
        np.linalg.norm(np.cross(z, [1.0, 0.0, 0.0]))
    tilted = circle_along(pts, tilt, 0.003)
    assert tilted.share < true.share - 0.2


def test_scan_axis_finds_the_axis_from_a_start_ten_degrees_off():
    pts, z = _half_cylinder_with_handle(np.array([0.2, 0.7, -0.7]), seed=3)
    side = np.cross(z, [0.0, 0.0, 1.0])
    start = np.cos(np.radians(10.0)) * z + np.sin(np.radians(10.0)) * side / np.linalg.norm(side)
    fits = scan_axis(pts, start, np.radians(15.0), 0.003, step=np.radians(1.0))
    assert _deg(fits[0].direction, z) <= 1.5
    assert [f.share for f in fits] == sorted((f.share for f in fits), reverse=True)
    assert all(_deg(f.direction, start) <= 15.0 + 1e-6 for f in fits)
