"""The edge test within the noise bounds the noise the frame's neighbourhoods show.

Hand geometry: planes and a 90 degree fold on a 4 mm grid with Gaussian noise along their
normals. A depth model that overstates the noise a neighbourhood shows (a real sensor's
noise is correlated between neighbouring pixels, so its working points lie flatter than
the model says) must not make a fold's neighbourhoods planar "within the noise"; one that
understates it (working points of a dense camera) must not cut smooth surfaces apart.
"""

import numpy as np
import pytest

from geomodel_ros.core.faces import estimate_normals, neighborhood_moments, \
    smallest_eigenpairs_sym
from geomodel_ros.core.segmentation import (_patch_normals, _planar_within_noise,
                                            _seen_noise_share)

SPACING = 0.004
K = 16
DOF = K - 3
OFFSET = np.array([0.0, 0.0, 0.8])


def _plane(sigma: float, rng: np.random.Generator, n: int = 30) -> np.ndarray:
    x, y = np.meshgrid(np.arange(n) * SPACING, np.arange(n) * SPACING, indexing="ij")
    return np.c_[x.ravel(), y.ravel(), rng.normal(0.0, sigma, x.size)] - OFFSET


def _fold(sigma: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Top (z = 0, y >= 0) and front (y = 0, z < 0) faces, 20 x 20 points each.

    Returns the points (M, 3) [m] and which of them lie within a spacing of the edge,
    away from the ends.
    """
    u, v = np.meshgrid(np.arange(20) * SPACING, np.arange(20) * SPACING, indexing="ij")
    u, v = u.ravel(), v.ravel()
    top = np.c_[u, v, rng.normal(0.0, sigma, u.size)]
    front = np.c_[u, rng.normal(0.0, sigma, u.size), -(v + SPACING)]
    local = np.r_[top, front]
    near = (np.abs(local[:, 1]) <= SPACING) & (np.abs(local[:, 2]) <= SPACING) \
        & (local[:, 0] > 3 * SPACING) & (local[:, 0] < 16 * SPACING)
    return local - OFFSET, near


def _off_plane(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    _, _, nbrs = estimate_normals(pts, K)
    off, _ = smallest_eigenpairs_sym(*neighborhood_moments(pts, nbrs))
    return off, nbrs


@pytest.mark.parametrize("seed", [0, 1])
def test_noise_as_modelled_keeps_the_plane_planar(seed):
    # Independent noise of exactly the modelled sigma (half the spacing). The 16 nearest
    # neighbours in 3-D favour points near the centre's own height, so the median
    # neighbourhood lies a little flatter than the chi-square median (the share is below
    # 1, not far); the bound on the variance seen still leaves under 3 % of the plane's
    # neighbourhoods out (3 standard deviations).
    rng = np.random.default_rng(seed)
    sigma = 0.002
    off, nbrs = _off_plane(_plane(sigma, rng))
    share = _seen_noise_share(off, np.full(len(off), sigma ** 2), DOF, K)
    assert 0.7 <= share <= 1.0
    assert _planar_within_noise(off, np.full(len(off), sigma), nbrs).mean() >= 0.97


@pytest.mark.parametrize("seed", [2, 3])
def test_overstated_noise_is_scaled_to_what_is_seen(seed):
    # The model says 2 mm, the surface shows 0.5 mm: the variance seen is (0.5 / 2)^2 =
    # 1/16 of the modelled one.
    rng = np.random.default_rng(seed)
    off, nbrs = _off_plane(_plane(0.0005, rng))
    share = _seen_noise_share(off, np.full(len(off), 0.002 ** 2), DOF, K)
    assert 0.8 / 16 <= share <= 1.25 / 16


@pytest.mark.parametrize("seed", [4, 9])
def test_understated_noise_is_scaled_to_what_is_seen(seed):
    # The surface is rougher than the model (2 mm against 0.5 mm): the variance seen is 16
    # times the modelled one (working points averaging many pixels: a voxel's walls select
    # its points by their noise, so its centroid does not average them as independent
    # samples), and the bound follows it; the plane stays planar.
    rng = np.random.default_rng(seed)
    off, nbrs = _off_plane(_plane(0.002, rng))
    share = _seen_noise_share(off, np.full(len(off), 0.0005 ** 2), DOF, K)
    assert 0.7 * 16 <= share <= 1.0 * 16
    assert _planar_within_noise(off, np.full(len(off), 0.0005), nbrs).mean() >= 0.97


@pytest.mark.parametrize("seed", [10, 11])
def test_fold_is_not_planar_under_understated_noise(seed):
    # A 90 degree fold with 1 mm noise; the model says 0.25 mm. The bound widens to the
    # 1 mm the faces show (RMS bound sqrt(1.77) x 1 = 1.3 mm), still short of the ~2 mm a
    # neighbourhood spanning both faces lies off any plane.
    rng = np.random.default_rng(seed)
    pts, near = _fold(0.001, rng)
    off, nbrs = _off_plane(pts)
    model = np.full(len(pts), 0.00025)
    assert _seen_noise_share(off, model ** 2, DOF, K) > 4.0
    planar = _planar_within_noise(off, model, nbrs)
    assert planar[near].mean() <= 0.1
    local = pts + OFFSET
    far = (local[:, 1] > 3 * SPACING) | (local[:, 2] < -3 * SPACING)
    assert planar[far].mean() >= 0.9


def test_unknown_noise_gives_share_one():
    rng = np.random.default_rng(5)
    off, nbrs = _off_plane(_plane(0.001, rng))
    assert _seen_noise_share(off, np.zeros(len(off)), DOF, K) == 1.0


@pytest.mark.parametrize("seed", [6, 7])
def test_fold_is_not_planar_under_overstated_noise(seed):
    # A 90 degree fold with 0.5 mm noise; the model says 2 mm. Within a spacing of the
    # edge a neighbourhood spans both faces and lies about 2 mm RMS off any plane: inside
    # 3 standard deviations of the model's noise (RMS bound sqrt(1.77) x 2 = 2.7 mm), far
    # outside those of the noise the faces show (about a quarter of that).
    rng = np.random.default_rng(seed)
    pts, near = _fold(0.0005, rng)
    off, nbrs = _off_plane(pts)
    assert near.sum() >= 20
    model = np.full(len(pts), 0.002)
    dof_bound = (DOF + 3.0 * np.sqrt(2.0 * DOF)) / K
    assert np.mean(off[near] <= dof_bound * model[near] ** 2) >= 0.9  # planar by the model
    planar = _planar_within_noise(off, model, nbrs)
    assert not planar[near].any()
    # Away from the edge the faces stay planar within the noise they show.
    local = pts + OFFSET
    far = (local[:, 1] > 3 * SPACING) | (local[:, 2] < -3 * SPACING)
    assert planar[far].mean() >= 0.9


def test_points_smooth_by_the_noise_take_their_own_patch_normal():
    # A 90 degree fold whose faces are two patches. With a noise allowance above every
    # residual no point is refitted by its residual, and the points within a spacing of
    # the edge keep normals blended from both faces (about 45 degrees off each). Marked
    # as smooth only by the noise test, they take their own face's normal: z on the top,
    # y on the front (compared up to sign).
    rng = np.random.default_rng(8)
    pts, near = _fold(0.00002, rng)
    normals, _, nbrs = estimate_normals(pts, K)
    off, _ = smallest_eigenpairs_sym(*neighborhood_moments(pts, nbrs))
    local = pts + OFFSET
    on_top = np.abs(local[:, 2]) < 0.5 * SPACING
    patches = np.where(on_top, 0, 1).astype(np.int64)
    face_normal = np.where(on_top[:, None], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0])
    loud = np.full(len(pts), 1.0)
    kept = _patch_normals(pts, normals, nbrs, patches, loud, off)
    refit = _patch_normals(pts, normals, nbrs, patches, loud, off, refit=near)
    cos_kept = np.abs(np.einsum("ij,ij->i", kept, face_normal))[near]
    cos_refit = np.abs(np.einsum("ij,ij->i", refit, face_normal))[near]
    assert np.median(cos_kept) < np.cos(np.radians(20.0))
    assert cos_refit.min() > np.cos(np.radians(2.0))
    # Points not marked keep their normals.
    assert np.array_equal(refit[~near], kept[~near])
