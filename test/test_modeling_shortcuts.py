"""Cheaper forms of modeling steps give the values of their plain definitions.

Each step below was made cheaper (a partition instead of a full sort, no negated copy, a
stop when a refinement round would repeat itself, a cheaper tree, a basis computed once);
these tests check the results against hand-worked values and against the plain
definitions, written out here independently of the code.
"""

import math

import numpy as np
import pytest

from geomodel_ros.core import obb, ransac
from geomodel_ros.core.fitting import measure
from geomodel_ros.core.fitting.cloud import _grouped
from geomodel_ros.core.geometry import perpendicular_basis
from geomodel_ros.core.modeling import estimate_spacing, model_scene
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.ransac import ConeModel, CylinderModel, PlaneModel, refine
from geomodel_ros.tools.synth.clutter import render_clutter


def _plain_small_end_groups(vals):
    """Apply the stray-group rule to fully sorted values (its definition)."""
    ordered = np.sort(vals)
    n = len(ordered)
    k = int(measure.STRAY_GROUP_SHARE * n)
    if k < 1:
        return vals
    gaps = np.diff(ordered)
    low = [i for i in range(k) if gaps[i] > measure.STRAY_GAP]
    high = [i for i in range(n - 1 - k, n - 1) if gaps[i] > measure.STRAY_GAP]
    if not low and not high:
        return vals
    lo = ordered[low[-1] + 1] if low else ordered[0]
    hi = ordered[high[0]] if high else ordered[-1]
    return vals[(vals >= lo) & (vals <= hi)]


def test_a_small_group_beyond_a_gap_is_dropped_at_either_end():
    bulk = np.arange(100) * 0.001                          # 0 .. 0.099 m, 1 mm apart
    far_high = np.array([0.2, 0.201, 0.202])               # 3 % of the points, 101 mm off
    far_low = np.array([-0.15, -0.149])                    # 2 %, 149 mm below
    vals = np.concatenate([far_high, bulk, far_low])
    kept = measure._without_small_end_groups(vals)
    assert np.array_equal(np.sort(kept), bulk)


def test_a_group_larger_than_the_share_stays():
    bulk = np.arange(100) * 0.001
    group = 0.2 + np.arange(10) * 0.001                    # 9 % of the points: an object part
    vals = np.concatenate([bulk, group])
    assert measure._without_small_end_groups(vals) is vals


def test_a_group_within_the_gap_stays():
    bulk = np.arange(100) * 0.001
    near = np.array([0.099 + 0.8 * measure.STRAY_GAP])     # closer than STRAY_GAP
    vals = np.concatenate([bulk, near])
    assert measure._without_small_end_groups(vals) is vals


@pytest.mark.parametrize("seed", range(40))
def test_small_end_groups_match_the_sorted_definition(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(20, 600))
    vals = rng.normal(0.0, 0.03, n)
    m = int(rng.integers(1, max(2, n // 15)))
    vals[:m] += rng.choice([-1.0, 1.0]) * (0.04 + 0.2 * rng.random())
    if seed % 3 == 0:
        vals = np.round(vals, 2)                           # ties
    got = measure._without_small_end_groups(vals)
    want = _plain_small_end_groups(vals)
    assert np.array_equal(got, want)


def test_interval_adds_the_edge_gaps_worked_by_hand():
    values = np.array([0.0, 0.003, 0.004, 0.0045, 0.010])
    lo, hi = obb.interval(values, 0.001)
    # High end: within EDGE_BAND (4) spacings of 0.010 only 0.010 itself: half a spacing.
    assert hi == pytest.approx(0.010 + 0.0005, abs=1e-15)
    # Low end: 0, 0.003, 0.004 lie within 4 mm of 0; largest step 3 mm, half of it.
    assert lo == pytest.approx(-0.0015, abs=1e-15)


def test_interval_low_end_is_the_high_end_of_the_negated_values():
    rng = np.random.default_rng(7)
    for _ in range(200):
        values = rng.normal(0.0, 0.05, int(rng.integers(2, 300)))
        if rng.random() < 0.5:
            values = np.round(values / 0.002) * 0.002      # rows of a sampling grid
        spacing = float(rng.choice([1e-3, 2e-3, 5e-3]))
        lo, _ = obb.interval(values, spacing)
        assert lo == float(values.min()) - obb.edge_gap(-values, spacing)


def test_interval_without_correction_or_spacing_is_the_plain_range():
    values = np.array([0.2, -0.1, 0.05])
    assert obb.interval(values, 0.001, correct=False) == (-0.1, 0.2)
    assert obb.interval(values, 0.0) == (-0.1, 0.2)
    assert obb.interval(np.array([0.3]), 0.001) == (0.3, 0.3)


def test_closed_ends_are_kept_as_given():
    values = np.array([0.0, 0.001, 0.002])
    assert obb.interval(values, 0.001, closed_low=-0.05, closed_high=0.07) == (-0.05, 0.07)


def _count_plane_fits(monkeypatch):
    """Count the points of every plane fit ``refine`` makes; return the growing list."""
    calls = []
    plain = ransac.fit_plane_svd

    def counted(p):
        calls.append(len(p))
        return plain(p)

    monkeypatch.setattr(ransac, "fit_plane_svd", counted)
    return calls


def test_plane_refinement_stops_when_the_inliers_repeat(monkeypatch):
    rng = np.random.default_rng(3)
    xy = rng.uniform(-0.1, 0.1, (400, 2))
    points = np.column_stack([xy, 0.5 + rng.normal(0.0, 0.0005, 400)])
    plain = ransac.fit_plane_svd
    calls = _count_plane_fits(monkeypatch)
    start = PlaneModel(np.array([0.0, 0.0, 1.0]), -0.5)
    model = refine(start, points, 0.01, rounds=5)
    # Every point is within 10 mm of the start and of each fit: the second round would
    # select the same points and fit the same plane.
    assert calls == [400]
    want = plain(points)
    assert np.array_equal(model.normal, want.normal) and model.d == want.d


def test_plane_refinement_goes_on_while_the_inliers_change(monkeypatch):
    rng = np.random.default_rng(4)
    xy = rng.uniform(-0.1, 0.1, (300, 2))
    plane = np.column_stack([xy, np.zeros(300)])
    strays = np.column_stack([rng.uniform(-0.1, 0.1, (30, 2)), np.full(30, 0.0045)])
    points = np.vstack([plane, strays])
    calls = _count_plane_fits(monkeypatch)
    start = PlaneModel(np.array([0.0, 0.0, 1.0]), -0.003)   # 3 mm up: strays inside
    model = refine(start, points, 0.0035, rounds=5)
    # Round 1 takes all 330 points (plane lifted by ~0.4 mm, strays 4.1 mm above it);
    # round 2 keeps the 300 plane points and fits z = 0; round 3 would repeat round 2.
    assert calls == [330, 300]
    assert abs(model.d) < 1e-12 and abs(abs(model.normal[2]) - 1.0) < 1e-12


@pytest.mark.parametrize("model", [
    CylinderModel(np.zeros(3), np.array([0.0, 0.6, 0.8]), 0.05),
    ConeModel(np.array([0.1, 0.0, 0.3]), np.array([1.0, 0.0, 0.0]), 0.4),
])
def test_the_axis_basis_is_computed_once_and_is_orthonormal(model):
    e1, e2 = model.basis
    assert model.basis is model.basis                      # cached on the model
    want = perpendicular_basis(model.axis)
    assert np.array_equal(e1, want[0]) and np.array_equal(e2, want[1])
    assert abs(e1 @ model.axis) < 1e-15 and abs(e2 @ model.axis) < 1e-15
    assert np.allclose(np.cross(e1, e2), model.axis, atol=1e-15)
    tilted = model.from_vector(np.r_[0.01, 0.0, np.zeros(len(model.to_vector()) - 2)])
    # A new model has the basis of its own axis, not its parent's.
    assert np.array_equal(tilted.basis[0], perpendicular_basis(tilted.axis)[0])
    assert not np.array_equal(tilted.axis, model.axis)


def test_spacing_of_a_regular_grid_is_its_step():
    g = np.arange(30) * 0.002
    x, y = np.meshgrid(g, g)
    points = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, 0.7)])
    assert estimate_spacing(points, np.random.default_rng(0)) == pytest.approx(0.002, rel=1e-12)


def test_spacing_is_the_median_nearest_neighbour_distance():
    rng = np.random.default_rng(5)
    points = rng.uniform(-0.1, 0.1, (1500, 3))
    q = points[:500]
    d2 = ((q[:, None, :] - points[None, :, :]) ** 2).sum(axis=2)
    d2[np.arange(500), np.arange(500)] = math.inf
    want = float(np.median(np.sqrt(d2.min(axis=1))))
    assert estimate_spacing(points, rng) == pytest.approx(want, rel=1e-12)


def test_spacing_looks_past_exact_duplicates():
    # The 2 mm grid of the test above with every point three times (a cloud merged with
    # itself twice): the nearest other position is still 2 mm away.
    g = np.arange(30) * 0.002
    x, y = np.meshgrid(g, g)
    points = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, 0.7)])
    tripled = np.repeat(points, 3, axis=0)
    got = estimate_spacing(tripled, np.random.default_rng(0), max_points=len(tripled))
    assert got == pytest.approx(0.002, rel=1e-12)
    # One position only: no spacing.
    assert estimate_spacing(np.tile([[0.1, 0.2, 0.7]], (50, 1)), np.random.default_rng(0)) \
        == 0.0


def test_a_frame_merged_with_itself_is_modeled_as_the_frame():
    # Every point of a clutter frame twice: the point spacing was 0, and the occlusion
    # test of a box's completion divided by it (ZeroDivisionError); now the same objects.
    scene = render_clutter(3)
    points = scene.organized.reshape(-1, 3)
    points = points[np.isfinite(points).all(axis=1)]
    _, once = model_scene(points, ModelingParams(), rng=0)
    _, twice = model_scene(np.repeat(points, 2, axis=0), ModelingParams(), rng=0)
    assert sorted(str(o.type) for o in twice.objects) == \
        sorted(str(o.type) for o in once.objects)


def test_points_grouped_by_face_in_input_order():
    order, bounds = _grouped(np.array([2, 0, 1, 0, 2, 2]), 3)
    assert order.tolist() == [1, 3, 2, 0, 4, 5]
    assert bounds.tolist() == [0, 2, 3, 6]
    # A face without points has an empty range.
    order, bounds = _grouped(np.array([0, 2, 0]), 3)
    assert order.tolist() == [0, 2, 1]
    assert bounds.tolist() == [0, 2, 2, 3]


def test_grouping_matches_a_stable_sort_of_the_labels():
    rng = np.random.default_rng(11)
    for _ in range(50):
        count = int(rng.integers(1, 30))
        labels = rng.integers(0, count, int(rng.integers(1, 2000)))
        order, bounds = _grouped(labels, count)
        assert np.array_equal(order, np.argsort(labels, kind="stable"))
        for f in range(count):
            assert np.array_equal(order[bounds[f]:bounds[f + 1]], np.flatnonzero(labels == f))


@pytest.mark.parametrize("model", [
    ransac.SphereModel(np.array([0.02, -0.01, 0.7]), 0.05),
    CylinderModel(np.array([0.0, 0.0, 0.8]), np.array([0.0, 0.6, 0.8]), 0.04),
    ConeModel(np.array([0.0, 0.05, 0.5]), np.array([0.0, 0.0, 1.0]), 0.35),
])
def test_shared_parts_give_the_distances_and_jacobian(model):
    rng = np.random.default_rng(9)
    pt = np.ascontiguousarray(rng.normal([0.0, 0.0, 0.7], 0.05, (200, 3)).T)
    x = rng.normal(0.0, 1e-3, len(model.to_vector()))
    if isinstance(model, ransac.SphereModel):
        x = model.to_vector() + x                          # absolute parameters
    m = model.from_vector(x)
    parts = m.parts_t(pt)
    assert np.array_equal(m.distance_from(parts), m.distance_t(pt))
    jac = model.jacobian_from(x, m, parts)
    assert np.array_equal(jac, model.jacobian_t(x, pt))
    # Independently: central differences of the distances.
    h = 1e-7
    for i in range(len(x)):
        step = np.zeros(len(x))
        step[i] = h
        fd = (model.from_vector(x + step).distance_t(pt)
              - model.from_vector(x - step).distance_t(pt)) / (2 * h)
        assert np.allclose(jac[i], fd, atol=1e-6)
