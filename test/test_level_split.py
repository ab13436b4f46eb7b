"""Flat patches that are two parallel levels are split; one flat or bent surface is not.

Module: core.segmentation (_split_levels, called by the object segmentation with the
frame's noise known). Two touching objects whose flat tops differ by a few millimetres
(a can's top 3 mm above a box's) grow into one smooth patch: the working points along
the contact average both heights. Expectations come from the hand-built geometry: a
grid of working points 4 mm apart (the default working voxel) seen from 0.8 m, its half
x > 0 raised by the step towards the sensor, with independent noise along the normal.
"""
from __future__ import annotations

import numpy as np
import pytest

from geomodel_ros.core.fastmath import knn
from geomodel_ros.core.segmentation import _split_levels

SPACING = 0.004
#: The step floor of the defaults (STEP_SHARE x seg_plane_threshold) [m].
FLOOR = 0.001
MIN_POINTS = 30
ANGLE = 0.2
MAX_EDGE = 0.012


def _patch(height, sigma, seed):
    """Working points of a 12 x 8 cm patch at 0.8 m, z = 0.8 - height(x) + noise."""
    xs, ys = np.meshgrid(np.arange(-0.06, 0.06, SPACING), np.arange(-0.04, 0.04, SPACING))
    x, y = xs.ravel(), ys.ravel()
    rng = np.random.default_rng(seed)
    z = 0.8 - height(x) + rng.normal(0.0, sigma, len(x))
    pts = np.column_stack([x, y, z])
    nbrs, sqdist = knn(pts, 16, return_sqdist=True)
    normals = np.tile([0.0, 0.0, -1.0], (len(x), 1))  # towards the sensor
    return pts, normals, nbrs, sqdist


def _split(pts, normals, nbrs, sqdist, sigma):
    patches = np.zeros(len(pts), dtype=np.int64)
    return _split_levels(pts, normals, nbrs, sqdist, patches, MAX_EDGE,
                         np.full(len(pts), sigma), FLOOR, MIN_POINTS, ANGLE)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("step, sigma", [(0.003, 0.0), (0.003, 0.0005), (0.0025, 0.0005),
                                         (0.004, 0.001)])
def test_two_parallel_levels_are_split_along_the_step(step, sigma, seed):
    pts, normals, nbrs, sqdist = _patch(lambda x: np.where(x > 0, step, 0.0), sigma, seed)
    out, stepped = _split(pts, normals, nbrs, sqdist, sigma)
    assert len(stepped) == 1 and stepped[0][0] == 0
    new = out == stepped[0][1]
    raised = pts[:, 0] > 0
    # The new patch is one of the two levels: at most a few points on the wrong side.
    agree = max(np.mean(new == raised), np.mean(new == ~raised))
    assert agree >= 0.97, agree


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("sigma", [0.0005, 0.001, 0.002])
def test_one_flat_surface_under_noise_is_not_split(sigma, seed):
    pts, normals, nbrs, sqdist = _patch(lambda x: 0.0 * x, sigma, seed)
    out, stepped = _split(pts, normals, nbrs, sqdist, sigma)
    assert stepped == [] and (out == 0).all()


@pytest.mark.parametrize("seed", range(3))
def test_a_tilted_or_bent_surface_is_not_split(seed):
    sigma = 0.0005
    shapes = [lambda x: np.tan(np.radians(10.0)) * x,          # tilted plane
              lambda x: 3.0 * (x / 0.06) ** 2 * 1e-3,          # bent 3 mm to both sides
              lambda x: 3.0 * np.maximum(x / 0.06, 0.0) ** 2 * 1e-3]  # bent on one side
    for h in shapes:
        pts, normals, nbrs, sqdist = _patch(h, sigma, seed)
        _, stepped = _split(pts, normals, nbrs, sqdist, sigma)
        assert stepped == []


def test_a_step_within_the_floor_is_not_split():
    # 0.8 mm, noise-free: below the smallest step between two surfaces.
    pts, normals, nbrs, sqdist = _patch(lambda x: np.where(x > 0, 0.0008, 0.0), 0.0, 0)
    assert _split(pts, normals, nbrs, sqdist, 0.0)[1] == []
