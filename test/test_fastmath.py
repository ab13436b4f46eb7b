"""Nearest-neighbour search of ``geomodel_ros.core.fastmath.knn`` against a brute force."""

from __future__ import annotations

import numpy as np

from geomodel_ros.core.fastmath import knn


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
