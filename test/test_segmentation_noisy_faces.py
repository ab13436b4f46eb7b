"""A face whose surface variation comes from the depth noise alone is no band of edge points.

Hand geometry: an L of two perpendicular faces on a 4 mm grid (a box's edge), one of them
noisy along its normal. Under Kinect-class noise a box face seen face-on has a surface
variation above ``edge_variation_threshold`` over its whole area; with the frame's noise
known, its points are smooth when their neighbourhood lies on its plane within that noise.
"""

import numpy as np
import pytest

from geomodel_ros.core.faces import (WorkingCloud, estimate_normals, face_labels,
                                     neighborhood_moments, smallest_eigenpairs_sym)
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.segmentation import _planar_within_noise

SPACING = 0.004
K = 16
#: The L's edge lies on the x axis; it is moved this far from the sensor (origin).
OFFSET = np.array([0.0, 0.0, 0.8])


def _grid(n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    u, v = np.meshgrid(np.arange(n) * SPACING, np.arange(m) * SPACING, indexing="ij")
    return u.ravel(), v.ravel()


def _ell(sigma_top: float, sigma_front: float, rng: np.random.Generator
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points of a top face (y >= 0, z = 0) and a front face (y = 0, z < 0) meeting at y = 0.

    Returns the points (M, 3) [m] (sensor at the origin, faces about 0.8 m away), the
    noise of every point along its face normal (M,) [m] and which points are on the top.
    """
    x, y = _grid(16, 16)
    top = np.c_[x, y, np.zeros_like(x)]
    top[:, 2] += rng.normal(0.0, sigma_top, len(top))
    x, z = _grid(16, 15)
    front = np.c_[x, np.zeros_like(x), -(z + SPACING)]
    front[:, 1] += rng.normal(0.0, sigma_front, len(front))
    pts = np.r_[top, front] - OFFSET
    noise = np.r_[np.full(len(top), sigma_top), np.full(len(front), sigma_front)]
    return pts, noise, np.r_[np.ones(len(top), bool), np.zeros(len(front), bool)]


def _off_plane(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    normals, variation, nbrs = estimate_normals(pts, K)
    off, _ = smallest_eigenpairs_sym(*neighborhood_moments(pts, nbrs))
    return normals, variation, nbrs, off


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noisy_plane_is_planar_within_its_noise(seed):
    # One plane with i.i.d. Gaussian noise sigma along its normal: the noise alone exceeds
    # the 3-standard-deviation bound in under 1 % of neighbourhoods (chi-square, 13 dof).
    rng = np.random.default_rng(seed)
    x, y = _grid(30, 30)
    sigma = 0.002
    pts = np.c_[x, y, rng.normal(0.0, sigma, len(x))] - OFFSET
    _, variation, nbrs, off = _off_plane(pts)
    assert np.median(variation) > ModelingParams().edge_variation_threshold  # edge by variation
    planar = _planar_within_noise(off, np.full(len(pts), sigma), nbrs)
    assert planar.mean() >= 0.97


def test_fold_is_not_planar_at_low_noise():
    # A 90 degree fold seen with noise far below its bend: every point within one spacing
    # of the edge has a neighbourhood on both faces, off any plane by about a millimetre.
    rng = np.random.default_rng(3)
    pts, noise, _ = _ell(0.0001, 0.0001, rng)
    _, _, nbrs, off = _off_plane(pts)
    local = pts + OFFSET
    near_edge = (np.abs(local[:, 1]) <= SPACING) & (np.abs(local[:, 2]) <= SPACING) \
        & (local[:, 0] > 2 * SPACING) & (local[:, 0] < 13 * SPACING)
    assert near_edge.sum() >= 20
    assert not _planar_within_noise(off, noise, nbrs)[near_edge].any()


def test_unknown_noise_makes_nothing_planar():
    rng = np.random.default_rng(4)
    pts, noise, _ = _ell(0.002, 0.00005, rng)
    _, _, nbrs, off = _off_plane(pts)
    assert not _planar_within_noise(off, np.zeros(len(pts)), nbrs).any()


@pytest.mark.parametrize("seed", [5, 6, 7])
def test_noisy_face_keeps_its_points(seed):
    # The top is noisy (2 mm along its normal: variation about 0.07 over its area, above
    # the 0.04 edge threshold), the front quiet. Without the noise, the top's points are
    # edge points handed to the nearest face point, the front's face among them; with it,
    # the top is one face of its own that holds nearly all its points.
    rng = np.random.default_rng(seed)
    pts, noise, on_top = _ell(0.002, 0.00005, rng)
    normals, variation, nbrs, off = _off_plane(pts)
    p = ModelingParams()
    cloud = WorkingCloud(pts, normals, variation, nbrs, np.ones(len(pts), dtype=np.int64),
                         np.arange(len(pts)))
    args = (p.face_angle_threshold, p.edge_variation_threshold, p.min_face_points,
            p.seg_max_edge_factor * SPACING)
    assert np.mean(variation[on_top] > p.edge_variation_threshold) > 0.5
    with_noise = face_labels(cloud, *args, planar=_planar_within_noise(off, noise, nbrs))
    top_face = np.bincount(with_noise[on_top]).argmax()
    front_face = np.bincount(with_noise[~on_top]).argmax()
    assert top_face != front_face
    # The points on the edge line itself (y = 0) belong to both faces; the others do not.
    inside = on_top & (pts[:, 1] + OFFSET[1] > 0.5 * SPACING)
    assert np.mean(with_noise[inside] == top_face) >= 0.95
    assert np.mean(with_noise[~on_top] == front_face) >= 0.95
    without = face_labels(cloud, *args)
    assert np.mean(without[inside] == np.bincount(without[inside]).argmax()) < 0.9
