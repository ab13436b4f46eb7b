"""Disparity step of a frame whose depths carry a jitter that blurs only its near levels.

A jitter of sd ``s`` in depth is ``s / z**2`` in 1/z while the disparity step is one constant
in 1/z: 0.5 mm blurs a Kinect's levels at 0.8 m (0.27 of a step) and leaves them sharp at
3 m (0.02). The clouds are built by hand: depths on the levels 1/z = (k + 0.37) STEP (a
camera's levels need not pass through 1/z = 0), then a jitter in depth; the step is found in
the frame's far range (:func:`geomodel_ros.core.noise._far_range_step`). Continuous depths,
clumps of them, and a noise-free render whose far desk repeats one depth along each pixel
row get none.
"""

from __future__ import annotations

import numpy as np
import pytest

from geomodel_ros.core.noise import _blurred_levels, _far_range_step, disparity_step

#: Kinect v1's disparity step in 1/z [1/m].
STEP = 2.85e-3
#: Focal length [px] (Kinect v1, 640 x 480).
F = 575.0


def _cloud(z: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Points (N, 3) at depths ``z`` along random rays in a 0.4 x 0.3 rad window."""
    return np.stack([z * rng.uniform(-0.2, 0.2, z.size), z * rng.uniform(-0.15, 0.15, z.size),
                     z], axis=1)


def _level_depths(rng: np.random.Generator, near: float, far: float, size: int = 30000,
                  shift: float = 0.0) -> np.ndarray:
    """Depths [m] uniform in [near, far] put on the nearest level.

    Each level is moved by up to ``shift`` steps at random (the rounding of stored depths).
    """
    k = np.round(1.0 / rng.uniform(near, far, size) / STEP - 0.37).astype(np.int64)
    moved = rng.uniform(-shift, shift, k.max() + 1)
    return 1.0 / ((k + 0.37 + moved[k]) * STEP)


def _sorted_inverse(pts: np.ndarray) -> np.ndarray:
    return np.sort(1.0 / np.abs(pts[:, 2]))


@pytest.mark.parametrize("jitter_mm", [0.5, 1.0, 2.0])
def test_step_found_where_far_levels_are_sharp(jitter_mm):
    # A floor from 0.8 to 4 m (350 levels); the jitter blurs the levels nearer than about
    # sqrt(jitter / (0.25 STEP)) (0.84-1.7 m), and the whole frame is no set of levels.
    rng = np.random.default_rng(11)
    z = _level_depths(rng, 0.8, 4.0) + rng.normal(0.0, jitter_mm * 1e-3, 30000)
    pts = _cloud(z, rng)
    assert _blurred_levels(_sorted_inverse(pts)) is None
    assert disparity_step(pts) == pytest.approx(STEP, rel=0.02)
    pts[:, 2] *= -1.0  # optical axis along -z
    assert disparity_step(pts) == pytest.approx(STEP, rel=0.02)


def test_step_found_for_rounded_levels_under_a_jitter():
    # Stored depths rounded (levels moved by up to 0.25 of a step), then 0.5 mm of jitter:
    # a tabletop at 0.6-1.1 m blurred, a back wall at 2-3 m sharp.
    rng = np.random.default_rng(12)
    z = np.concatenate([_level_depths(rng, 0.6, 1.1, 20000, 0.25),
                        _level_depths(rng, 2.0, 3.0, 10000, 0.25)])
    z += rng.normal(0.0, 5e-4, z.size)
    pts = _cloud(z, rng)
    assert _blurred_levels(_sorted_inverse(pts)) is None
    assert disparity_step(pts) == pytest.approx(STEP, rel=0.03)


def test_exact_and_slightly_jittered_frames_keep_the_whole_frame_step():
    # Where the levels are exact or resolved over the whole frame, the far range adds
    # nothing: the step is that of the whole frame's levels.
    rng = np.random.default_rng(13)
    z = _level_depths(rng, 0.8, 4.0)
    assert disparity_step(_cloud(z, rng)) == pytest.approx(STEP, abs=1e-6)
    inv = 1.0 / z + rng.normal(0.0, 0.02 * STEP, z.size)
    pts = _cloud(1.0 / inv, rng)
    assert _blurred_levels(_sorted_inverse(pts)) is not None
    assert disparity_step(pts) == pytest.approx(STEP, rel=0.02)


def test_no_step_when_every_range_is_blurred():
    # 2 mm of jitter on a desk at 0.5-1 m: at most 0.7 m behind, a step is 1.4-2.85 mm.
    rng = np.random.default_rng(14)
    z = _level_depths(rng, 0.5, 1.0) + rng.normal(0.0, 2e-3, 30000)
    assert disparity_step(_cloud(z, rng)) is None


@pytest.mark.parametrize("seed", range(8))
def test_no_step_for_continuous_depths_or_clumps(seed):
    rng = np.random.default_rng(100 + seed)
    assert disparity_step(_cloud(rng.uniform(0.5, 4.0, 30000), rng)) is None
    for count in (40, 200, 1000):
        # Objects at random ranges, each a continuum 1 mm deep (sd) or 2e-3 1/m wide.
        centres = np.repeat(rng.uniform(0.5, 4.0, count), 30000 // count)
        assert disparity_step(_cloud(centres + rng.normal(0.0, 1e-3, centres.size), rng)) \
            is None
        centres = np.repeat(rng.uniform(0.25, 2.0, count), 30000 // count)
        inv = centres + rng.uniform(-1e-3, 1e-3, centres.size)
        assert disparity_step(_cloud(1.0 / inv, rng)) is None
    # A dense desk at 0.8-1 m and 300 scattered far points (1-6 m).
    z = np.concatenate([rng.uniform(0.8, 1.0, 29700), rng.uniform(1.0, 6.0, 300)])
    assert disparity_step(_cloud(z, rng)) is None


def test_no_step_for_the_rows_of_a_noise_free_far_desk():
    # A noise-free render: the desk's plane is level in the image's x, so its depth along a
    # ray depends on the pixel row only and each row is one exact value; as 1/z of a plane
    # is affine in the pixel coordinates, its rows are a perfect lattice in 1/z. Nearer,
    # continuous objects. The rows repeat exactly, which no jitter would leave: no step.
    rng = np.random.default_rng(15)
    u, v = np.meshgrid(np.arange(-160, 161), np.arange(-100, 1))
    rays = np.stack([u.ravel() / F, v.ravel() / F, np.ones(u.size)], axis=1)
    tilt = np.radians(60.0)  # the desk's normal, 60 deg from the optical axis
    normal = np.array([0.0, -np.sin(tilt), -np.cos(tilt)])
    desk = rays * (-0.5 / (rays @ normal))[:, None]  # desk 0.5 m from the camera centre
    objects = _cloud(rng.uniform(0.45, 0.7, 2 * len(desk)), rng)
    frame = np.concatenate([desk, objects])
    inv = _sorted_inverse(frame[::max(1, len(frame) // 20000)])
    # Were every value distinct, the desk's rows would pass for levels.
    assert _far_range_step(inv, np.arange(1, len(inv) + 1)) is not None
    assert disparity_step(frame) is None
