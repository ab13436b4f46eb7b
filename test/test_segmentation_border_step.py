"""A patch border judged as a whole: a step or crease along it, not link by link.

Hand-made borders, the geometry worked out in the comments. A grid of working points 4 mm
apart (the default ``seg_voxel_size``) at 1 m in front of the sensor, split into two
patches along the line y = 0, 10 cm long. The depth noise is that of a Kinect-like frame:
every working point averages ``COUNT`` input points of sigma 1.5 mm that neighbours do not
share (local sigma of a working point 1.5 / sqrt(9) = 0.5 mm), plus a slowly varying error
shared by neighbours (a smooth field of 2 mm amplitude over 5 cm); the frame's estimate
(:class:`~geomodel_ros.core.noise.NoiseEstimate`) carries that slow part as its ``scale``.

- :func:`geomodel_ros.core.segmentation._border_votes` marks a border ``stepped`` where the
  median offset of its links between parallel sides, or the median fold, departs from one
  smooth surface by more than the median's standard error allows;
- :func:`geomodel_ros.core.joins.merge_patches` never joins a stepped border and treats it
  as a crease.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from geomodel_ros.core.faces import estimate_normals
from geomodel_ros.core.joins import merge_patches
from geomodel_ros.core.noise import NoiseEstimate, object_params
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.segmentation import (STEP_SHARE, _border_votes, _patch_normals,
                                            working_noise)

MM = 1e-3
SPACING = 4 * MM
#: Input points per working point (a Kinect at 1 m has about 1.7 mm between its pixels:
#: some 9 of them in a 4 mm voxel).
COUNT = 9
#: The frame's noise over its local noise, as on real Kinect frames (1.6-2.5).
SCALE = 1.9
#: Noise of one input point that neighbours do not share [m].
LOCAL_SIGMA = 1.5 * MM
SEEDS = range(12)


def _field(x, y, rng, amplitude, wavelength):
    """Smooth random field: a product of two sinusoids with random phases."""
    phase = rng.uniform(0.0, 2.0 * math.pi, 2)
    return amplitude * np.sin(2 * math.pi * x / wavelength + phase[0]) \
        * np.cos(2 * math.pi * y / wavelength + phase[1])


def _border(rng, step=0.0, fold=0.0, length=0.10, local_sigma=LOCAL_SIGMA, slow=2 * MM):
    """Votes of the one border between the halves y < 0 and y > 0 of a plane at 1 m.

    The half y > 0 is raised towards the sensor by ``step`` [m] and bent about the
    border by ``fold`` [rad] (positive: concave, the two halves rise towards each other
    when seen from the sensor; negative: convex).

    Returns
    -------
    votes, yes : int, float
        Links across the border and their yes votes (link by link).
    stepped : bool
        The whole-border verdict.
    """
    xs = np.arange(-length / 2, length / 2, SPACING) + SPACING / 2
    ys = np.arange(-0.03, 0.03, SPACING) + SPACING / 2
    x, y = (g.ravel() for g in np.meshgrid(xs, ys))
    upper = y > 0
    # The sensor looks along +z; "towards the sensor" is -z. A concave fold lifts the far
    # parts of both halves: |y| tan(fold) towards the sensor.
    z = 1.0 - step * upper - np.abs(y) * math.tan(fold) + _field(x, y, rng, slow, 0.05)
    z += rng.normal(0.0, local_sigma / math.sqrt(COUNT), len(x))
    points = np.c_[x, y, z]
    patches = upper.astype(np.int64)
    noise = NoiseEstimate(a=SCALE * local_sigma, b=0.0, scale=SCALE, samples=1)
    params = object_params(ModelingParams(), noise, depth=1.0)
    normals, _, nbrs, sqdist = estimate_normals(points, params.normal_neighbors,
                                                return_sqdist=True)
    noise_w = working_noise(points, np.full(len(points), COUNT), noise)
    floor = STEP_SHARE * params.seg_plane_threshold
    step_w = np.maximum(floor, noise_w)
    normals, own = _patch_normals(points, normals, nbrs, patches, noise_w, return_own=True)
    max_edge = params.seg_max_edge_factor * params.seg_voxel_size
    parallel = math.cos(params.face_angle_threshold)
    _, _, votes, yes, stepped = _border_votes(
        points, normals, nbrs, sqdist, patches, 2, max_edge, params.seg_concavity_tolerance,
        step_w, parallel, whole=(own, noise_w, SCALE, floor))
    assert len(votes) == 1
    return int(votes[0]), float(yes[0]), bool(stepped[0])


def test_a_consistent_small_step_along_a_long_border_is_cut():
    # A 2.5 mm step (a can's top beside a box's top) is 5 local sigmas of a working point
    # but only 1.3 frame sigmas (0.5 mm x 1.9 x ... per input point 2.85 mm): link by link
    # most votes pass it (the per-link limit follows the frame's noise and its plane
    # band), so the majority would join the two levels. Along 10 cm (25 point spacings,
    # each about an independent vote) the median offset stands 2.5 mm off with a
    # standard error of about 0.5 mm x 1.25 x spread / 5: the border is cut, every seed.
    for seed in SEEDS:
        votes, yes, stepped = _border(np.random.default_rng(seed), step=2.5 * MM)
        assert yes >= 0.5 * votes, seed  # the link-by-link majority is fooled
        assert stepped, seed


def test_one_smooth_surface_split_into_two_patches_is_not_cut():
    # The same plane with its slowly varying error and no step: the medians of fold and
    # offset stay within their standard errors (3 of them are needed).
    for seed in SEEDS:
        assert not _border(np.random.default_rng(seed))[2], seed


def test_random_link_excursions_as_large_as_the_step_are_not_cut():
    # Local noise five times larger (7.5 mm an input point, 2.5 mm a working point): one
    # link's offset is often as large as the 2.5 mm step above (sqrt(2) x 2.5 mm is its
    # sigma), but it has no consistent sign along the border, so the median stays small.
    for seed in SEEDS:
        assert not _border(np.random.default_rng(seed), local_sigma=7.5 * MM)[2], seed


def test_the_same_step_along_a_short_border_is_not_enough_evidence():
    # A 1 mm step (2 local sigmas of a working point) is cut along 20 cm but along 1.6 cm
    # (4 point spacings) its median has a standard error 3.5 times larger: too little
    # evidence, the border is left to the per-link votes.
    long_cut = [_border(np.random.default_rng(s), step=1.0 * MM, length=0.20)[2]
                for s in SEEDS]
    short_cut = [_border(np.random.default_rng(s), step=1.0 * MM, length=0.016)[2]
                 for s in SEEDS]
    assert all(long_cut)
    assert not any(short_cut)


def test_a_shallow_concave_crease_is_cut_and_the_same_convex_fold_is_not():
    # Two faces meeting at 2 x 6 degrees concave (two objects leaning against each other):
    # across a 4-8 mm link the fold is about -tan(6 deg) x 6 mm = -0.6 mm, within the
    # frame's per-link tolerance (and the concavity tolerance 0.1 x link length), but
    # consistent along the border. Convex by the same angle (the rounded edge of one
    # object) it is no crease.
    fold = math.radians(6.0)
    for seed in SEEDS:
        assert _border(np.random.default_rng(seed), fold=fold)[2], seed
        assert not _border(np.random.default_rng(seed), fold=-fold)[2], seed


# --------------------------------------------------------------------------- merge_patches
def test_a_stepped_border_is_never_joined_whatever_its_votes():
    # Two patches of 100 points, all 60 votes yes (a majority and a border of more than
    # sqrt(100) = 10 votes): joined, unless the border is stepped.
    a, b, votes, yes = np.array([0]), np.array([1]), np.array([60]), np.array([60.0])
    sizes = np.array([100, 100])
    assert merge_patches(2, a, b, votes, yes, sizes=sizes).tolist() == [0, 0]
    assert merge_patches(2, a, b, votes, yes, sizes=sizes,
                         stepped=np.array([True])).tolist() == [0, 1]


def test_a_stepped_border_keeps_its_patches_apart_through_a_third():
    # Patches 0 and 1 meet at a step; patch 2 borders both with all-yes votes (a can's
    # side touching a box's top and the can's own top). Joining 2 to one of them is fine,
    # but not to both: that would put 0 and 1, apart at the step, in one object. The
    # strongest pair (0, 2: 50 yes) joins first, then (1, 2) is refused.
    a, b = np.array([0, 0, 1]), np.array([1, 2, 2])
    votes, yes = np.array([40, 50, 45]), np.array([40.0, 50.0, 45.0])
    out = merge_patches(3, a, b, votes, yes, stepped=np.array([True, False, False]))
    assert out[0] == out[2] and out[1] != out[0]
    # Without the step all three are one object.
    assert len(set(merge_patches(3, a, b, votes, yes).tolist())) == 1


def test_without_a_noise_estimate_no_border_is_tested_as_a_whole():
    # noise_model = fixed: no local noise, the border votes alone decide (as before).
    rng = np.random.default_rng(0)
    points = np.c_[rng.uniform(-0.05, 0.05, (200, 2)), np.ones(200)]
    patches = (points[:, 1] > 0).astype(np.int64)
    normals, _, nbrs, sqdist = estimate_normals(points, 16, return_sqdist=True)
    out = _border_votes(points, normals, nbrs, sqdist, patches, 2, 0.01, 0.1,
                        np.full(200, 1 * MM))
    assert out[4] is None


@pytest.mark.parametrize("step_mm", [5.0])
def test_a_large_step_is_cut_along_a_short_border_too(step_mm):
    # 5 mm along 4 cm: 10 spacings, the bound about 0.5 mm x 1.25 x spread x 3 / 3.2.
    for seed in SEEDS:
        assert _border(np.random.default_rng(seed), step=step_mm * MM, length=0.04)[2], seed
