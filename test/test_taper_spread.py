"""A round side's taper judged by its own points: least-squares slope and block jackknife spread.

Module: core.fitting.taper_spread (and its use by core.fitting.frustum).

Geometry by hand: a side of revolution about the axis y through (0, 0, 1 m), radius
``r(t) = r_mid + k t`` for ``t`` in [-h/2, h/2], seen from the origin: the points facing
the sensor, angles -80..80 deg about the axis from the direction towards it. Its taper is
``k h``. With independent noise sigma along the rays, the slope's least-squares standard
deviation is about ``sigma / (sqrt(N) std(t))`` (``std(t) = h / sqrt 12``), times a small
factor for the slope's correlation with the axis tilt, so with sigma = 2 mm, N = 2400,
h = 95 mm the taper's spread is a few tenths of a millimetre: a 12 mm taper is far beyond
it, while two inlier bands of that noise (2 x 3.5 sigma = 14 mm) are not.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats

from geomodel_ros.core.fitting.frustum import taper_minimum
from geomodel_ros.core.fitting.slow_bend import SlowBendNull
from geomodel_ros.core.fitting.slow_taper import slow_taper
from geomodel_ros.core.fitting.taper_spread import (LAYERS, MIN_BLOCKS, SECTORS, TAPER_LEVEL,
                                                    least_taper, taper_estimate)
from geomodel_ros.core.noise import NoiseEstimate
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import PrimitiveType
from geomodel_ros.core.ransac import ConeModel
from suite_helpers import suite_true_labels

MM = 1e-3
DEPTH = 1.0
UP = np.array([0.0, 1.0, 0.0])
MID = np.array([0.0, 0.0, DEPTH])
#: The suite's open cup: radii 42 and 30 mm over 95 mm (a 12 mm taper).
R_BASE, R_TOP, HEIGHT = 0.042, 0.030, 0.095
SIGMA = 2.0 * MM


def side(r_mid, slope, height=HEIGHT, rows=60, cols=40, field=None, sigma=SIGMA, seed=0):
    """Points (rows * cols, 3) of the side facing the sensor, noise along the rays [m].

    ``field(y)`` [m], if given, is a range error added along each point's ray.
    """
    t, th = np.meshgrid(np.linspace(-height / 2, height / 2, rows),
                        np.radians(np.linspace(-80.0, 80.0, cols)), indexing="ij")
    t, th = t.ravel(), th.ravel()
    r = r_mid + slope * t
    p = MID + np.c_[r * np.sin(th), t, -r * np.cos(th)]
    ray = p / np.linalg.norm(p, axis=1, keepdims=True)
    err = np.random.default_rng(seed).normal(0.0, sigma, len(p))
    if field is not None:
        err = err + field(p[:, 1])
    return p + ray * err[:, None]


def cone_of(r_mid, slope, height=HEIGHT):
    """Return the exact cone of the side (apex where the radius vanishes), its lo, hi [m]."""
    t_apex = -r_mid / slope
    return ConeModel(MID + UP * t_apex, UP, math.atan(slope)), -height / 2 - t_apex, \
        height / 2 - t_apex


def test_a_cup_taper_far_within_two_bands_is_significant():
    slope = (R_BASE - R_TOP) / HEIGHT
    model, lo, hi = cone_of((R_BASE + R_TOP) / 2, slope)
    taper, least = least_taper(side((R_BASE + R_TOP) / 2, slope), model, lo, hi)
    assert taper == pytest.approx(R_BASE - R_TOP, abs=1.0 * MM)
    # Two inlier bands (3.5 sigma each) would have taken it for a cylinder.
    assert 2 * 3.5 * SIGMA > R_BASE - R_TOP
    assert least < 2.0 * MM
    assert taper > least


def test_a_cylinder_under_independent_noise_shows_no_significant_taper():
    # The RANSAC cone of a cylinder: a slope of 1e-3 (apex 40 m away).
    model, lo, hi = cone_of(0.040, 1e-3)
    taper, least = least_taper(side(0.040, 0.0), model, lo, hi)
    assert abs(taper) < least
    assert least < 2.0 * MM


def test_one_biased_block_is_never_significant():
    # Mixed pixels along one silhouette's lowest quarter: +4 mm off the side in one block
    # (an eighth of the arc, a quarter of the height). The least-squares taper moves by D,
    # and so does every fit but the one without that block: the jackknife spread is
    # (G - 1) / G D, the t statistic G / (G - 1).
    pts = side(0.040, 0.0, sigma=0.5 * MM)
    exact = side(0.040, 0.0, sigma=0.0) - MID       # the same rows without noise
    # The five columns of 40 beyond 60 deg and the 15 rows of 60 lowest: 75 of 2400 points.
    block = (np.arctan2(exact[:, 0], -exact[:, 2]) > np.radians(60.0)) & \
        (exact[:, 1] < -HEIGHT / 4)
    assert block.sum() * SECTORS * LAYERS == len(pts)
    centre = pts - MID
    radial = np.c_[centre[:, 0], np.zeros(len(pts)), centre[:, 2]]
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    pts[block] += 4.0 * MM * radial[block]
    model, lo, hi = cone_of(0.040, 1e-3)
    taper, spread, _ = taper_estimate(pts, model, lo, hi)
    assert abs(taper) > 0.2 * MM                 # the bias does move the estimate
    assert abs(taper) / spread == pytest.approx(SECTORS * LAYERS / (SECTORS * LAYERS - 1),
                                                rel=0.15)
    assert abs(taper) < least_taper(pts, model, lo, hi)[1]


def test_the_level_is_the_slow_nulls_and_the_quantile_students():
    assert TAPER_LEVEL == pytest.approx(1 / 41)
    est = taper_estimate(side(0.040, 0.0), *cone_of(0.040, 1e-3))
    assert est[2] == SECTORS * LAYERS
    ppf = stats.t.ppf(1 - 1 / 41, SECTORS * LAYERS - 1)
    assert least_taper(side(0.040, 0.0), *cone_of(0.040, 1e-3))[1] == pytest.approx(ppf * est[1])


def test_too_few_points_are_not_judged():
    few = side(0.040, 0.0, rows=15, cols=20)     # 300 points, under ten a block
    assert least_taper(few, *cone_of(0.040, 1e-3)) is None


# A slow range error across the image: A sin(2 pi y / wavelength), the same on the support
# (a plane z = 1 m) and on the side; the side's two ends, half a wavelength apart at its
# zero crossing, meet errors of -A and +A: the front of one end moves 2 A nearer.
AMPLITUDE, WAVELENGTH = 2.0 * MM, 2.0 * HEIGHT


def wave(y):
    return AMPLITUDE * np.sin(2.0 * math.pi * y / WAVELENGTH)


def support(step=0.004, half=0.3):
    g = np.arange(-half, half + step / 2, step)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    p = np.c_[x, y, np.full_like(x, DEPTH)]
    ray = p / np.linalg.norm(p, axis=1, keepdims=True)
    return p + ray * wave(y)[:, None]


def test_a_cylinder_under_a_slow_error_field_stays_a_cylinder():
    # The field moves the front of one end 2 A = 4 mm nearer than the other's (the silhouette
    # lines, grazing, do not move across the axis): the fit tilts its axis towards the
    # sensor instead of tapering, and what taper remains is within both terms.
    model, lo, hi = cone_of(0.040, 1e-3)
    taper, least_own = least_taper(side(0.040, 0.0, field=wave, sigma=0.5 * MM), model, lo, hi)
    noise = NoiseEstimate(a=0.5 * MM, b=0.0, samples=100, scale=2.0)
    null = SlowBendNull(support(), np.array([0.0, 0.0, -1.0]), noise)
    cloud = SimpleNamespace(params=ModelingParams(ransac_threshold=7.0 * MM), correlation=2.0,
                            slow_null=null)
    least = taper_minimum(cloud, model, lo, hi, least_own)
    assert least == pytest.approx(max(least_own, slow_taper(null, model.apex + UP * lo,
                                                            model.apex + UP * hi, 0.040)))
    assert abs(taper) <= least
    assert abs(taper) < 0.25 * 2 * AMPLITUDE
    # Negative: the same field on a cup leaves its 12 mm taper a frustum's.
    slope = (R_BASE - R_TOP) / HEIGHT
    cup, c_lo, c_hi = cone_of((R_BASE + R_TOP) / 2, slope)
    taper, least_own = least_taper(side((R_BASE + R_TOP) / 2, slope, field=wave, sigma=0.5 * MM),
                                   cup, c_lo, c_hi)
    assert taper == pytest.approx(R_BASE - R_TOP, abs=1.0 * MM)
    assert taper > taper_minimum(cloud, cup, c_lo, c_hi, least_own)


def test_fixed_noise_values_keep_the_bands():
    model, lo, hi = cone_of(0.040, 1e-3)
    cloud = SimpleNamespace(params=ModelingParams(noise_model="fixed", ransac_threshold=5 * MM),
                            correlation=1.0, slow_null=None)
    assert taper_minimum(cloud, model, lo, hi, 0.1 * MM) == pytest.approx(10.0 * MM)


@pytest.mark.parametrize("noise", ["kinect", "kinect-real"])
def test_suite_frustums_at_one_metre_and_cylinders_stay_cylinders(noise):
    # True labels: the pot (taper 18 mm) and the open cup (12 mm), both within two inlier
    # bands at 1 m, are frustums; the standing and the lying cylinder stay cylinders.
    objs, gts, _ = suite_true_labels("set_c", 1.0, noise, seed=1)
    assert [objs[i].type for i in (1, 2)] == [PrimitiveType.FRUSTUM] * 2
    for i in (1, 2):
        dims, truth = objs[i].dimensions, gts[i].dimensions
        assert dims["radius"] - dims["top_radius"] == pytest.approx(
            truth["radius"] - truth["top_radius"], abs=5.0 * MM)
    for layout, oid in (("set_a", 2), ("set_b", 1)):
        objs, _, _ = suite_true_labels(layout, 1.0, noise, seed=1)
        assert objs[oid].type == PrimitiveType.CYLINDER


def test_a_side_partly_hidden_is_judged_on_the_blocks_that_hold_points():
    # The quarter of the side at positive angle and height is hidden (an occluder). The
    # blocks are equal shares of angle and of height, so the upper quarter by height holds
    # only points of negative angle and the two eighths of largest angle only points of the
    # lower half: the blocks of both are empty. The taper is measured on the others.
    slope = (R_BASE - R_TOP) / HEIGHT
    pts = side((R_BASE + R_TOP) / 2, slope)
    exact = side((R_BASE + R_TOP) / 2, slope, sigma=0.0) - MID
    hidden = (np.arctan2(exact[:, 0], -exact[:, 2]) > 0.0) & (exact[:, 1] > 0.0)
    model, lo, hi = cone_of((R_BASE + R_TOP) / 2, slope)
    taper, spread, blocks = taper_estimate(pts[~hidden], model, lo, hi)
    assert MIN_BLOCKS <= blocks <= SECTORS * LAYERS - 2
    assert taper == pytest.approx(R_BASE - R_TOP, abs=1.0 * MM)
    assert taper > least_taper(pts[~hidden], model, lo, hi)[1]


def test_a_sliver_of_few_blocks_is_not_judged():
    # One point per row along the diagonal of the grid, noise-free: angle and height rise
    # together, in the same order, so the sector of a point's rank fixes its layer: 8
    # blocks hold points (two sectors to a layer), fewer than MIN_BLOCKS.
    n = 400
    pts = side(0.040, 0.0, rows=n, cols=n, sigma=0.0)
    diagonal = np.arange(n) * (n + 1)
    assert SECTORS < MIN_BLOCKS
    assert taper_estimate(pts[diagonal], *cone_of(0.040, 1e-3)) is None
