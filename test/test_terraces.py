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
from geomodel_ros.core.noise import NoiseEstimate, disparity_step
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.segmentation import level_quantum

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
    assert disparity_step(pts[:0]) is None
    with_nan = pts.copy()
    with_nan[::2] = np.nan
    assert disparity_step(with_nan) is None


def _tilted_wall(depth: float, tilt_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Plane z = depth + tan(tilt) y, quantised: points and level per point."""
    rays = _rays()
    z = depth / (1.0 - math.tan(math.radians(tilt_deg)) * rays[:, 1])
    return _quantised(rays, z)



def test_depths_whose_inverse_overflows_are_ignored_without_warnings():
    # A malformed message can hold subnormal depths (5e-324 m): 1/z is inf there, and the
    # gaps between sorted levels would be inf - inf = NaN. Such points hold no level: the
    # step is that of the others, and no numeric warning is raised.
    rng = np.random.default_rng(2)
    z = 1.0 / (STEP * rng.integers(80, 1100, size=30000))
    pts = np.stack([0.1 * z, 0.2 * z, z], axis=1)
    pts[::7, 2] = 5e-324
    pts[1::7, 2] = -1e-310
    with np.errstate(all="raise"):
        assert disparity_step(pts) == pytest.approx(STEP, abs=1e-6)
    # Jittered levels (every value distinct: the far-range search) likewise.
    jittered = pts.copy()
    jittered[2::7, 2] += rng.normal(0.0, 1e-5, jittered[2::7].shape[0])
    with np.errstate(all="raise"):
        disparity_step(jittered)
    tiny = np.tile([[0.0, 0.0, 5e-324]], (100, 1))
    with np.errstate(all="raise"):
        assert disparity_step(tiny) is None
    # Normal but so small that 1/z overflows when scaled for the rounding (1e-305 m).
    small = pts.copy()
    small[::7, 2] = 1e-305
    small[1::7, 2] = -3e-303
    with np.errstate(all="raise"):
        assert disparity_step(small) == pytest.approx(STEP, abs=1e-6)


def test_depths_whose_step_squares_beyond_float64_hold_a_level_without_warnings():
    # A malformed cloud's 1e80 m depths: the depth step there (step z^2 = 3e157 m) squares
    # beyond float64's range. Two equal depths are one level; the near working point's
    # step (3 mm at 1 m) is below the 4 mm grid: no level. No numeric warning.
    pts = np.array([[0.0, 0.0, 1e80], [0.0, 0.0, 1e80], [0.0, 0.0, 1.0], [0.001, 0.0, 1.0]])
    with np.errstate(all="raise"):
        quantum = level_quantum(pts, np.array([0, 0, 1, 1]), np.array([2, 2]), 0.003, 0.004)
    assert quantum[0] == pytest.approx(0.003 * 1e160, rel=1e-12)
    assert quantum[1] == 0.0

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


def _bent_wall(depth: float, tilt_deg: float, bend: float) -> tuple[np.ndarray, np.ndarray]:
    """Build the tilted wall of :func:`_tilted_wall` bent by a slow error, then quantise it.

    The error (a sensor's depth distortion) is ``bend`` [m] x sin over two periods across
    the image's columns, along the viewing ray.
    """
    rays = _rays()
    z = depth / (1.0 - math.tan(math.radians(tilt_deg)) * rays[:, 1])
    u = rays[:, 0] / np.abs(rays[:, 0]).max()
    return _quantised(rays, z + bend * np.sin(2.0 * math.pi * u))


def _far_noise(sigma_at_4m: float) -> NoiseEstimate:
    """Return a noise estimate whose sigma grows as z^2 to ``sigma_at_4m`` [m] at 4 m."""
    return NoiseEstimate(a=0.0, b=sigma_at_4m / 16.0, spacing_per_m=1.0 / F, samples=500)


def test_terraces_of_a_wall_bent_by_a_slow_error_join_within_the_frames_noise():
    # A 4 cm slow error bends the wall: the union of its terraces lies up to 1.2 steps
    # (95th percentile; 5.5 cm at 4 m) off its plane, beyond the one step allowed for the
    # quantisation alone. The frame's noise (2.5 cm at 4 m, as a real Kinect's there)
    # explains it: 0.5 step + 2 x 2.1 cm (the noise without the quantisation's share).
    pts, level = _bent_wall(4.0, 30.0, 0.04)
    comp = level - level.min()
    valid = np.ones(len(pts), dtype=bool)
    params = ModelingParams()
    alone = join_terraces(pts, comp, valid, STEP, params)
    assert np.unique(alone).size > 1
    out = join_terraces(pts, comp, valid, STEP, params, _far_noise(0.025))
    assert np.unique(out).size == 1
    # A frame with little noise there allows no more than the step: as without it.
    np.testing.assert_array_equal(
        join_terraces(pts, comp, valid, STEP, params, _far_noise(0.002)), alone)


@pytest.mark.parametrize("sigma", [None, 0.025])
def test_terraces_of_a_curved_surface_stay_apart(sigma):
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
    out = join_terraces(pts, comp, valid, STEP, ModelingParams(),
                        None if sigma is None else _far_noise(sigma))
    assert np.unique(out).size < np.unique(comp).size  # neighbouring bands do join
    outer = np.abs(pts[:, 0]) > 0.45
    left = set(out[outer & (side == 0)].tolist())
    right = set(out[outer & (side == 1)].tolist())
    assert left and right and not left & right


# --------------------------------------------------------------------------- blurred levels
# A small jitter of the depths (a cloud averaged, filtered, transformed or stored with float
# noise) makes every 1/z distinct while the levels stay far apart compared with their width.
# Levels 1/z = (k + 0.37) STEP: a camera's levels need not pass through 1/z = 0.


def _levels(rng: np.random.Generator, size: int = 30000, low: int = 80, high: int = 1100
            ) -> np.ndarray:
    """Points on random levels (k + 0.37) STEP, k in [low, high), rays in a 0.2 rad cone."""
    inv = (rng.integers(low, high, size=size) + 0.37) * STEP
    return inv


def _cloud(inv: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Points (N, 3) at the inverse depths ``inv`` along random rays."""
    z = 1.0 / inv
    return np.stack([z * rng.uniform(-0.2, 0.2, z.size), z * rng.uniform(-0.15, 0.15, z.size),
                     z], axis=1)


def _all_distinct(pts: np.ndarray) -> bool:
    """More distinct 1/z (to 1e-6) than half the points: the distinct-value test sees no levels."""
    return np.unique(np.round(1.0 / np.abs(pts[:, 2]), 6)).size > 0.5 * len(pts)


@pytest.mark.parametrize("jitter", [0.01, 0.03, 0.1])
def test_disparity_step_of_levels_blurred_by_a_small_jitter(jitter):
    # About 30 points per level, each level's mean off by jitter / sqrt(30) <= 0.02 STEP;
    # the median of ~1000 neighbouring differences is within a fraction of that.
    rng = np.random.default_rng(2)
    inv = _levels(rng)
    pts = _cloud(inv + rng.normal(0.0, jitter * STEP, inv.size), rng)
    assert _all_distinct(pts)
    assert disparity_step(pts) == pytest.approx(STEP, rel=0.02)
    pts[:, 2] *= -1.0
    assert disparity_step(pts) == pytest.approx(STEP, rel=0.02)


def test_disparity_step_of_unevenly_rounded_levels():
    # Stored depths rounded (a Kinect's millimetres) move each level by up to 0.3 of a step
    # (neighbours 0.4-1.6 steps apart, median 1); then a jitter of 0.03 STEP.
    rng = np.random.default_rng(3)
    k = rng.integers(88, 351, size=30000)
    shift = rng.uniform(-0.3, 0.3, 351) * STEP
    inv = (k + 0.37) * STEP + shift[k] + rng.normal(0.0, 0.03 * STEP, k.size)
    pts = _cloud(inv, rng)
    assert _all_distinct(pts)
    assert disparity_step(pts) == pytest.approx(STEP, rel=0.03)


@pytest.mark.parametrize("jitter", [0.5, 1.0])
def test_no_disparity_step_when_the_jitter_blurs_the_levels(jitter):
    # Two normal densities one step apart make one mode once their sd reaches half a step:
    # the levels are gone, and so is the step.
    rng = np.random.default_rng(4)
    inv = _levels(rng)
    pts = _cloud(inv + rng.normal(0.0, jitter * STEP, inv.size), rng)
    assert disparity_step(pts) is None


def test_no_disparity_step_for_clumps_or_sparse_tails_of_continuous_depths():
    rng = np.random.default_rng(5)
    # 40 objects at random ranges, each a continuum of 1/z 2e-3 1/m wide: far apart
    # compared with their width, but not a lattice (randomly spaced).
    centres = rng.uniform(0.25, 2.0, 40)
    inv = np.repeat(centres, 750) + rng.uniform(-1e-3, 1e-3, 30000)
    pts = _cloud(inv, rng)
    assert _all_distinct(pts)
    assert disparity_step(pts) is None
    # A dense desk at 0.8-1 m and 300 scattered far points (1-6 m).
    z = np.concatenate([rng.uniform(0.8, 1.0, 29700), rng.uniform(1.0, 6.0, 300)])
    assert disparity_step(_cloud(1.0 / z, rng)) is None


def test_no_disparity_step_for_the_suite_with_continuous_noise():
    from geomodel_ros.tools.synth.suite import render_case, suite_cases
    for case in suite_cases((1,), ("mid", "kinect", "kinect-real")):
        if case.layout != "set_a" or case.distance != 1.0:
            continue
        pts = render_case(case).organized.reshape(-1, 3)
        step = disparity_step(pts[np.isfinite(pts).all(axis=1)])
        # kinect-real quantises 1/z exactly: its distinct values give the step.
        assert step == (pytest.approx(STEP, abs=1e-6) if case.noise == "kinect-real" else None)


def test_terraces_of_a_jittered_far_wall_are_joined():
    # A floor receding from 1.5 to 3.8 m (about 140 levels) and the tilted far wall, every
    # 1/z jittered by 0.02 STEP (0.9 mm in depth at 4 m): the step is found and the wall's
    # bands join as the exact wall's do.
    rng = np.random.default_rng(6)
    wall, level = _quantised(*_tilted_wall_rays(4.0, 30.0))
    floor_z = rng.uniform(1.5, 3.8, 20000)
    floor, _ = _quantised(np.stack([rng.uniform(-0.2, 0.2, floor_z.size),
                                    np.full(floor_z.size, 0.3), np.ones(floor_z.size)], 1),
                          floor_z)
    frame = np.concatenate([wall, floor])
    inv = 1.0 / frame[:, 2] + rng.normal(0.0, 0.02 * STEP, len(frame))
    frame *= (1.0 / inv / frame[:, 2])[:, None]  # moved along the rays
    assert _all_distinct(frame)
    step = disparity_step(frame)
    assert step == pytest.approx(STEP, rel=0.03)
    comp = level - level.min()
    assert comp.max() >= 3
    out = join_terraces(frame[:len(wall)], comp, np.ones(len(wall), dtype=bool), step,
                        ModelingParams())
    assert np.unique(out).size == 1


def _tilted_wall_rays(depth: float, tilt_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Rays of an 81 x 61 pixel window and the depths of the plane z = depth + tan(tilt) y."""
    rays = _rays(40, 30)
    return rays, depth / (1.0 - math.tan(math.radians(tilt_deg)) * rays[:, 1])


def test_no_disparity_step_for_a_few_evenly_spaced_objects():
    # Three objects, each a continuum 0.04 1/m wide, at 1/z = 0.5, 0.9 and 1.3 1/m: their
    # gaps are even, but three levels are no period.
    rng = np.random.default_rng(7)
    inv = np.repeat([0.5, 0.9, 1.3], 10000) + rng.uniform(-0.02, 0.02, 30000)
    pts = _cloud(inv, rng)
    assert _all_distinct(pts)
    assert disparity_step(pts) is None
