"""The joins' shortcuts give what their plain definitions give.

Each shortcut of :mod:`geomodel_ros.core.joins` (a search bounded by a distance already
reached, a tree of the few directions near a gap instead of the frame's, a test decided by
one end, summaries computed once per segment) is checked against the plain definition it
replaces, computed here by brute force on hand-made inputs, and on the cases where it
must not take the short way (equally near directions, a pair that touches).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from geomodel_ros.core.geometry import perpendicular_basis
from geomodel_ros.core.joins import (CONTAINED_MIN_INSIDE_SHARE, CONTAINED_MIN_POINTS,
                                     CONTAINED_RADIUS_MARGIN, GAP_DIRECT_POINTS,
                                     OCCLUSION_MAX_GAP_TILT, OCCLUSION_MAX_NORMAL_ANGLE,
                                     OCCLUSION_NORMAL_RADIUS_LINKS, RIM_HEIGHT_QUANTILE, _cells,
                                     _closest_gap, _Gap, _nearest_rays, _round_footprint,
                                     _Segments, _surface_continues, join_contained_parts,
                                     segment_members)
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.ransac import PlaneModel


def _brute_gap(a: np.ndarray, b: np.ndarray) -> tuple[int, float]:
    """Return the first row of ``a`` nearest to ``b`` and that distance (brute force)."""
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2).min(axis=1)
    k = int(np.argmin(d))
    return k, float(d[k])


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("n_a", [40, GAP_DIRECT_POINTS])
def test_small_segments_gap_is_the_brute_force_nearest_pair(seed, n_a):
    # The smaller segment (at most GAP_DIRECT_POINTS: searched row by row, after a probe of
    # every few rows) on a 1 mm grid (many equal distances) 0-20 cm from a larger one: the
    # gap's near end is the brute-force nearest row, the first among equally near ones;
    # no gap when the pair touches (within a link) or lies beyond seg_max_occlusion_gap.
    rng = np.random.default_rng(seed)
    params = ModelingParams()
    link = params.seg_max_edge_factor * params.seg_voxel_size
    a = np.round(rng.normal(0.0, 0.02, (n_a, 3)), 3) + [0.0, 0.0, 1.0]
    b = np.round(rng.normal(0.0, 0.05, (900, 3)), 3) + [rng.uniform(0.0, 0.35), 0.0, 1.0]
    points = np.vstack([a, b])
    comp = np.repeat([0, 1], [n_a, 900])
    segs = _Segments(points, comp, np.ones(len(points), dtype=bool))
    k, length = _brute_gap(a, b)
    gap = _closest_gap(segs, 0, 1, params)
    if length <= link or length > params.seg_max_occlusion_gap:
        assert gap is None
        return
    assert gap is not None and (gap.small, gap.big, gap.pa) == (0, 1, k)
    assert gap.length == pytest.approx(length, abs=1e-12)


@pytest.mark.parametrize("n_a", [40, GAP_DIRECT_POINTS + 200])
def test_a_touching_pair_has_no_gap_and_one_just_apart_has(n_a):
    # Two parallel sheets of points on a 2 mm grid, the smaller one 3 mm (within a link of
    # 10 mm) or 30 mm in front of the larger: touching gives no gap (the probe's distance
    # already decides), apart gives a gap of exactly the spacing.
    params = ModelingParams()
    side = int(math.ceil(math.sqrt(n_a)))
    g = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:n_a]
    big = np.stack(np.meshgrid(np.arange(60), np.arange(60)), -1).reshape(-1, 2)
    for dz, expect in ((0.003, None), (0.03, 0.03)):
        a = np.column_stack([g * 0.002, np.full(len(g), 1.0 - dz)])
        b = np.column_stack([big * 0.002 - 0.02, np.ones(len(big))])
        points = np.vstack([a, b])
        comp = np.repeat([0, 1], [len(a), len(b)])
        gap = _closest_gap(_Segments(points, comp, np.ones(len(points), bool)), 0, 1, params)
        if expect is None:
            assert gap is None
        else:
            assert gap is not None and gap.length == pytest.approx(expect, abs=1e-9)
            assert gap.pa == 0  # the first of the equally near rows


def test_cells_hold_every_row_once_within_their_reach():
    rng = np.random.default_rng(3)
    q = rng.uniform(-0.1, 0.1, (500, 3))
    first, inv, reach = _cells(q, 0.02)
    # Each row's cell's first row is in the same 2 cm cube and the reach is the farthest.
    key = np.floor(q / 0.02).astype(int)
    assert np.array_equal(key[first][inv], key)
    assert np.all(first[inv] <= np.arange(len(q)))
    dist = np.linalg.norm(q - q[first][inv], axis=1)
    assert np.allclose(reach, [dist[inv == c].max() for c in range(len(first))], atol=0)
    assert np.all(reach <= 0.02 * math.sqrt(3))


def _ray_cloud(rng: np.random.Generator, n: int) -> np.ndarray:
    """Random points 0.5-1.5 m in front of the sensor within a 40 x 30 degree view."""
    az = rng.uniform(-0.35, 0.35, n)
    el = rng.uniform(-0.26, 0.26, n)
    d = np.column_stack([np.tan(az), np.tan(el), np.ones(n)])
    return d / np.linalg.norm(d, axis=1)[:, None] * rng.uniform(0.5, 1.5, n)[:, None]


@pytest.mark.parametrize("seed", range(5))
def test_nearest_rays_are_the_frames_nearest_within_the_tolerance(seed):
    rng = np.random.default_rng(seed)
    points = _ray_cloud(rng, 20000)
    segs = _Segments(points, np.zeros(len(points), dtype=np.int64), np.ones(len(points), bool))
    rays = points / np.linalg.norm(points, axis=1)[:, None]
    for _ in range(20):
        ends = _ray_cloud(rng, 2)
        samples = ends[0] + np.linspace(0.15, 0.85, 8)[:, None] * (ends[1] - ends[0])
        dirs = samples / np.linalg.norm(samples, axis=1)[:, None]
        tol = rng.uniform(0.002, 0.02) / np.linalg.norm(samples, axis=1)
        dist, hit = _nearest_rays(segs, dirs, tol)
        # Plain definition: the nearest of all directions, by brute force.
        full = np.linalg.norm(dirs[:, None, :] - rays[None, :, :], axis=2)
        best = full.min(axis=1)
        seen = best <= tol
        assert np.array_equal(dist <= tol, seen)
        assert np.allclose(dist[seen], best[seen], rtol=0, atol=1e-15)
        assert np.array_equal(hit[seen], full.argmin(axis=1)[seen])


def test_nearest_rays_defer_to_the_frames_tree_when_two_are_equally_near():
    # Two points mirrored about the optical axis at different depths are equally near the
    # axis' direction: the answer must be the frame tree's, whichever of the two it gives;
    # a sample with no direction within its tolerance is not seen.
    points = np.array([[0.002, 0.0, 1.0], [-0.004, 0.0, 2.0], [0.3, 0.2, 1.0]])
    segs = _Segments(points, np.zeros(3, dtype=np.int64), np.ones(3, bool))
    dirs = np.array([[0.0, 0.0, 1.0], [0.0, 0.6, 0.8]])
    tol = np.array([0.01, 0.01])
    dist, hit = _nearest_rays(segs, dirs, tol)
    ref_dist, ref_hit = segs.ray_tree().query(dirs, k=1)
    assert dist[0] == ref_dist[0] and hit[0] == ref_hit[0] and hit[0] in (0, 1)
    assert dist[1] > tol[1]
    # Nothing near at all: every sample unseen.
    far = np.array([[0.0, -0.6, 0.8]])
    assert _nearest_rays(segs, far, np.array([0.01]))[0][0] > 0.01


def _plain_surface_continues(segs, normals, gap, params) -> bool:
    """Return the surface test as defined: both ends' mean normals, three conditions."""
    link = params.seg_max_edge_factor * params.seg_voxel_size
    radius = OCCLUSION_NORMAL_RADIUS_LINKS * link
    means = []
    for seg, at in ((gap.small, gap.pa), (gap.big, gap.pb)):
        m = segs.members[seg]
        near = m[np.linalg.norm(segs.points[m] - segs.points[at], axis=1) <= radius]
        nrm = normals[near] * np.sign(normals[near] @ normals[at])[:, None]
        means.append(nrm.sum(axis=0) / np.linalg.norm(nrm.sum(axis=0)))
    na, nb = means
    tilt = math.sin(OCCLUSION_MAX_GAP_TILT)
    return bool(abs(na @ nb) >= math.cos(OCCLUSION_MAX_NORMAL_ANGLE)
                and abs(na @ gap.u) <= tilt and abs(nb @ gap.u) <= tilt)


def test_surface_test_with_its_shortcuts_is_the_plain_test():
    # Four noisy sheets: 0 and 1 in one plane 15 cm apart (gaps along the plane: the
    # surface continues), 2 beside 0 but turned by 40 degrees and 3 parallel 10 cm in front
    # of 0 (the gaps leave 0's plane: decided by 0's end alone, 3's normals never needed).
    # Gaps between random ends: the test (near end first, mean normals kept per point)
    # agrees with the plain one, also when a gap end is asked for again.
    rng = np.random.default_rng(7)
    params = ModelingParams()
    n = np.array([0.1, -0.2, 1.0]) / np.linalg.norm([0.1, -0.2, 1.0])
    e1, e2 = perpendicular_basis(n)
    turned = math.cos(0.7) * n + math.sin(0.7) * e1
    t1, t2 = perpendicular_basis(turned)
    sheets = [(np.array([0, 0, 1.0]), n, e1, e2), (np.array([0, 0, 1.0]) + 0.15 * e1, n, e1, e2),
              (np.array([0, 0, 1.0]) + 0.15 * e2, turned, t1, t2),
              (np.array([0, 0, 1.0]) - 0.1 * n, n, e1, e2)]
    pts, nrm = [], []
    for origin, normal, u, v in sheets:
        uv = rng.uniform(-0.05, 0.05, (600, 2))
        pts.append(origin + uv[:, :1] * u + uv[:, 1:] * v + rng.normal(0, 0.001, (600, 1)) * normal)
        nrm.append(normal + rng.normal(0, 0.05, (600, 3)))
    points, normals = np.vstack(pts), np.vstack(nrm)
    comp = np.repeat([0, 1, 2, 3], 600)
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    normals[rng.random(len(normals)) < 0.3] *= -1  # unoriented, as estimated normals
    segs = _Segments(points, comp, np.ones(len(points), bool))
    outcomes = {1: set(), 2: set(), 3: set()}
    for _ in range(2):
        for other in (1, 2, 3):
            for pa, pb in zip(rng.integers(0, 600, 30), rng.integers(0, 600, 30) + 600 * other):
                d = points[pb] - points[pa]
                length = float(np.linalg.norm(d))
                gap = _Gap(0, other, int(pa), int(pb), length, d / length)
                got = _surface_continues(segs, normals, gap, params)
                assert got == _plain_surface_continues(segs, normals, gap, params)
                outcomes[other].add(got)
    assert outcomes == {1: {True}, 2: {False}, 3: {False}}
    assert {seg for seg, _, _ in segs.mean_normals} == {0, 1, 2}


def _plain_contained(points, normals, comp, valid, support):
    """Return the container join as defined: every round segment against every other."""
    n = support.normal
    basis = np.column_stack(perpendicular_basis(n))
    members = segment_members(comp, valid)
    ids = list(members)
    foot = {i: points[m] @ basis for i, m in members.items()}
    height = {i: np.abs(points[m] @ n + support.d) for i, m in members.items()}
    circles = {i: _round_footprint(foot[i], normals[members[i]] @ basis, height[i])
               for i in ids if len(members[i]) >= CONTAINED_MIN_POINTS}
    root = {i: i for i in ids}

    def find(x):
        while root[x] != x:
            x = root[x]
        return x
    for a in sorted((i for i, c in circles.items() if c is not None),
                    key=lambda i: -len(members[i])):
        wall = circles[a]
        for b in ids:
            if len(members[b]) < CONTAINED_MIN_POINTS or find(a) == find(b):
                continue
            inside = (np.linalg.norm(foot[b] - wall.center, axis=1)
                      <= CONTAINED_RADIUS_MARGIN * wall.radius_at(height[b]))
            ha, hb = height[a], height[b]
            overlap = min(ha.max(), hb.max()) - max(ha.min(), hb.min())
            below = np.median(hb) <= np.quantile(ha, RIM_HEIGHT_QUANTILE)
            if inside.mean() >= CONTAINED_MIN_INSIDE_SHARE and overlap > 0 and below:
                root[find(b)] = find(a)
    out = comp.copy()
    for i in ids:
        out[members[i]] = find(i)
    return out


def _wall(rng, center, r, h0, h1, arc, n, inward=False):
    """Points and normals of a vertical round wall (z up) over ``arc`` [rad]."""
    t = rng.uniform(*arc, n)
    z = rng.uniform(h0, h1, n)
    radial = np.column_stack([np.cos(t), np.sin(t), np.zeros(n)])
    pts = np.r_[center, 0.0] + r * radial + np.column_stack([np.zeros((n, 2)), z])
    return pts, (-radial if inward else radial)


def test_container_join_with_its_shortcuts_is_the_plain_join():
    # A cup on the desk (z = 0): its outer front wall, its inner back wall (inside the
    # footprint, below the rim: joined), a box beside it (apart), a ball above the rim
    # inside the footprint (above the rim: apart) and a crumb of a few points (too small).
    rng = np.random.default_rng(11)
    parts = [_wall(rng, (0, 0), 0.04, 0.0, 0.10, (-2.6, -0.5), 800),
             _wall(rng, (0, 0), 0.036, 0.03, 0.10, (0.6, 2.5), 400, inward=True)]
    box = rng.uniform([0.08, -0.03, 0.0], [0.14, 0.03, 0.08], (500, 3))
    ball = rng.normal(0, 0.01, (200, 3)) + [0.0, 0.0, 0.16]
    crumb = rng.normal(0, 0.002, (10, 3)) + [0.0, 0.01, 0.05]
    parts += [(box, np.tile([1.0, 0, 0], (500, 1))), (ball, ball - [0, 0, 0.16]),
              (crumb, np.tile([0, 0, 1.0], (10, 1)))]
    points = np.vstack([p for p, _ in parts])
    normals = np.vstack([q for _, q in parts])
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    comp = np.repeat(np.arange(len(parts)) * 2 + 1, [len(p) for p, _ in parts])
    valid = np.ones(len(points), bool)
    support = PlaneModel(np.array([0.0, 0.0, 1.0]), 0.0)
    got = join_contained_parts(points, normals, comp, valid, support)
    assert np.array_equal(got, _plain_contained(points, normals, comp, valid, support))
    # The expectation worked out above: only the two walls become one.
    labels = [set(got[comp == i].tolist()) for i in (1, 3, 5, 7, 9)]
    assert labels[0] == labels[1] == {1}
    assert labels[2] == {5} and labels[3] == {7} and labels[4] == {9}


def test_container_join_without_a_round_segment_keeps_the_ids():
    rng = np.random.default_rng(2)
    points = rng.uniform(0, 0.1, (300, 3))
    normals = np.tile([0.0, 0.0, 1.0], (300, 1))
    comp = np.repeat([4, 9], 150)
    got = join_contained_parts(points, normals, comp, np.ones(300, bool),
                               PlaneModel(np.array([0.0, 0.0, 1.0]), 0.0))
    assert np.array_equal(got, comp)
