"""Far terraces of disparity quantisation: the frame's step and the join of one plane's terraces.

The scenes are built by hand: a pinhole camera (focal length ``F`` px) looks along +z; a
surface's depth along each pixel's ray is quantised to the nearest of the levels 1/z = k *
STEP (k integer), as a Kinect's disparity is. Every level's points form one segment (one
per side of the image where a level appears twice).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from geomodel_ros.core.joins import join_terraces
from geomodel_ros.core.noise import disparity_step
from geomodel_ros.core.params import ModelingParams

#: Kinect v1's disparity step in 1/z [1/m].
STEP = 2.85e-3
#: Focal length [px] (Kinect v1, 640 x 480): one pixel is 1/575 rad, 7 mm at 4 m.
F = 575.0


def _rays(half_u: int = 80, half_v: int = 60) -> np.ndarray:
    """Rays (N, 3) with z = 1 of a pixel grid of (2 half_u + 1) x (2 half_v + 1)."""
    u, v = np.meshgrid(np.arange(-half_u, half_u + 1), np.arange(-half_v, half_v + 1))
    return np.stack([u.ravel() / F, v.ravel() / F, np.ones(u.size)], axis=1)


def _quantised(rays: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points on ``rays`` at depths ``z`` quantised in 1/z, and their level numbers."""
    level = np.round(1.0 / z / STEP).astype(np.int64)
    return rays * (1.0 / (level * STEP))[:, None], level


def test_disparity_step_of_quantised_depths():
    rng = np.random.default_rng(0)
    z = 1.0 / (STEP * rng.integers(80, 1100, size=30000))  # 0.3 to 4.4 m, on the levels
    pts = np.stack([z * rng.uniform(-0.5, 0.5, z.size), z * rng.uniform(-0.4, 0.4, z.size),
                    z], axis=1)
    # The median of gaps between distinct rounded values: within the rounding (1e-6).
    assert disparity_step(pts) == pytest.approx(STEP, abs=1e-6)
    pts[:, 2] *= -1.0  # optical axis along -z (some PCL clouds)
    assert disparity_step(pts) == pytest.approx(STEP, abs=1e-6)


def test_no_disparity_step_for_unquantised_depths():
    rng = np.random.default_rng(1)
    z = rng.uniform(0.5, 4.0, 30000)
    pts = np.stack([0.1 * z, 0.2 * z, z], axis=1)
    assert disparity_step(pts) is None
    assert disparity_step(pts[:1]) is None
    with_nan = pts.copy()
    with_nan[::2] = np.nan
    assert disparity_step(with_nan) is None


def _tilted_wall(depth: float, tilt_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Plane z = depth + tan(tilt) y, quantised: points and level per point."""
    rays = _rays()
    z = depth / (1.0 - math.tan(math.radians(tilt_deg)) * rays[:, 1])
    return _quantised(rays, z)


def test_terraces_of_one_far_wall_are_joined():
    # At 3.8-4.3 m a step is 4.1-5.3 cm, longer than a link (2.5 voxels of 4 mm): the
    # wall is about ten bands of constant depth, each a segment.
    pts, level = _tilted_wall(4.0, 30.0)
    comp = level - level.min()
    assert comp.max() >= 6
    valid = np.ones(len(pts), dtype=bool)
    out = join_terraces(pts, comp, valid, STEP, ModelingParams())
    assert np.unique(out).size == 1


def test_terraces_not_joined_without_a_step_or_near_the_sensor():
    pts, level = _tilted_wall(4.0, 30.0)
    comp = level - level.min()
    valid = np.ones(len(pts), dtype=bool)
    params = ModelingParams()
    np.testing.assert_array_equal(join_terraces(pts, comp, valid, None, params), comp)
    # At 1 m a step is 2.9 mm, shorter than a link: the links cross it, nothing to join.
    near, near_level = _tilted_wall(1.0, 30.0)
    near_comp = near_level - near_level.min()
    assert near_comp.max() >= 2
    out = join_terraces(near, near_comp, np.ones(len(near), dtype=bool), STEP, params)
    np.testing.assert_array_equal(out, near_comp)
    # Points left out (noise) keep their ids and take no part.
    valid[comp % 2 == 1] = False
    out = join_terraces(pts, comp, valid, STEP, params)
    np.testing.assert_array_equal(out[~valid], comp[~valid])
    # Every other band left out: the rest are two steps apart and do not touch.
    assert np.unique(out[valid]).size == np.unique(comp[valid]).size


def test_terraces_of_a_curved_surface_stay_apart():
    # A trough z = 4 + 0.6 x^2 over x = +-0.56 m: 19 cm deeper at the sides than at the
    # middle (about 4 steps), so no plane holds both sides within a step: the bands of
    # the left and right sides (levels appear twice) never end in one group.
    rays = _rays()
    x_over_z = rays[:, 0]
    # z = 4 + 0.6 (z x/z)^2 solved for z (smaller root).
    a = 0.6 * x_over_z ** 2
    z = np.where(a > 1e-12, (1.0 - np.sqrt(np.maximum(1.0 - 16.0 * a, 0.0))) / (2.0 * a + 1e-300),
                 4.0)
    pts, level = _quantised(rays, z)
    assert np.abs(pts[:, 2] - 4.0 - 0.6 * pts[:, 0] ** 2).max() < 0.5 * STEP * 4.5 ** 2
    side = (x_over_z > 0).astype(np.int64)
    # One segment per band and side; the middle band (the nearest level, at x = 0)
    # is one segment that borders the next level on both sides.
    comp = np.where(level == level.max(), 0, 2 * (level.max() - level) + side - 1)
    valid = np.ones(len(pts), dtype=bool)
    out = join_terraces(pts, comp, valid, STEP, ModelingParams())
    assert np.unique(out).size < np.unique(comp).size  # neighbouring bands do join
    outer = np.abs(pts[:, 0]) > 0.45
    left = set(out[outer & (side == 0)].tolist())
    right = set(out[outer & (side == 1)].tolist())
    assert left and right and not left & right
