"""Nearest-neighbour search of ``geomodel_ros.core.fastmath.knn`` against a brute force."""

from __future__ import annotations

import multiprocessing

import numpy as np

import pytest
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from geomodel_ros.core.fastmath import FIRST_LINKS, knn, knn_among, link_components


def test_knn_gives_the_nearest_points_in_order_with_their_squared_distances():
    # Random points in a 10 cm cube: no two distances from one point are equal, so the
    # k nearest and their order are unique.
    p = np.random.default_rng(11).uniform(0.0, 0.1, (500, 3))
    idx, sqdist = knn(p, 8, return_sqdist=True)
    assert idx.shape == sqdist.shape == (500, 8)
    assert idx.dtype == np.int64 and sqdist.dtype == np.float64
    d = p[:, None, :] - p[None, :, :]
    full = (d[..., 0] ** 2 + d[..., 1] ** 2) + d[..., 2] ** 2
    expected = np.argsort(full, axis=1)[:, :8]
    np.testing.assert_array_equal(idx, expected)
    np.testing.assert_array_equal(idx[:, 0], np.arange(500))      # itself first
    np.testing.assert_array_equal(sqdist, np.take_along_axis(full, expected, axis=1))
    np.testing.assert_array_equal(knn(p, 8), idx)


def test_knn_asks_for_no_more_neighbours_than_there_are_points():
    p = np.array([[0.0, 0.0, 1.0], [0.0, 0.3, 1.0], [0.1, 0.0, 1.0]])
    idx, sqdist = knn(p, 16, return_sqdist=True)
    np.testing.assert_array_equal(idx, [[0, 2, 1], [1, 0, 2], [2, 0, 1]])
    np.testing.assert_allclose(sqdist, [[0, 0.01, 0.09], [0, 0.09, 0.1], [0, 0.01, 0.1]],
                               rtol=0, atol=1e-15)
    empty, none = knn(np.zeros((0, 3)), 4, return_sqdist=True)
    assert empty.shape == none.shape == (0, 0)


def test_knn_of_other_query_points_and_of_a_single_neighbour():
    rng = np.random.default_rng(12)
    p = rng.uniform(0.0, 0.1, (300, 3))
    q = rng.uniform(0.0, 0.1, (40, 3))
    idx, sqdist = knn(p, 5, return_sqdist=True, queries=q)
    d = q[:, None, :] - p[None, :, :]
    full = (d[..., 0] ** 2 + d[..., 1] ** 2) + d[..., 2] ** 2
    expected = np.argsort(full, axis=1)[:, :5]
    assert idx.shape == sqdist.shape == (40, 5)
    np.testing.assert_array_equal(idx, expected)
    np.testing.assert_allclose(sqdist, np.take_along_axis(full, expected, axis=1),
                               rtol=1e-12, atol=0)
    # k = 1: each point's nearest is itself, still as an (M, 1) array
    one = knn(p, 1)
    assert one.shape == (300, 1) and one.dtype == np.int64
    np.testing.assert_array_equal(one[:, 0], np.arange(300))


def _knn_in_child(queue, p, k):
    queue.put(knn(p, k, return_sqdist=True))


@pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(),
                    reason="no fork on this platform")
def test_knn_in_a_child_forked_after_a_parallel_search():
    # The parent's search starts the OpenMP team (50k queries run in parallel); a child
    # forked after it must still search (GNU OpenMP's threads are not in the child).
    rng = np.random.default_rng(13)
    knn(rng.uniform(0.0, 1.0, (50_000, 3)), 16)
    p = rng.uniform(0.0, 0.1, (400, 3))
    queue = multiprocessing.get_context("fork").Queue()
    child = multiprocessing.get_context("fork").Process(target=_knn_in_child, args=(queue, p, 6))
    child.start()
    try:
        idx, sqdist = queue.get(timeout=60)
    finally:
        child.join(timeout=10)
        if child.is_alive():
            child.kill()
    want, want_sq = _brute_knn(p, 6)
    np.testing.assert_array_equal(idx, want)
    np.testing.assert_allclose(sqdist, want_sq, rtol=1e-12, atol=0)


def _brute_knn(p, k):
    d = p[:, None, :] - p[None, :, :]
    full = (d[..., 0] ** 2 + d[..., 1] ** 2) + d[..., 2] ** 2
    idx = np.argsort(full, axis=1)[:, :k]
    return idx, np.take_along_axis(full, idx, axis=1)


def test_knn_among_gives_the_nearest_points_of_the_subset():
    # Random points (no equal distances): the k nearest within a random subset, whether
    # taken from the whole cloud's lists or searched again, are those of a brute force
    # over the subset alone; both ways occur here.
    rng = np.random.default_rng(5)
    p = rng.uniform(0.0, 0.1, (600, 3))
    sel = np.flatnonzero(rng.random(600) < 0.7)
    for big_k, k in ((8, 8), (12, 8)):
        nb, sq = knn(p, big_k, return_sqdist=True)
        local = np.full(600, -1)
        local[sel] = np.arange(len(sel))
        inside = (local[nb[sel]] >= 0).sum(axis=1) >= k
        assert inside.any() and not inside.all()
        got, got_sq = knn_among(p, sel, nb, sq, k)
        want, want_sq = _brute_knn(p[sel], k)
        np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(got_sq, want_sq)


def test_knn_among_never_returns_a_neighbour_outside_the_subset():
    # Points on a line 1 m apart; the subset {0, 5, 6}. Point 0's two nearest overall are 0
    # and 1, but 1 is not in the subset: its nearest in it are itself and 5 (5 m away).
    p = np.column_stack([np.arange(8.0), np.zeros(8), np.zeros(8)])
    nb, sq = knn(p, 2, return_sqdist=True)
    got, got_sq = knn_among(p, np.array([0, 5, 6]), nb, sq, 2)
    np.testing.assert_array_equal(got, [[0, 1], [1, 2], [2, 1]])
    np.testing.assert_array_equal(got_sq, [[0.0, 25.0], [0.0, 1.0], [0.0, 1.0]])
    # Fewer subset points than neighbours asked for: all of them.
    got, _ = knn_among(p, np.array([3, 7]), nb, sq, 4)
    np.testing.assert_array_equal(got, [[0, 1], [1, 0]])


def _scipy_components(nb, keep):
    m = len(nb)
    rows = np.repeat(np.arange(m), nb.shape[1])[keep.ravel()]
    graph = csr_matrix((np.ones(len(rows)), (rows, nb[keep])), shape=(m, m))
    return connected_components(graph, directed=False)


@pytest.mark.parametrize("seed", range(6))
def test_link_components_are_scipys_on_the_whole_graph(seed):
    # Random clusters linked by their nearest points, links dropped at random (so the
    # first columns alone leave pieces that only the later columns join), some links of
    # the later columns pointing to arbitrary values where they are not kept: the same
    # components, numbered the same way, as scipy gives for all the links.
    rng = np.random.default_rng(seed)
    centres = rng.uniform(0.0, 1.0, (12, 3))
    p = (centres[rng.integers(0, 12, 800)] + rng.normal(0.0, 0.03, (800, 3)))
    nb, sq = knn(p, 16, return_sqdist=True)
    keep = (sq <= 0.03 ** 2) & (rng.random(nb.shape) < 0.6)
    nb = np.where(keep | (rng.random(nb.shape) < 0.5), nb, -1)
    n, labels = link_components(nb, keep)
    want_n, want = _scipy_components(nb, keep)
    assert n == want_n and 1 < n < 800
    np.testing.assert_array_equal(labels, want)
    # The later columns did join pieces of the first ones here.
    first_n, _ = _scipy_components(nb[:, 1:FIRST_LINKS + 1], keep[:, 1:FIRST_LINKS + 1])
    assert first_n > n


def test_link_components_join_through_a_late_link_only():
    # Points 0-1 and 2-3 are linked in the first column; the only link between the two
    # pairs is 1 -> 2 in the last column: one component. Without it, two, numbered by
    # their first point.
    k = FIRST_LINKS + 2
    nb = np.tile(np.arange(4)[:, None], (1, k))
    nb[0, 1], nb[1, 1], nb[2, 1], nb[3, 1] = 1, 0, 3, 2
    nb[1, -1] = 2
    keep = np.zeros((4, k), dtype=bool)
    keep[:, :2] = True
    keep[1, -1] = True
    n, labels = link_components(nb, keep)
    assert n == 1 and labels.tolist() == [0, 0, 0, 0]
    keep[1, -1] = False
    n, labels = link_components(nb, keep)
    assert n == 2 and labels.tolist() == [0, 0, 1, 1]


@pytest.mark.parametrize("k", [1, 2])
def test_link_components_of_one_or_two_columns_are_scipys(k):
    # A kNN list of one column holds only the point itself: no link joins two points, each
    # is its own component (as an object of one working point gives it). With a second
    # column, the pairs linked there: {0, 1}, {2, 3}, {4, 5} (4 points to itself).
    nb = np.column_stack([np.arange(6), [1, 0, 3, 2, 4, 4]])[:, :k]
    keep = np.ones((6, k), dtype=bool)
    n, labels = link_components(nb, keep)
    want_n, want = _scipy_components(nb, keep)
    assert n == want_n == (6 if k == 1 else 3)
    assert labels.dtype == want.dtype
    np.testing.assert_array_equal(labels, want)
    np.testing.assert_array_equal(labels, range(6) if k == 1 else [0, 0, 1, 1, 2, 2])
