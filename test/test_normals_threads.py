"""PCA normals of large clouds computed in two halves on two threads.

:func:`geomodel_ros.core.faces.pca_normals` splits clouds of at least ``THREADED_NORMALS``
points into two halves, the second on a thread of its own, and takes the moments'
differences on a transposed copy. These tests check the bits against the one-thread path
and the values against the plain definition (numpy's eigh of every neighbourhood's
covariance, written out here), on clouds whose halves differ: a wrongly split or
wrongly joined half shows.
"""

import numpy as np
import pytest

from geomodel_ros.core import faces
from geomodel_ros.core.faces import estimate_normals, neighborhood_moments, pca_normals
from geomodel_ros.core.fastmath import knn


def _two_sheets(rng, n=3001):
    """Return an odd number of points [m] in three parts.

    A sheet facing the sensor, then a tilted one, then one point repeated (neighbourhoods
    of one point: no plane, variation 0).
    """
    a = rng.uniform(-0.1, 0.1, size=(n // 2, 2))
    first = np.column_stack([a, 0.8 + rng.normal(0.0, 3e-4, len(a))])
    b = rng.uniform(-0.1, 0.1, size=(n - n // 2 - 20, 2))
    second = np.column_stack([b[:, 0] + 0.3, b[:, 1], 0.9 + 0.7 * b[:, 0]])
    same = np.repeat([[0.5, 0.5, 1.5]], 20, axis=0)
    return np.concatenate([first, second, same])


def _plain(points, nbrs, viewpoint):
    """Return normals, variation and smallest eigenvalue from numpy's eigh, point by point."""
    hood = points[nbrs]
    d = hood - hood.mean(axis=1, keepdims=True)
    w, v = np.linalg.eigh(np.einsum("mki,mkj->mij", d, d) / nbrs.shape[1])
    normals = v[:, :, 0]
    away = np.einsum("mi,mi->m", normals, points - viewpoint) > 0
    normals[away] *= -1
    total = w.sum(axis=1)
    variation = np.where(total > 0, w[:, 0] / np.where(total > 0, total, 1.0), 0.0)
    return normals, variation, w[:, 0]


def _bits(a):
    return a.view(np.uint64)


@pytest.mark.parametrize("viewpoint", [None, (0.05, -0.1, 0.2)])
def test_two_threads_give_the_bits_of_one(monkeypatch, viewpoint):
    rng = np.random.default_rng(11)
    pts = _two_sheets(rng)
    nbrs = knn(pts, 16)
    monkeypatch.setattr(faces, "THREADED_NORMALS", len(pts) + 1)
    one = pca_normals(pts, nbrs, viewpoint)
    monkeypatch.setattr(faces, "THREADED_NORMALS", 2)
    two = pca_normals(pts, nbrs, viewpoint)
    for a, b in zip(one, two):
        np.testing.assert_array_equal(_bits(a), _bits(b))
    # estimate_normals goes the same way.
    np.testing.assert_array_equal(_bits(estimate_normals(pts, 16, viewpoint)[0]),
                                  _bits(two[0]))


@pytest.mark.parametrize("threaded", [False, True])
def test_normals_equal_the_plain_definition_on_both_halves(monkeypatch, threaded):
    rng = np.random.default_rng(12)
    pts = _two_sheets(rng)
    nbrs = knn(pts, 12)
    viewpoint = np.zeros(3)
    monkeypatch.setattr(faces, "THREADED_NORMALS", 2 if threaded else len(pts) + 1)
    normals, variation, lam = pca_normals(pts, nbrs)
    want_n, want_v, want_lam = _plain(pts, nbrs, viewpoint)
    plane = np.ptp(pts[nbrs], axis=1).max(axis=1) > 0          # not the repeated point
    # Orientation included: the same unit vector, not only the same line.
    np.testing.assert_allclose(normals[plane], want_n[plane], atol=1e-6)
    np.testing.assert_allclose(variation, want_v, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(lam, want_lam, rtol=1e-6, atol=1e-12)
    assert np.all(variation[~plane] == 0.0) and np.all(np.isfinite(normals))
    # Each half faces its own way: the first sheet along -z, the tilted one off it.
    half = len(pts) // 2
    assert np.median(normals[:half, 2]) < -0.99
    assert np.median(normals[half:-20, 2]) > -0.9


def test_moments_of_some_rows_are_those_rows_of_all():
    rng = np.random.default_rng(13)
    pts = rng.normal(size=(400, 3)) * [0.02, 0.02, 1e-4] + [0.1, 0.2, 0.7]
    nbrs = knn(pts, 10)
    mono = faces._monomials(pts)
    whole = neighborhood_moments(pts, nbrs)
    part = faces._moments(mono, nbrs[150:260])
    for a, b in zip(whole, part):
        np.testing.assert_array_equal(_bits(a[150:260]), _bits(b))
    x = pts[nbrs] - pts[nbrs].mean(axis=1, keepdims=True)
    cov = np.einsum("mki,mkj->mij", x, x) / 10
    want = cov[:, [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]
    np.testing.assert_allclose(np.stack(whole, axis=1), want, rtol=1e-6, atol=1e-15)


def test_empty_and_single_point_clouds():
    normals, variation, lam = pca_normals(np.zeros((0, 3)), np.zeros((0, 1), dtype=np.int64))
    assert normals.shape == (0, 3) and variation.shape == (0,) and lam.shape == (0,)
    normals, variation, lam = pca_normals(np.array([[0.0, 0.0, 1.0]]),
                                          np.zeros((1, 1), dtype=np.int64))
    assert variation[0] == 0.0 and lam[0] == 0.0 and np.isclose(np.linalg.norm(normals[0]), 1.0)


def test_an_error_on_the_second_thread_reaches_the_caller(monkeypatch):
    import threading

    rng = np.random.default_rng(14)
    pts = _two_sheets(rng, n=301)
    nbrs = knn(pts, 8)
    plain = faces.smallest_eigenpairs_sym

    def fails_off_the_main_thread(*entries):
        if threading.current_thread() is not threading.main_thread():
            raise RuntimeError("second half failed")
        return plain(*entries)

    monkeypatch.setattr(faces, "THREADED_NORMALS", 2)
    monkeypatch.setattr(faces, "smallest_eigenpairs_sym", fails_off_the_main_thread)
    with pytest.raises(RuntimeError, match="second half failed"):
        pca_normals(pts, nbrs)
