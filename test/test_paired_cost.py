"""Model comparison beyond correlated noise, and a box against the round model of its faces.

Modules: core.fitting.paired_cost and core.fitting.strategies (prefer_round, thinned).

By hand: with B equal blocks of m points each and block means of the per-point
difference d_b, the cluster-robust standard error of the mean is
sqrt(sum_b (m (d_b - mean))^2) / (B m); a difference that is constant within blocks but
alternates between blocks has a tiny per-point standard error and a large one over the
blocks.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from geomodel_ros.core.fitting.paired_cost import (BLOCK_GRID, LOWER_LEVEL, MIN_BLOCKS,
                                                   lower_beyond_noise, spread_blocks)
from geomodel_ros.core.fitting import strategies
from geomodel_ros.core.fitting.strategies import all_faces_curved, thinned
from geomodel_ros.core.fitting.units import fit_first
from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import PrimitiveType
from geomodel_ros.tools.synth.suite import SuiteCase, render_case

from test_fitting_units import CYL_R, cloud_of, cylinder_points, plane_points

#: The Student quantile of a 16-block comparison (15 degrees of freedom), about 2.13.
T16 = stats.t.ppf(1.0 - LOWER_LEVEL, BLOCK_GRID ** 2 - 1)


def grid_points(nx=40, ny=40, wx=0.4, wy=0.2):
    """Return points of an nx x ny grid, wx [m] wide along x and wy along y, at z = 1 m."""
    x, y = np.meshgrid(np.linspace(0, wx, nx), np.linspace(0, wy, ny), indexing="ij")
    return np.c_[x.ravel(), y.ravel(), np.ones(x.size)]


def test_blocks_are_equal_count_cells_of_the_two_widest_directions():
    p = grid_points()
    b = spread_blocks(p)
    assert np.array_equal(np.bincount(b), np.full(16, 100))
    # Cells follow x (the widest) in quarters of 10 columns, y in quarters of 10 rows.
    qx, qy = (np.arange(40) // 10)[:, None], (np.arange(40) // 10)[None, :]
    cell = np.broadcast_to(qx * 4 + qy, (40, 40)).ravel()
    # Same cell <=> same block (the labels may be permuted by the eigenvectors' signs).
    pairs = {(int(c), int(k)) for c, k in zip(cell, b)}
    assert len(pairs) == 16
    assert len({c for c, _ in pairs}) == 16 and len({k for _, k in pairs}) == 16


def test_a_lower_cost_with_independent_noise_is_significant():
    rng = np.random.default_rng(1)
    p = grid_points()
    other = rng.uniform(0.0, 0.2, len(p))
    lower = other - 0.01 + rng.normal(0.0, 0.02, len(p))
    ok, t = lower_beyond_noise(lower, other, spread_blocks(p))
    # Mean 0.01 over a standard error of about 0.02 / 40 = 0.0005: t about 20.
    assert ok and 10.0 < t < 40.0


def test_the_same_costs_are_not_lower():
    rng = np.random.default_rng(2)
    p = grid_points()
    c = rng.uniform(0.0, 0.2, len(p))
    ok, t = lower_beyond_noise(c, rng.permutation(c), spread_blocks(p))
    assert not ok and abs(t) < T16


def test_a_difference_that_alternates_between_blocks_is_not_significant():
    # Half the blocks favour one model by 0.05, the other half the other by 0.03: mean
    # 0.01; each block deviates by 0.04 -> se = sqrt(16 (100 * 0.04)^2) / 1600 = 0.01,
    # t = 1.0 (per point the differences look exact: a naive se would be ~0.001).
    p = grid_points()
    b = spread_blocks(p)
    other = np.full(len(p), 0.1)
    lower = other - np.where(b % 2 == 0, 0.05, -0.03)
    ok, t = lower_beyond_noise(lower, other, b)
    assert not ok
    assert t == pytest.approx(1.0, rel=1e-9)


def test_too_few_blocks_judge_nothing():
    p = grid_points()
    b = np.minimum(spread_blocks(p), MIN_BLOCKS - 2)
    ok, t = lower_beyond_noise(np.zeros(len(p)), np.ones(len(p)), b)
    assert not ok and t == 0.0


def _object_over(case, truth_id):
    """Return the modeled object that holds most of the ground truth object's points."""
    sc = render_case(case)
    labels, res = model_scene(sc.points, ModelingParams())
    m = (sc.labels == truth_id) & (labels >= 0)
    best = int(np.argmax(np.bincount(labels[m])))
    return next(o for o in res.objects if o.id == best)


@pytest.mark.parametrize("seed", [1, 2])
def test_a_lying_cylinder_faceted_by_correlated_noise_is_no_box(seed):
    # set_b at 0.5 m: a cylinder r 30 mm, 120 mm long, lying; its visible half splits into
    # facets that meet at about right angles and each pass as planar.
    o = _object_over(SuiteCase("set_b", 0.5, "kinect-real", seed), 1)
    assert o.type == "cylinder"
    assert o.dimensions["radius"] == pytest.approx(0.030, abs=0.003)
    # Seed 1 keeps its lower flanks next to the desk (the contact rim claim judges them
    # against the desk around them) and is verified as a cylinder without a box rival.
    assert "replaces cuboid" in o.reason or "cuboid" not in o.reason


# The box at 1.5 m, seed 2: at the unshifted position its faces come out planar but 13 deg
# off square ("planar faces not aligned with three orthogonal axes"); it is the box of its
# point normals' modes (strategies.PlanarFacesWithoutRule; a cuboid at 7 of 8 sub-voxel
# shifts of the cloud, camera x/y 0-3 mm, BENCHMARKS.md section 20), never a round type.
@pytest.mark.parametrize("distance, seed", [(1.0, 1), (1.5, 1), (1.5, 2)])
def test_a_box_stays_a_box(distance, seed):
    # set_a's box (100 x 70 x 60 mm); at 1.5 m seed 2 its segment has extra points and a
    # cone fits them about as well as the box (not significantly better).
    o = _object_over(SuiteCase("set_a", distance, "kinect-real", seed), 1)
    assert o.type == "cuboid"
    assert "replaces cuboid" not in o.reason
    assert math.isfinite(sum(o.dimensions.values()))


def test_the_far_box_is_never_typed_round():
    # Whatever the grid phase makes of the box at 1.5 m (seed 2), a cylinder or cone that
    # explains its positions as well as the box (r 34 mm, truncated cost 0.053 either way)
    # must not be reported: its normals agree with the box's sides, not with a round side.
    o = _object_over(SuiteCase("set_a", 1.5, "kinect-real", 2), 1)
    assert o.type in ("cuboid", "unknown")


def test_thinned_faces_keep_every_kth_point_and_its_normal():
    # A cylinder r 40 mm, 120 mm long: tens of thousands of points, thinned to ~400.
    cloud = cloud_of(cylinder_points())
    thin = thinned(cloud, 400)
    n_w = sum(len(f.working) for f in cloud.faces)
    n_obj = len(cloud.points)
    kw, kp = n_w // 400, n_obj // 400
    assert kw > 1 and kp > 1  # the example really thins
    # The object's points: every kp-th, about the target (k = floor(n / target)).
    assert np.array_equal(thin.points, cloud.points[::kp])
    assert 400 <= len(thin.points) < 800
    for f, t in zip(cloud.faces, thin.faces, strict=True):
        assert np.array_equal(t.working, f.working[::kw])
        assert np.array_equal(t.info.point_normals, f.info.point_normals[::kw])
        assert t.info.size == len(t.working)
        # The face keeps exactly its points that the object kept, as the same 3-D points.
        kept = f.points[f.points % kp == 0]
        assert np.array_equal(thin.points[t.points], cloud.points[kept])
    assert 400 <= sum(len(f.working) for f in thin.faces) < 800
    # A first look (no full-resolution refinement); the working cloud is shared and the
    # original object is untouched.
    assert thin.first_look and not cloud.first_look
    assert thin.wc is cloud.wc and len(cloud.points) == n_obj
    assert sum(len(f.working) for f in cloud.faces) == n_w


def test_a_round_side_fits_on_its_thinned_faces():
    # The cheap rival must find a round side the object really has: the cylinder's
    # radius within 2 mm on about 400 of its points (noise-free surface).
    cloud = cloud_of(cylinder_points())
    attempt = all_faces_curved(cloud, "all faces taken as curved")
    assert attempt is not None
    prim, _ = fit_first(thinned(attempt.cloud), attempt.decision)
    assert prim is not None and prim.type is PrimitiveType.CYLINDER
    assert prim.dimensions["radius"] == pytest.approx(CYL_R, abs=0.002)


def test_a_plane_has_no_thinned_round_rival():
    # A flat patch: no round model passes its own checks on it, so nothing is refitted.
    cloud = cloud_of(plane_points())
    attempt = all_faces_curved(cloud, "all faces taken as curved")
    assert attempt is None or fit_first(thinned(attempt.cloud), attempt.decision)[0] is None


def test_a_round_sides_candidates_come_from_a_few_hundred_of_its_points():
    # A cylinder r 40 mm: k2 ~ 0 and k1 = 1/r at every point, so a few hundred of its
    # working points propose the cylinder first, as all of them do.
    cloud = cloud_of(cylinder_points())
    assert len(cloud.wc.points) > 2 * 400  # the example really thins
    full = all_faces_curved(cloud, "all faces taken as curved")
    few = all_faces_curved(cloud, "all faces taken as curved", 400)
    assert full is not None and few is not None
    assert full.decision.candidates[0] == few.decision.candidates[0] == "cylinder"
    assert "k1 constant" in few.note


@pytest.mark.parametrize("cheap_cost, refitted", [(0.2, False), (0.05, True)])
def test_the_rival_is_refitted_only_when_its_first_look_is_no_worse_than_the_box(
        monkeypatch, cheap_cost, refitted):
    # A cylinder r 40 mm and a stand-in box whose truncated cost is 0.1 per point: the
    # thinned rival's mean cost decides whether the full-resolution refit is paid for. A
    # first look that loses to the box has the other candidate types fitted alone, also
    # thinned (strategies._cheapest_type): one first look per candidate type, no refit.
    cloud = cloud_of(cylinder_points())
    candidates = all_faces_curved(cloud, "all faces taken as curved",
                                  strategies.RIVAL_FIT_POINTS).decision.candidates
    assert len(candidates) > 1
    box = object()
    calls = []

    def counted(c, decision):
        calls.append(c.first_look)
        return fit_first(c, decision)

    def costs(prim, c):
        return np.full(len(c.points), 0.1 if prim is box else cheap_cost)

    monkeypatch.setattr(strategies, "fit_first", counted)
    monkeypatch.setattr(strategies, "truncated_costs", costs)
    found = strategies.round_rival(cloud, box)
    assert calls == ([True, False] if refitted else [True] * len(candidates))
    assert (found is not None) == refitted
    if refitted:
        assert found[1].type is PrimitiveType.CYLINDER
