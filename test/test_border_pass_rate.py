"""Border vote shares taken relative to what one smooth surface gives under the frame's noise.

:func:`geomodel_ros.core.segmentation._surface_pass_rate` measures the share of the noisy
links inside the patches that pass the border vote (flat or convex within the concavity
tolerance, no step), and :func:`geomodel_ros.core.joins.merge_patches` takes the share of
yes votes of every border not between two exactly tested patches relative to it. The
expectations are worked out by hand: a plane with Gaussian noise along its normal and
exact normals, whose links pass the step test with the probability of a Gaussian
difference (erf(1/2) at a step of one sigma), and hand-made votes whose relative shares
are counted in the comments; then what must not be joined (exact borders, clear creases,
borders found creased).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from geomodel_ros.core.joins import merge_patches
from geomodel_ros.core.segmentation import MIN_PASS_RATE, _surface_pass_rate

#: Working grid of the hand-made plane [m] and its longest link (2.5 voxels, the defaults).
SPACING = 0.004
MAX_EDGE = 2.5 * SPACING
#: Noise of every working point along the plane's normal [m].
SIGMA = 0.001


def _noisy_plane(seed: int, sigma: float = SIGMA, n: int = 60):
    """Build a plane 1 m in front of the sensor, facing it, noisy along its normal.

    Returns points, exact normals (towards the sensor), the 8-neighbourhood on the grid
    (with the point itself; chosen on the noise-free grid, so that no neighbour is chosen
    for its noise, as the nearest in 3-D among a ring of equally far ones would be) and the
    squared 3-D distances, and one patch holding every point.
    """
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.arange(n) * SPACING, np.arange(n) * SPACING)
    grid = np.column_stack([u.ravel(), v.ravel()])
    points = np.column_stack([grid, 1.0 + sigma * rng.standard_normal(n * n)])
    normals = np.tile([0.0, 0.0, -1.0], (len(points), 1))
    _, nbrs = cKDTree(grid).query(grid, k=9, distance_upper_bound=1.5 * SPACING)
    keep = (nbrs < len(points)).all(axis=1)  # inner points: a whole 8-neighbourhood
    nbrs = np.where(keep[:, None], nbrs, np.arange(len(points))[:, None])
    sqdist = np.square(points[nbrs] - points[:, None]).sum(axis=2)
    return points, normals, nbrs, sqdist, np.zeros(len(points), dtype=np.int64)


@pytest.mark.parametrize("step_sigmas, seed", [(1.0, 0), (1.0, 1), (1.0, 2), (2.0, 3)])
def test_a_noisy_plane_passes_the_step_test_as_a_gaussian_difference_does(step_sigmas, seed):
    # With exact normals every link's fold is 0 (it passes any tolerance), and
    # below_i = -below_j = e_i - e_j ~ N(0, 2 sigma^2): the step test at s sigma passes
    # |e_i - e_j| <= s sigma, P(|Z| <= s / sqrt(2)) = erf(s / 2): 0.5205 at one sigma,
    # 0.8427 at two.
    points, normals, nbrs, sqdist, patches = _noisy_plane(seed)
    rate = _surface_pass_rate(points, normals, nbrs, sqdist, patches, MAX_EDGE, 0.1,
                              np.full(len(points), step_sigmas * SIGMA),
                              np.ones(len(points), dtype=bool))
    assert rate == pytest.approx(math.erf(step_sigmas / 2.0), abs=0.03)


def test_the_rate_is_never_below_its_floor():
    # A step of a tenth of sigma passes erf(0.05) = 6 % of the links: the floor holds.
    points, normals, nbrs, sqdist, patches = _noisy_plane(4)
    rate = _surface_pass_rate(points, normals, nbrs, sqdist, patches, MAX_EDGE, 0.1,
                              np.full(len(points), 0.1 * SIGMA),
                              np.ones(len(points), dtype=bool))
    assert rate == MIN_PASS_RATE


def test_without_noisy_links_the_rate_is_one():
    # Where no point's step is set by its noise the tests are exact: nothing to measure.
    points, normals, nbrs, sqdist, patches = _noisy_plane(5)
    rate = _surface_pass_rate(points, normals, nbrs, sqdist, patches, MAX_EDGE, 0.1,
                              np.full(len(points), 0.1 * SIGMA),
                              np.zeros(len(points), dtype=bool))
    assert rate == 1.0


def test_a_noise_free_plane_passes_every_link():
    points, normals, nbrs, sqdist, patches = _noisy_plane(6, sigma=0.0)
    rate = _surface_pass_rate(points, normals, nbrs, sqdist, patches, MAX_EDGE, 0.1,
                              np.full(len(points), SIGMA), np.ones(len(points), dtype=bool))
    assert rate == 1.0


# --- merge_patches: two patches of 400 points (a border needs sqrt(400) = 20 votes) -------
A, B = np.array([0]), np.array([1])
SIZES = np.array([400, 400])


def test_a_border_below_the_majority_joins_relative_to_the_pass_rate():
    # 45 yes of 100 votes: 45 % alone, apart; relative to a pass rate of 0.8 it is
    # 45 / 80 = 56 %, a majority of what one surface gives: joined.
    votes, yes = np.array([100]), np.array([45.0])
    assert merge_patches(2, A, B, votes, yes, sizes=SIZES).tolist() == [0, 1]
    assert merge_patches(2, A, B, votes, yes, sizes=SIZES, pass_rate=0.8).tolist() == [0, 0]


def test_the_relative_share_still_needs_its_majority():
    # 39 of 100 at a pass rate of 0.8: 39 / 80 = 49 %, below half: apart.
    votes, yes = np.array([100]), np.array([39.0])
    assert merge_patches(2, A, B, votes, yes, sizes=SIZES, pass_rate=0.8).tolist() == [0, 1]


def test_exactly_tested_borders_are_not_rescaled():
    # Both patches tested exactly (noise below the fixed floor): a failed link met a real
    # edge, so 45 % stays 45 %: apart, whatever the frame's pass rate elsewhere.
    votes, yes = np.array([100]), np.array([45.0])
    out = merge_patches(2, A, B, votes, yes, sizes=SIZES, exact=np.ones(2, dtype=bool),
                        pass_rate=0.8)
    assert out.tolist() == [0, 1]
    # One noisy patch: the border's tests were not exact, the relative share decides.
    out = merge_patches(2, A, B, votes, yes, sizes=SIZES, exact=np.array([True, False]),
                        pass_rate=0.8)
    assert out.tolist() == [0, 0]


def test_a_border_found_creased_is_never_joined():
    # 70 of 100 is a majority on its own; its median fold showed a crease: apart.
    votes, yes = np.array([100]), np.array([70.0])
    out = merge_patches(2, A, B, votes, yes, sizes=SIZES, creased=np.array([True]),
                        pass_rate=0.6)
    assert out.tolist() == [0, 1]


def test_a_clear_crease_still_keeps_two_groups_apart():
    # Patches 0-1 one object (60 of 100, relative 75 %), 2 another. 1-2 is a clear crease
    # (20 of 100: 25 % relative to 0.8, below the 30 % of a crease); 0-2 has 21 of 40
    # (52 %: a majority alone, 66 % relative) but 0's group already meets 2 at the crease.
    a, b = np.array([0, 0, 1]), np.array([1, 2, 2])
    votes, yes = np.array([100, 40, 100]), np.array([60.0, 21.0, 20.0])
    out = merge_patches(3, a, b, votes, yes, sizes=np.array([400, 400, 400]), pass_rate=0.8)
    assert out[0] == out[1] and out[2] != out[0]
