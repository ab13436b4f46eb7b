"""Working cloud, normals and face splitting (geomodel_ros.core.faces)."""

import numpy as np
import pytest

from geomodel_ros.core.faces import (build_working_cloud, estimate_normals, face_plane,
                                smallest_eigenpairs, split_faces, voxelize, working_voxel_size)


def test_smallest_eigenpairs_match_eigh():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(2000, 3, 3))
    cov = a @ a.transpose(0, 2, 1)
    cov[:5] = np.diag([1.0, 1.0, 0.0])      # repeated largest eigenvalue
    cov[5:10] = np.eye(3)                   # fully degenerate: any unit vector is right
    cov[10:15] = 0.0
    lam, vec = smallest_eigenpairs(cov)
    w, v = np.linalg.eigh(cov)
    np.testing.assert_allclose(lam, w[:, 0], atol=1e-10)
    np.testing.assert_allclose(np.linalg.norm(vec, axis=1), 1.0, atol=1e-12)
    residual = np.einsum("mij,mj->mi", cov, vec) - lam[:, None] * vec
    assert np.abs(residual).max() < 1e-9
    # unique eigenvectors agree with eigh up to sign
    sel = np.arange(15, 2000)
    agree = np.abs(np.einsum("mi,mi->m", vec[sel], v[sel, :, 0]))
    assert agree.min() > 1 - 1e-8
    np.testing.assert_allclose(np.abs(vec[:5, 2]), 1.0, atol=1e-12)


def test_voxelize_averages_points_per_voxel():
    pts = np.array([[0.0001, 0.0001, 0.0001], [0.0009, 0.0009, 0.0009], [0.0051, 0.0, 0.0]])
    centroids, inverse, counts = voxelize(pts, 0.001)
    assert len(centroids) == 2
    assert inverse[0] == inverse[1] != inverse[2]
    np.testing.assert_allclose(centroids[inverse[0]], [0.0005] * 3)
    assert sorted(counts.tolist()) == [1, 2]
    # groups keep points of different groups apart even in one voxel
    c2, inv2, _ = voxelize(pts, 0.001, groups=np.array([0, 1, 0]))
    assert len(c2) == 3 and inv2[0] != inv2[1]


def _box_surface(spacing=0.002):
    """Three visible faces of a 60 x 40 x 50 mm box at z ~ 0.5 m (seen from the origin)."""
    u = np.arange(0, 0.06 + 1e-9, spacing)
    v = np.arange(0, 0.04 + 1e-9, spacing)
    w = np.arange(0, 0.05 + 1e-9, spacing)
    top = np.stack(np.meshgrid(u, v), -1).reshape(-1, 2)
    front = np.stack(np.meshgrid(u, w), -1).reshape(-1, 2)
    side = np.stack(np.meshgrid(v, w), -1).reshape(-1, 2)
    pts = np.vstack([
        np.c_[top[:, 0], top[:, 1], np.zeros(len(top))],          # z = 0 face
        np.c_[front[:, 0], np.zeros(len(front)), front[:, 1]],    # y = 0 face
        np.c_[np.zeros(len(side)), side[:, 0], side[:, 1]],       # x = 0 face
    ])
    return np.unique(pts, axis=0) + np.array([-0.03, -0.02, 0.45])  # edges appear once


def test_split_faces_finds_the_three_box_faces_and_their_adjacency():
    pts = _box_surface()
    cloud = build_working_cloud(pts, 0.003, 16)
    faces = split_faces(cloud, 0.2, 0.04, 12)
    assert faces.count == 3
    adj = faces.adjacency
    assert adj.sum() == 6 and not adj.diagonal().any()  # each pair touches
    # every face's normal is one of the axes
    for f in range(3):
        n = cloud.normals[faces.labels == f].mean(axis=0)
        n /= np.linalg.norm(n)
        assert np.abs(n).max() > 0.995   # 0.9962 measured (normals turn at the edges)


def test_normals_point_to_the_viewpoint():
    pts = _box_surface()
    normals, variation, nbrs = estimate_normals(pts, 12)
    assert np.all(np.einsum("ij,ij->i", normals, pts) <= 0)
    assert nbrs.shape == (len(pts), 12) and np.all(nbrs[:, 0] == np.arange(len(pts)))
    assert np.median(variation) < 1e-6


@pytest.mark.parametrize("n", [1, 2, 3])
def test_tiny_inputs_do_not_crash(n):
    pts = np.random.default_rng(n).random((n, 3))
    normals, variation, nbrs = estimate_normals(pts, 16)
    assert normals.shape == (n, 3) and np.all(np.isfinite(normals))


def test_neighborhood_moments_match_direct_covariances():
    from geomodel_ros.core.faces import neighborhood_moments
    rng = np.random.default_rng(7)
    # Far from the origin and nearly planar: the case where raw moments lose precision.
    pts = rng.normal(size=(500, 3)) * [0.01, 0.01, 1e-5] + [0.3, -0.2, 0.9]
    nbrs = rng.integers(0, 500, size=(500, 12))
    got = np.stack(neighborhood_moments(pts, nbrs), axis=1)
    x = pts[nbrs] - pts[nbrs].mean(axis=1, keepdims=True)
    cov = np.einsum("mki,mkj->mij", x, x) / 12
    want = cov[:, [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-15)


def test_estimate_normals_equal_eigh_of_the_neighbourhood_covariance():
    rng = np.random.default_rng(8)
    pts = rng.normal(size=(800, 3)) * [0.05, 0.03, 0.002] + [0.0, 0.1, 0.6]
    normals, variation, nbrs = estimate_normals(pts, 10)
    x = pts[nbrs] - pts[nbrs].mean(axis=1, keepdims=True)
    w, v = np.linalg.eigh(np.einsum("mki,mkj->mij", x, x) / 10)
    assert np.all(np.abs(np.einsum("mi,mi->m", normals, v[:, :, 0])) > 1 - 1e-9)
    np.testing.assert_allclose(variation, w[:, 0] / w.sum(axis=1), rtol=1e-6, atol=1e-12)


def test_voxelize_dense_table_and_sorting_paths_agree(monkeypatch):
    import geomodel_ros.core.faces as faces

    rng = np.random.default_rng(4)
    pts = rng.uniform(-0.1, 0.1, size=(5000, 3))
    groups = rng.integers(0, 3, size=5000)
    dense = voxelize(pts, 0.01, groups)
    monkeypatch.setattr(faces, "DENSE_CELLS", 0)
    monkeypatch.setattr(faces, "DENSE_CELLS_PER_POINT", 0)
    sorted_ = voxelize(pts, 0.01, groups)
    for a, b in zip(dense, sorted_):
        np.testing.assert_array_equal(a, b)
    # Every input point lies in its voxel, voxels of different groups are apart, and
    # the counts add up.
    assert dense[2].sum() == len(pts)
    np.testing.assert_array_equal(np.floor(dense[0][dense[1]] / 0.01), np.floor(pts / 0.01))
    assert len(dense[2]) == len(np.unique(np.column_stack([np.floor(pts / 0.01), groups]),
                                          axis=0))


def test_large_objects_get_a_coarser_working_cloud_small_ones_keep_the_voxel():
    rng = np.random.default_rng(5)
    plane = np.column_stack([rng.uniform(0, 0.4, 200_000), rng.uniform(0, 0.4, 200_000),
                             np.full(200_000, 0.5)])
    coarse = working_voxel_size(plane, 0.003, 5000)
    assert coarse > 0.003
    wc = build_working_cloud(plane, 0.003, 16, max_points=5000)
    assert 3500 <= len(wc.points) <= 6500
    small = plane[:3000]
    assert working_voxel_size(small, 0.003, 5000) == 0.003
    assert working_voxel_size(plane, 0.003, 10_000_000) == 0.003


def _face_set_of_one(cloud):
    from geomodel_ros.core.faces import FaceSet

    return FaceSet(np.zeros(len(cloud.points), dtype=np.int64), np.zeros((1, 1), dtype=bool))


def test_two_perpendicular_planes_grown_into_one_face_are_taken_apart():
    # An L of two 100 x 80 mm sides of a box, sampled at 2 mm, given as a single face
    # (what region growing does when the normals turn gradually across the edge).
    from geomodel_ros.core.faces import split_plane_unions

    u, v = np.meshgrid(np.arange(0, 0.1, 0.002), np.arange(0, 0.08, 0.002))
    side_a = np.column_stack([u.ravel(), v.ravel(), np.zeros(u.size)])
    side_b = np.column_stack([np.zeros(u.size), v.ravel(), u.ravel()])
    pts = np.vstack([side_a, side_b[u.ravel() > 0]]) + [0.0, 0.0, 0.6]
    cloud = build_working_cloud(pts, 0.003, 16)
    out = split_plane_unions(cloud, _face_set_of_one(cloud), 0.002, 0.14, 12)
    assert out.count == 2
    assert out.adjacency[0, 1] and out.adjacency[1, 0]
    # Each new face is one side: its points lie on one of the two planes.
    for f in range(2):
        q = cloud.points[out.labels == f]
        # Within 1 mm measured: voxel centroids next to the edge average both sides.
        assert min(np.abs(q[:, 2] - 0.6).max(), np.abs(q[:, 0]).max()) < 0.0015


def test_a_curved_face_is_not_taken_apart_into_planes():
    # Half a cylinder (r 40 mm) and a quarter sphere: their normals turn steadily, no
    # two perpendicular planes hold most of them.
    from geomodel_ros.core.faces import split_plane_unions

    phi, y = np.meshgrid(np.linspace(-np.pi / 2, np.pi / 2, 120), np.arange(-0.04, 0.04, 0.002))
    cyl = np.column_stack([0.04 * np.sin(phi.ravel()), y.ravel(), 0.6 - 0.04 * np.cos(phi.ravel())])
    th, ph = np.meshgrid(np.linspace(0, np.pi / 2, 60), np.linspace(0, np.pi, 120))
    sph = 0.05 * np.column_stack([np.sin(th.ravel()) * np.cos(ph.ravel()),
                                  np.sin(th.ravel()) * np.sin(ph.ravel()),
                                  -np.cos(th.ravel())]) + [0.0, 0.0, 0.6]
    for pts in (cyl, sph):
        cloud = build_working_cloud(pts, 0.003, 16)
        faces = _face_set_of_one(cloud)
        assert split_plane_unions(cloud, faces, 0.002, 0.14, 12) is faces


def test_a_face_plane_is_not_tilted_by_strays_behind_it():
    # A 60 x 40 mm face (0.5 mm noise) with 12 % of its working points 0.15-0.35 m
    # behind it along the view (flying pixels): least squares tilts by tens of degrees
    # and spreads the face over centimetres, which made small boxes' faces "curved".
    from geomodel_ros.core.fastmath import robust_sigma
    from geomodel_ros.core.ransac import fit_plane_svd

    rng = np.random.default_rng(5)
    normal = np.array([0.0, -0.6, -0.8])
    e1 = np.array([1.0, 0.0, 0.0])
    e2 = np.cross(normal, e1)
    uv = rng.uniform([-0.03, -0.02], [0.03, 0.02], (600, 2))
    face = np.array([0.0, 0.0, 0.8]) + uv[:, :1] * e1 + uv[:, 1:] * e2 + \
        rng.normal(0.0, 0.0005, (600, 1)) * normal
    behind = face[:80] * rng.uniform(1.2, 1.45, (80, 1))
    pts = np.vstack([face, behind])
    normals = np.vstack([np.tile(normal, (600, 1)),
                         rng.normal(0.0, 0.3, (80, 3)) + normal])
    lsq = fit_plane_svd(pts)
    assert robust_sigma(lsq.distance(pts)) > 0.003  # what made the face curved
    plane, spread = face_plane(pts, normals, 0.006)
    assert abs(plane.normal @ normal) >= np.cos(np.radians(0.5))   # 0.15 deg measured
    assert spread < 0.0007   # the face's own noise, sigma 0.5 mm


def test_sorted_groups_numbers_equal_keys_in_ascending_order():
    from geomodel_ros.core.faces import _sorted_groups

    # Mostly ascending (scan order, the stable sort) and mixed (quicksort): groups are
    # numbered by ascending key, sizes counted, as numpy.unique numbers them.
    inverse, counts = _sorted_groups(np.array([1, 1, 3, 3, 3, 7], dtype=np.int64))
    np.testing.assert_array_equal(inverse, [0, 0, 1, 1, 1, 2])
    np.testing.assert_array_equal(counts, [2, 3, 1])
    inverse, counts = _sorted_groups(np.array([5, 5, 2, 9, 2], dtype=np.int64))
    np.testing.assert_array_equal(inverse, [1, 1, 0, 2, 0])
    np.testing.assert_array_equal(counts, [2, 2, 1])
    rng = np.random.default_rng(8)
    runs = np.sort(rng.integers(0, 10 ** 9, 3000)).repeat(rng.integers(1, 5, 3000))
    for keys in (runs, rng.permutation(runs)):
        _, want_inv, want_counts = np.unique(keys, return_inverse=True, return_counts=True)
        inverse, counts = _sorted_groups(keys)
        np.testing.assert_array_equal(inverse, want_inv.ravel())
        np.testing.assert_array_equal(counts, want_counts)
