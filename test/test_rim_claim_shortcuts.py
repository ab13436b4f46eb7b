"""The cheaper contact rim claim gives the values of its plain definition.

The support around a point (:func:`_support_around`) is gathered from summed-area tables
of the support plane's cells, its coordinates reduced as two vectors; the claim
(:func:`_claim_contact_rims`) takes the labels of the finite points as they are and
judges each object point once. These tests check the results against hand-worked values
and against the plain definitions written out here independently of the code: every
support point's cell, every query's window of cells, grown by doubling while it holds none
of the support; and a support's band, in which an object point goes to the first support
that holds it.
"""

import numpy as np
import pytest

from geomodel_ros.core.faces import voxelize
from geomodel_ros.core.geometry import perpendicular_basis
from geomodel_ros.core.noise import K_SUPPORT, NoiseEstimate
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.segmentation import (AROUND_MAX_CELLS, SUPPORT_AROUND_CELLS,
                                            SUPPORT_AROUND_MAX_CELLS, LocalSupport,
                                            _claim_contact_rims, _on_local_support,
                                            _support_around)
from geomodel_ros.core.support import REFIT_MAX_POINTS, support_plane_equation

CELL = 0.01
#: The desk z = DESK_Z (normal +z, towards a sensor above it): n . x + d = 0 with d.
DESK_Z = -0.8
UP = np.array([0.0, 0.0, 1.0])


def _plain_support_around(points, weights, at, normal, d, cell):
    """Count and sum the support around each query by the definition, one at a time.

    The cells of the plane are square, ``cell`` wide, counted from the lowest coordinate
    of support and queries along the plane's axes; the support is that in the window of
    cells up to r from the query's own, r doubled from SUPPORT_AROUND_CELLS while the
    window holds none, up to the largest.
    """
    e1, e2 = perpendicular_basis(normal)
    sup = np.flatnonzero(weights)
    uv = np.c_[points[sup] @ e1, points[sup] @ e2]
    q = np.c_[at @ e1, at @ e2]
    low = np.minimum(uv.min(axis=0), q.min(axis=0))
    span = np.maximum(uv.max(axis=0), q.max(axis=0)) - low
    while np.prod(span / cell + 1.0) > AROUND_MAX_CELLS:
        cell *= 2.0
    own = np.floor((uv - low) / cell).astype(int)
    ask = np.floor((q - low) / cell).astype(int)
    w = weights[sup]
    height = points[sup] @ normal + d
    n, total = np.zeros(len(at), dtype=np.int64), np.zeros(len(at))
    for i, a in enumerate(ask):
        r = SUPPORT_AROUND_CELLS
        while r <= SUPPORT_AROUND_MAX_CELLS:
            inside = np.all(np.abs(own - a) <= r, axis=1)
            if w[inside].sum() > 0:
                n[i], total[i] = w[inside].sum(), np.sum(w[inside] * height[inside])
                break
            r *= 2
    return n, total


def test_hand_built_windows():
    # Support points at known cells of the desk (cell centres, x and y in cells), heights
    # above the plane 1 mm per input point's weight, and three queries.
    e1, e2 = perpendicular_basis(UP)
    cells = np.array([[0, 0], [1, 0], [2, 2], [3, 0], [10, 10], [40, 40]])
    weights = np.array([1, 2, 3, 4, 5, 6])
    lift = 0.001 * np.arange(1, 7)
    along = (cells + 0.5) * CELL
    points = along[:, :1] * e1 + along[:, 1:] * e2 + (DESK_Z + lift)[:, None] * UP
    at = np.array([[0.5, 0.5], [5.5, 0.5], [10.5, 13.5]]) * CELL
    at = at[:, :1] * e1 + at[:, 1:] * e2 + DESK_Z * UP
    n, total = _support_around(points, weights, at, UP, -DESK_Z, CELL)
    # Query 0 at cell (0, 0): cells up to 2 away hold the first three points.
    # Query 1 at cell (5, 0): within 2 only the cell (3, 0).
    # Query 2 at cell (10, 13): nothing within 2; within 4 the cell (10, 10).
    np.testing.assert_array_equal(n, [1 + 2 + 3, 4, 5])
    np.testing.assert_allclose(total, [0.001 * 1 + 0.002 * 2 + 0.003 * 3, 0.004 * 4,
                                       0.005 * 5], rtol=1e-12)


def test_a_point_one_cell_beyond_the_window_is_not_counted():
    e1, e2 = perpendicular_basis(UP)
    r = SUPPORT_AROUND_CELLS
    # One support point r cells away (counted) and one r + 1 cells away (not counted).
    along = np.array([[r + 0.5, 0.5], [-(r + 1) + 0.5, 0.5]]) * CELL
    points = along[:, :1] * e1 + along[:, 1:] * e2 + DESK_Z * UP
    at = np.array([[0.5, 0.5]]) * CELL
    at = at[:, :1] * e1 + at[:, 1:] * e2 + DESK_Z * UP
    n, _ = _support_around(points, np.array([1, 10]), at, UP, -DESK_Z, CELL)
    np.testing.assert_array_equal(n, [1])


def test_no_support_seen_within_the_largest_window():
    e1, e2 = perpendicular_basis(UP)
    far = 2 * SUPPORT_AROUND_MAX_CELLS + 0.5
    along = np.array([[far, 0.5]]) * CELL
    points = along[:, :1] * e1 + along[:, 1:] * e2 + DESK_Z * UP
    at = (0.5 * CELL) * (e1 + e2) + DESK_Z * UP
    n, total = _support_around(points, np.array([3]), at[None, :], UP, -DESK_Z, CELL)
    np.testing.assert_array_equal(n, [0])
    np.testing.assert_array_equal(total, [0.0])


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_random_support_equals_the_plain_definition(seed):
    # A tilted plane with holes of every size (the support's foot under objects), random
    # weights (some working points of no support) and queries inside and outside it.
    rng = np.random.default_rng(seed)
    normal = rng.normal(size=3)
    normal[2] = abs(normal[2]) + 1.0
    normal /= np.linalg.norm(normal)
    e1, e2 = perpendicular_basis(normal)
    m = 3000
    uv = rng.uniform(-0.4, 0.4, size=(m, 2))
    for c in rng.uniform(-0.4, 0.4, size=(6, 2)):
        uv = uv[np.linalg.norm(uv - c, axis=1) > rng.uniform(0.02, 0.15)]
    d = 0.9
    points = uv[:, :1] * e1 + uv[:, 1:] * e2 + (rng.normal(0.0, 0.003, len(uv)) - d)[:, None] \
        * normal
    weights = np.where(rng.random(len(uv)) < 0.7, rng.integers(1, 20, len(uv)), 0)
    q = rng.uniform(-0.5, 0.5, size=(200, 2))
    at = q[:, :1] * e1 + q[:, 1:] * e2 + (rng.normal(0.0, 0.01, len(q)) - d)[:, None] * normal
    n, total = _support_around(points, weights, at, normal, d, CELL)
    want_n, want_total = _plain_support_around(points, weights, at, normal, d, CELL)
    np.testing.assert_array_equal(n, want_n)
    # The tables sum the whole grid before they difference it: rounding of sums of about
    # 10^4 heights of a few mm.
    np.testing.assert_allclose(total, want_total, rtol=0.0, atol=1e-12)
    assert np.any(n == 0) and np.any(n > 0)          # both outcomes are exercised


def test_a_room_sized_plane_gets_coarser_cells_as_defined():
    # A floor 3 km across in 1 cm cells would need 9e10 cells: the cells double.
    rng = np.random.default_rng(7)
    e1, e2 = perpendicular_basis(UP)
    uv = np.r_[rng.uniform(-5.0, 5.0, size=(500, 2)), [[-1500.0, -1500.0], [1500.0, 1500.0]]]
    points = uv[:, :1] * e1 + uv[:, 1:] * e2 + DESK_Z * UP
    weights = rng.integers(1, 5, len(uv))
    q = rng.uniform(-5.0, 5.0, size=(50, 2))
    at = q[:, :1] * e1 + q[:, 1:] * e2 + DESK_Z * UP
    n, total = _support_around(points, weights, at, UP, -DESK_Z, CELL)
    want_n, want_total = _plain_support_around(points, weights, at, UP, -DESK_Z, CELL)
    np.testing.assert_array_equal(n, want_n)
    np.testing.assert_allclose(total, want_total, rtol=0.0, atol=1e-12)


def test_an_object_point_in_two_bands_goes_to_the_first_support_only():
    # A desk z = -0.8 (support 0) and a wall x = 0.3 (support 1) meeting in a corner;
    # object points (label 2) near the corner lie in both bands, others in one or none.
    rng = np.random.default_rng(1)
    desk = np.c_[rng.uniform(-0.3, 0.3, 3000), rng.uniform(-0.2, 0.2, 3000),
                 np.full(3000, DESK_Z)]
    wall = np.c_[np.full(3000, 0.3), rng.uniform(-0.2, 0.2, 3000),
                 rng.uniform(DESK_Z, DESK_Z + 0.4, 3000)]
    band = 0.004
    objects = np.array([[0.298, 0.0, DESK_Z + 0.002],    # in both bands
                        [0.0, 0.0, DESK_Z + 0.003],      # desk band only
                        [0.297, 0.1, DESK_Z + 0.2],      # wall band only
                        [0.0, 0.0, DESK_Z + 0.006],      # in neither
                        [0.299, -0.1, DESK_Z + 0.001]])  # in both bands
    pts = np.r_[desk, wall, objects]
    labels = np.r_[np.zeros(3000, int), np.ones(3000, int), np.full(len(objects), 2)]
    params = ModelingParams(seg_plane_threshold=band)
    planes = _claim_contact_rims(pts, labels, 2, params, np.random.default_rng(0))
    np.testing.assert_array_equal(labels[-len(objects):], [0, 0, 1, 2, 0])
    np.testing.assert_array_equal(labels[:6000], np.r_[np.zeros(3000), np.ones(3000)])
    np.testing.assert_allclose(np.abs(planes[0][0]), [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(np.abs(planes[1][0]), [1.0, 0.0, 0.0], atol=1e-12)


def _plain_claim(p, labels, n_supports, params, rng, local):
    """Claim the rims by the definition, in place in ``labels``.

    Every support in turn refits its plane on its own points and judges the points
    labelled as objects at that moment (the working points' labels taken once, before
    any claim).
    """
    working = np.full(len(local.counts), -1)
    working[local.inverse] = labels
    for sid in range(n_supports):
        own = np.flatnonzero(labels == sid)
        if len(own) > REFIT_MAX_POINTS:
            own = rng.choice(own, REFIT_MAX_POINTS, replace=False)
        nrm, d = support_plane_equation(p[own], params)
        obj = np.flatnonzero(labels >= n_supports)
        near = obj[np.abs(p[obj] @ nrm + d) <= params.seg_plane_threshold]
        if len(near):
            near = near[_on_local_support(p, working == sid, near, nrm, d, local)]
        labels[near] = sid


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_claim_of_two_noisy_supports_equals_the_plain_definition(seed):
    # A noisy desk (support 0) and wall (support 1) meeting in a corner, more desk points
    # than a refit takes; objects: a box standing in the corner (its lower sides in both
    # bands), a slab of desk and a strip of wall labelled as objects.
    rng = np.random.default_rng(seed)
    sigma, voxel = 0.002, 0.004
    desk = np.c_[rng.uniform(-0.4, 0.3, 40000), rng.uniform(-0.3, 0.3, 40000),
                 DESK_Z + rng.normal(0.0, sigma, 40000)]
    wall = np.c_[0.3 + rng.normal(0.0, sigma, 15000), rng.uniform(-0.3, 0.3, 15000),
                 rng.uniform(DESK_Z, DESK_Z + 0.4, 15000)]
    box = np.c_[rng.uniform(0.2, 0.3, 6000), rng.uniform(-0.05, 0.05, 6000),
                rng.uniform(DESK_Z, DESK_Z + 0.08, 6000)]
    pts = np.r_[desk, wall, box]
    labels = np.r_[np.zeros(len(desk), int), np.ones(len(wall), int), np.full(len(box), 2)]
    labels[:40000][np.abs(desk[:, 0] + 0.2) < 0.02] = 3          # a slab of desk
    labels[40000:55000][np.abs(wall[:, 1]) > 0.25] = 4            # strips of wall
    wp, inverse, counts = voxelize(pts, voxel)
    noise = NoiseEstimate(a=sigma, b=0.0, scale=1.5, samples=1)
    local = LocalSupport(wp, inverse, counts, noise, np.zeros(len(wp)), 0.004, 2.5 * voxel)
    params = ModelingParams(seg_plane_threshold=K_SUPPORT * sigma * 1.5, seg_voxel_size=voxel)
    fast, plain = labels.copy(), labels.copy()
    planes = _claim_contact_rims(pts, fast, 2, params, np.random.default_rng(seed), local)
    _plain_claim(pts, plain, 2, params, np.random.default_rng(seed), local)
    np.testing.assert_array_equal(fast, plain)
    # Both supports claimed some of the objects' points, and not all of the box.
    assert np.any((labels >= 2) & (fast == 0)) and np.any((labels >= 2) & (fast == 1))
    assert np.mean(fast[-len(box):] == 2) > 0.5
    assert set(planes) == {0, 1}
