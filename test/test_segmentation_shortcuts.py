"""Cheaper forms of segmentation steps give the values of their plain definitions.

Each step below was made cheaper (a neighbourhood's plane computed once and reused, voxel
keys sorted by two radix passes, a nearest-face search on one thread for few queries,
group medians from one sort, the sign of a group median from counts, an image-neighbour
search that stops where no pair can be kept); these tests check the results against
hand-worked values and against the plain definitions, written out here independently of
the code.
"""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from geomodel_ros.core import faces, segmentation
from geomodel_ros.core.faces import (estimate_normals, link_folds, neighborhood_moments,
                                     pca_normals, smallest_eigenpairs_sym)
from geomodel_ros.core.fastmath import knn
from geomodel_ros.core.segmentation import (SEAM_NEIGHBORS, SEAM_RADIUS_SPACINGS,
                                            _concave_patches, _group_median,
                                            _group_median_negative, _image_seam,
                                            _patch_normals, _rest_neighbourhood, _step_free)


def _wavy_sheet(rng, n=1500, noise=0.0005):
    """Points [m] of a wavy sheet 0.6-0.8 m in front of the sensor, with Gaussian noise."""
    xy = rng.uniform(-0.1, 0.1, size=(n, 2))
    z = 0.7 + 0.02 * np.sin(30.0 * xy[:, 0]) + rng.normal(0.0, noise, n)
    return np.column_stack([xy, z])


def test_pca_normals_are_estimate_normals_with_the_plane_residual():
    rng = np.random.default_rng(3)
    pts = _wavy_sheet(rng)
    nbrs = knn(pts, 16)
    normals, variation, lam = pca_normals(pts, nbrs)
    want_n, want_v, _ = estimate_normals(pts, 16, neighbours=(nbrs, None))
    np.testing.assert_array_equal(normals, want_n)
    np.testing.assert_array_equal(variation, want_v)
    # The residual is the smallest eigenvalue of each neighbourhood's covariance (numpy's
    # eigh on the covariance written out), the mean squared distance from its plane.
    hood = pts[nbrs]
    d = hood - hood.mean(axis=1, keepdims=True)
    cov = np.einsum("mki,mkj->mij", d, d) / nbrs.shape[1]
    np.testing.assert_allclose(lam, np.linalg.eigvalsh(cov)[:, 0], rtol=1e-6, atol=1e-12)
    # On the sheet the residual is the noise squared (0.5 mm) times (k - 3) / k (a plane
    # takes 3 of the 16 degrees of freedom): 0.81 of it, plus the sheet's sag over a
    # neighbourhood about 7 mm across (curvature up to 18 /m: 0.1 mm).
    assert 0.3 * 0.0005 ** 2 < np.median(lam) < 1.5 * 0.0005 ** 2


def test_patch_normals_take_the_given_plane_residual_as_their_own():
    rng = np.random.default_rng(4)
    pts = _wavy_sheet(rng)
    normals, _, nbrs = estimate_normals(pts, 16)
    patches = (pts[:, 0] > 0.0).astype(np.int64)          # a border along x = 0
    noise = np.full(len(pts), 0.0003)
    off_plane, _ = smallest_eigenpairs_sym(*neighborhood_moments(pts, nbrs))
    plain = _patch_normals(pts, normals, nbrs, patches, noise)
    given = _patch_normals(pts, normals, nbrs, patches, noise, off_plane)
    np.testing.assert_array_equal(given, plain)
    # A residual that says every neighbourhood is on its plane replaces no normal.
    np.testing.assert_array_equal(
        _patch_normals(pts, normals, nbrs, patches, noise, np.zeros(len(pts))), normals)


def test_rest_neighbourhood_gives_the_normals_and_residuals_of_the_subset():
    rng = np.random.default_rng(5)
    pts = _wavy_sheet(rng, n=2000)
    nbrs, sqdist = knn(pts, 16, return_sqdist=True)
    rest = np.flatnonzero(pts[:, 1] > -0.03)               # two thirds of the sheet
    normals, variation, near, near_sq, off_plane = _rest_neighbourhood(pts, rest, nbrs, sqdist,
                                                                       16)
    sub = pts[rest]
    want_n, want_v, _ = estimate_normals(sub, 16, neighbours=(near, near_sq))
    np.testing.assert_array_equal(normals, want_n)
    np.testing.assert_array_equal(variation, want_v)
    want_lam, _ = smallest_eigenpairs_sym(*neighborhood_moments(sub, near))
    np.testing.assert_array_equal(off_plane, want_lam)
    assert near.max() < len(rest)                          # indices into the subset


@pytest.mark.parametrize("shuffle", [False, True])
def test_voxel_keys_sorted_by_radix_passes_group_as_numpy_unique(shuffle):
    rng = np.random.default_rng(6)
    # Keys of up to 2**32 - 1 in runs, as a scan of a surface gives them (and shuffled).
    runs = np.sort(rng.integers(0, 2 ** 32, 9000)).repeat(rng.integers(1, 6, 9000))
    keys = rng.permutation(runs) if shuffle else runs
    assert len(keys) >= faces.RADIX_MIN_KEYS
    _, want_inv, want_counts = np.unique(keys, return_inverse=True, return_counts=True)
    inverse, counts = faces._sorted_groups(keys)
    np.testing.assert_array_equal(inverse, want_inv.ravel())
    np.testing.assert_array_equal(counts, want_counts)
    # The two passes give the stable sort's order itself.
    np.testing.assert_array_equal(faces._key_order(keys, int(keys.max())),
                                  np.argsort(keys, kind="stable"))


def test_voxel_keys_beyond_two_digits_keep_the_comparison_sort():
    rng = np.random.default_rng(7)
    keys = rng.integers(0, 2 ** 40, 30000)
    _, want_inv, want_counts = np.unique(keys, return_inverse=True, return_counts=True)
    inverse, counts = faces._sorted_groups(keys)
    np.testing.assert_array_equal(inverse, want_inv.ravel())
    np.testing.assert_array_equal(counts, want_counts)


def test_voxelize_averages_each_voxel_whatever_the_point_order():
    rng = np.random.default_rng(8)
    pts = _wavy_sheet(rng, n=30000)
    centroids, inverse, counts = faces.voxelize(pts, 0.004)
    # Plain definition: np.unique of the integer cells, then the mean of each cell.
    cells = np.floor(pts / 0.004).astype(np.int64)
    _, want_inv, want_counts = np.unique(cells, axis=0, return_inverse=True,
                                         return_counts=True)
    np.testing.assert_array_equal(inverse, want_inv.ravel())
    np.testing.assert_array_equal(counts, want_counts)
    want = np.stack([np.bincount(want_inv.ravel(), weights=pts[:, a]) for a in range(3)],
                    axis=1) / want_counts[:, None]
    np.testing.assert_allclose(centroids, want, rtol=0, atol=1e-15)
    order = rng.permutation(len(pts))
    shuffled, inv2, counts2 = faces.voxelize(pts[order], 0.004)
    np.testing.assert_array_equal(inv2, inverse[order])
    np.testing.assert_array_equal(counts2, counts)
    np.testing.assert_allclose(shuffled, centroids, rtol=0, atol=1e-15)


def test_nearest_face_search_gives_the_same_faces_on_one_thread_or_all(monkeypatch):
    rng = np.random.default_rng(9)
    pts = rng.uniform(-0.1, 0.1, size=(6000, 3))
    labels = np.where(pts[:, 0] > 0.0, 0, 1)
    labels[rng.choice(6000, 1500, replace=False)] = -1      # edge points to hand out
    labels[:20] = 2                                          # a face too small to keep
    one = faces._relabel_small(labels, pts, 50)
    monkeypatch.setattr(faces, "THREADED_QUERIES", 1)
    np.testing.assert_array_equal(faces._relabel_small(labels, pts, 50), one)
    # Every point handed out takes its nearest kept point's face.
    keep = labels >= 0
    keep[:20] = False
    _, nearest = cKDTree(pts[keep]).query(pts[~keep])
    np.testing.assert_array_equal(one[~keep], labels[keep][nearest])
    assert set(np.unique(one)) == {0, 1}


def _plain_relabel_small(labels, points, min_size):
    """Faces of at least min_size points keep theirs, the rest take the nearest one's."""
    ids, sizes = np.unique(labels[labels >= 0], return_counts=True)
    big = ids[sizes >= min_size]
    keep = np.isin(labels, big)
    out = labels.copy()
    _, j = cKDTree(points[keep]).query(points[~keep])
    out[~keep] = labels[keep][j]
    return np.unique(out, return_inverse=True)[1].ravel()


@pytest.mark.parametrize("seed", [0, 1])
def test_small_faces_join_their_nearest_big_face_renumbered_in_order(seed):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-0.1, 0.1, size=(3000, 3))
    # Face ids with gaps (ids 0, 3, 7, 12 big; 5 and 9 small) and edge points (-1).
    labels = rng.choice([0, 3, 7, 12], size=3000)
    labels[rng.choice(3000, 600, replace=False)] = -1
    labels[:8] = 5
    labels[8:12] = 9
    got = faces._relabel_small(labels, pts, 20)
    np.testing.assert_array_equal(got, _plain_relabel_small(labels, pts, 20))
    np.testing.assert_array_equal(np.unique(got), [0, 1, 2, 3])      # four big faces
    np.testing.assert_array_equal(got[labels == 7], 2)               # 7 is the third id
    # No big face: one face of everything.
    np.testing.assert_array_equal(faces._relabel_small(labels, pts, 5000), 0)


def _plain_group_median(group, values, n):
    return np.array([np.median(values[group == g]) for g in range(n)])


@pytest.mark.parametrize("n", [1, 7, 40000])
def test_group_median_is_numpys_median_per_group(n):
    rng = np.random.default_rng(10)
    size = max(3 * n, 5000)
    group = np.concatenate([np.arange(n), rng.integers(0, n, size - n)])
    values = np.round(rng.normal(0.0, 1.0, size), 2)       # many equal values
    if n > 100:    # the plain loop is slow over many groups: check a sample of them
        got = _group_median(group, values, n)
        for g in rng.choice(n, 50, replace=False):
            assert got[g] == np.median(values[group == g])
        return
    np.testing.assert_array_equal(_group_median(group, values, n),
                                  _plain_group_median(group, values, n))
    # Hand-worked: the groups {3, 1, 2} and {5, 4} have medians 2 and 4.5.
    np.testing.assert_array_equal(
        _group_median(np.array([0, 1, 0, 1, 0]), np.array([3.0, 5.0, 1.0, 4.0, 2.0]), 2),
        [2.0, 4.5])


@pytest.mark.parametrize("kind", ["normal", "integers", "tiny", "nan", "signs"])
def test_group_median_sign_from_counts_is_the_sign_of_the_median(kind):
    rng = np.random.default_rng(12)
    for _ in range(200):
        n = int(rng.integers(1, 40))
        size = int(rng.integers(n, 300))
        group = np.concatenate([np.arange(n), rng.integers(0, n, size - n)])
        if kind == "normal":
            values = rng.normal(size=size)
        elif kind == "integers":    # exact zeros, and groups with half of them negative
            values = rng.integers(-2, 3, size).astype(float)
        elif kind == "tiny":        # signed zeros and the smallest subnormals
            values = rng.choice([-1e-9, -5e-324, -0.0, 0.0, 5e-324, 1e-9], size)
        elif kind == "nan":
            values = np.where(rng.random(size) < 0.1, np.nan, rng.normal(size=size))
        else:
            values = rng.choice([-1.0, 0.0, 1.0], size) * rng.random(size) * 1e-5
        np.testing.assert_array_equal(_group_median_negative(group, values, n),
                                      _group_median(group, values, n) < 0.0)
    # Hand-worked: {-3, 1} has median -1, {-1, 3} 1, {-2, 0, 5} 0 and {-1, -1, 4} -1.
    np.testing.assert_array_equal(
        _group_median_negative(np.array([0, 0, 1, 1, 2, 2, 2, 3, 3, 3]),
                               np.array([-3.0, 1.0, -1.0, 3.0, -2.0, 0.0, 5.0, -1.0, -1.0, 4.0]),
                               4),
        [True, False, False, True])


def test_link_folds_are_the_mean_depth_below_the_two_tangent_planes():
    rng = np.random.default_rng(13)
    pts = rng.normal(size=(500, 3))
    normals = rng.normal(size=(500, 3))
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    i, j = rng.integers(0, 500, 4000), rng.integers(0, 500, 4000)
    below_i, below_j, _ = _step_free(pts, normals, i, j, np.zeros(500))
    np.testing.assert_array_equal(link_folds(pts, normals, i, j), 0.5 * (below_i + below_j))


def test_concave_patches_are_those_whose_median_fold_is_negative():
    rng = np.random.default_rng(11)
    # A bowl (concave as seen from the sensor above it) beside a dome (convex), and a
    # flat plate between them: the bowl alone is concave.
    xy = rng.uniform(-0.04, 0.04, size=(3000, 2))
    r2 = np.einsum("ij,ij->i", xy, xy)
    parts = [np.column_stack([xy[:, 0] - 0.1, xy[:, 1], 0.6 - 3.0 * r2]),    # bowl
             np.column_stack([xy[:, 0], xy[:, 1], np.full(3000, 0.6)]),       # plate
             np.column_stack([xy[:, 0] + 0.1, xy[:, 1], 0.6 + 3.0 * r2])]     # dome
    pts = np.concatenate(parts)
    patches = np.repeat(np.arange(3), 3000)
    normals, _, nbrs, sqdist = estimate_normals(pts, 16, return_sqdist=True)
    got = _concave_patches(pts, normals, nbrs, sqdist, patches, 3, 0.01)
    np.testing.assert_array_equal(got, [True, False, False])
    # Plain definition: the median fold of each patch's links inside it, i != j.
    m, k = nbrs.shape
    i, j = np.repeat(np.arange(m), k), nbrs.ravel()
    inside = (patches[i] == patches[j]) & (i != j) & (sqdist.ravel() <= 0.01 ** 2)
    fold = link_folds(pts, normals, i[inside], j[inside])
    want = [np.median(fold[patches[i[inside]] == p]) < 0.0 for p in range(3)]
    np.testing.assert_array_equal(got, want)
    # Only the patches asked about are judged; the others are not concave.
    np.testing.assert_array_equal(
        _concave_patches(pts, normals, nbrs, sqdist, patches, 3, 0.01, np.array([2, 1])),
        [False, False, False])


def _plain_image_seam(points, rows, patches, spacing):
    """Pairs of image neighbours on two patches: the full 16-nearest search, then the test."""
    ranges = np.linalg.norm(points, axis=1)
    dirs = points[rows] / ranges[rows][:, None]
    k = min(SEAM_NEIGHBORS, len(rows))
    angle, nb = cKDTree(dirs).query(dirs, k=k)
    i, j = np.repeat(rows, k), rows[nb.ravel()]
    near = (angle.ravel() * np.minimum(ranges[i], ranges[j]) <= SEAM_RADIUS_SPACINGS * spacing)
    near &= patches[i] != patches[j]
    return sorted(zip(i[near].tolist(), j[near].tolist()))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_image_seam_is_the_full_search_tested_pair_by_pair(seed):
    rng = np.random.default_rng(seed)
    # A near box face (0.5 m) in front of a far wall (1.5 m), on a 4 mm grid with jitter:
    # their seam is along the face's outline, and pairs are kept out to 1.5 spacings as
    # seen from the nearer point, so the widest kept angle is the near face's.
    u, v = np.meshgrid(np.arange(-60, 60) * 0.004, np.arange(-60, 60) * 0.004)
    wall = np.column_stack([u.ravel(), v.ravel(), np.full(u.size, 1.5)])
    face = wall[(np.abs(wall[:, 0]) < 0.08) & (np.abs(wall[:, 1]) < 0.08)] / 3.0
    pts = np.concatenate([face, wall]) + rng.normal(0.0, 0.0004, (len(face) + len(wall), 3))
    patches = np.concatenate([np.zeros(len(face), dtype=np.int64),
                              np.ones(len(wall), dtype=np.int64)])
    rows = np.arange(len(pts))
    i, j, far = _image_seam(pts, rows, patches, 0.004)
    got = sorted(zip(i.tolist(), j.tolist()))
    assert got == _plain_image_seam(pts, rows, patches, 0.004)
    assert len(got) > 100                      # the seam along the face's outline
    assert np.all(patches[i] != patches[j])    # never a pair on one patch
    np.testing.assert_array_equal(far, np.where(np.linalg.norm(pts[i], axis=1)
                                                > np.linalg.norm(pts[j], axis=1), i, j))
    np.testing.assert_array_equal(patches[far], 1)   # the wall is behind


def test_image_seam_is_the_same_on_one_thread_or_all(monkeypatch):
    rng = np.random.default_rng(4)
    u, v = np.meshgrid(np.arange(-50, 50) * 0.004, np.arange(-50, 50) * 0.004)
    pts = np.column_stack([u.ravel(), v.ravel(), 1.0 + 0.1 * (u.ravel() > 0.0)])
    pts += rng.normal(0.0, 0.0004, pts.shape)
    patches = (pts[:, 0] > 0.0).astype(np.int64)
    rows = np.arange(len(pts))
    assert len(rows) >= segmentation.THREADED_QUERIES     # searched on all threads
    threaded = _image_seam(pts, rows, patches, 0.004)
    monkeypatch.setattr(segmentation, "THREADED_QUERIES", len(rows) + 1)
    for got, want in zip(_image_seam(pts, rows, patches, 0.004), threaded):
        np.testing.assert_array_equal(got, want)


def test_image_seam_without_pairs_in_reach_is_empty():
    # Two patches 10 degrees apart as seen from the sensor: no image neighbours.
    a = np.array([[0.0, 0.0, 1.0], [0.001, 0.0, 1.0]])
    b = np.array([[0.18, 0.0, 1.0], [0.181, 0.0, 1.0]])
    pts = np.concatenate([a, b])
    i, j, far = _image_seam(pts, np.arange(4), np.array([0, 0, 1, 1]), 0.004)
    assert len(i) == len(j) == len(far) == 0
