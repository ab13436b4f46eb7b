"""The curvature ratio of an all-curved object judged with its own uncertainty.

Module: core.model_graph (ratio_halfwidth, curvature_candidates, decide_type).

By hand: with G blocks whose medians give the ratios r_b, the half-width is
t(1 - LOWER_LEVEL, G - 1) * std(r_b, ddof=1) / sqrt(G). Four blocks of ratios 0.3, 0.4,
0.3, 0.4: std = sqrt(4 * 0.05^2 / 3) = 0.05774, se = 0.02887, t(0.975, 3) = 3.1824,
half-width 0.09187.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from geomodel_ros.core.model_graph import (BETWEEN_BOUNDS, FaceInfo, curvature_candidates,
                                           decide_type, ratio_halfwidth)

SPHERE, DEVELOPABLE, VARIATION = 0.45, 0.35, 0.25
#: Points per block in the examples.
M = 50


def blocks_of(ratios, k1=40.0):
    """Return |k1|, |k2| and blocks (M points per block): block b has ratio ratios[b].

    |k1| is constant (k1 constant: cylinder first among the developable candidates).
    """
    ratios = np.asarray(ratios, dtype=float)
    blocks = np.repeat(np.arange(len(ratios)), M)
    a_max = np.full(len(blocks), k1)
    return a_max, a_max * ratios[blocks], blocks


def test_the_halfwidth_is_the_student_interval_of_the_blocks_mean_ratio():
    a_max, a_min, blocks = blocks_of([0.3, 0.4, 0.3, 0.4])
    assert ratio_halfwidth(a_max, a_min, blocks) == pytest.approx(0.091869, abs=2e-6)
    # Equal ratios in every block: no uncertainty.
    a_max, a_min, blocks = blocks_of([0.4] * 16)
    assert ratio_halfwidth(a_max, a_min, blocks) == 0.0


def test_too_few_blocks_give_no_interval():
    a_max, a_min, blocks = blocks_of([0.3, 0.5, 0.3])
    assert ratio_halfwidth(a_max, a_min, blocks) == 0.0


def test_a_ratio_whose_interval_reaches_the_developable_bound_gets_its_candidates():
    # 16 blocks alternating 0.30 / 0.44: ratio of medians over all points 0.37 (the
    # median of |k2| falls between the two halves' values: (0.30 + 0.44) / 2 * 40 / 40),
    # block std 0.0723, se 0.0181, t(0.975, 15) = 2.131: half-width 0.0385 -> 0.33 <= 0.35.
    a_max, a_min, blocks = blocks_of([0.30, 0.44] * 8)
    t = stats.t.ppf(0.975, 15)
    half = t * np.std([0.30, 0.44] * 8, ddof=1) / 4
    assert 0.37 - half <= DEVELOPABLE < 0.37 + half < SPHERE  # the configuration tested
    cands, why = curvature_candidates(a_max, a_min, SPHERE, DEVELOPABLE, VARIATION, blocks)
    assert cands == ("cylinder", "cone", "frustum")
    assert BETWEEN_BOUNDS in why and "0.37" in why


def test_a_ratio_between_the_bounds_measured_tightly_fits_no_primitive():
    # The same ratio 0.40 in every block: the data tell it from both bounds.
    a_max, a_min, blocks = blocks_of([0.40] * 16)
    cands, why = curvature_candidates(a_max, a_min, SPHERE, DEVELOPABLE, VARIATION, blocks)
    assert cands == () and "fits no primitive" in why and BETWEEN_BOUNDS not in why
    # Without blocks the bounds alone decide, as before (also for a scattered ratio).
    a_max, a_min, _ = blocks_of([0.30, 0.44] * 8)
    assert curvature_candidates(a_max, a_min, SPHERE, DEVELOPABLE, VARIATION)[0] == ()


def test_an_interval_reaching_both_bounds_tries_the_nearer_first():
    # Blocks alternating 0.25 / 0.61: ratio 0.43, nearer the sphere bound; block std 0.186,
    # half-width 2.131 * 0.186 / 4 = 0.099 reaches 0.35 and 0.45.
    a_max, a_min, blocks = blocks_of([0.25, 0.61] * 8)
    cands, _ = curvature_candidates(a_max, a_min, SPHERE, DEVELOPABLE, VARIATION, blocks)
    assert cands == ("sphere", "cylinder", "cone", "frustum")
    # Outside the bounds nothing changes: a ratio beyond the sphere bound is a sphere only.
    a_max, a_min, blocks = blocks_of([0.30, 0.70] * 8)
    assert curvature_candidates(a_max, a_min, SPHERE, DEVELOPABLE, VARIATION,
                                blocks)[0] == ("sphere",)


def test_decide_type_marks_candidates_from_the_interval():
    a_max, a_min, blocks = blocks_of([0.30, 0.44] * 8)
    face = FaceInfo(False, np.array([0.0, 0.0, 1.0]), 0.0, len(blocks),
                    np.tile([0.0, 0.0, 1.0], (len(blocks), 1)))
    d = decide_type([face], np.zeros((1, 1), bool), 0.3, 0.006, (a_max, a_min),
                    SPHERE, DEVELOPABLE, VARIATION, blocks=blocks)
    assert d.candidates == ("cylinder", "cone", "frustum") and d.between_bounds
    d = decide_type([face], np.zeros((1, 1), bool), 0.3, 0.006, (a_max, a_min),
                    SPHERE, DEVELOPABLE, VARIATION)
    assert d.candidates == () and not d.between_bounds


def test_a_median_curvature_of_rounding_noise_has_no_relative_variation_in_the_reason():
    # 60 % of the points straight (|k1| at rounding level), 40 % bent at 30 1/m: the
    # IQR over the median has no scale; the reason says so instead of a ratio of 1e22.
    a_max = np.concatenate([np.full(60, 3e-22), np.full(40, 30.0)])
    cands, why = curvature_candidates(a_max, np.zeros(100), SPHERE, DEVELOPABLE, VARIATION)
    assert cands == ("cone", "frustum", "cylinder")
    assert "median ~0" in why and "e+" not in why and "e22" not in why
    # A true median keeps the relative variation.
    a_max = np.concatenate([np.full(60, 20.0), np.full(40, 30.0)])
    cands, why = curvature_candidates(a_max, np.zeros(100), SPHERE, DEVELOPABLE, VARIATION)
    assert cands == ("cone", "frustum", "cylinder") and why.endswith("(0.50)")
