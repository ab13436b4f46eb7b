"""How surely a round side's own points show a taper: its least-squares slope and spread.

A frustum differs from a cylinder by its taper, the difference of its two radii. How well
the side's points measure it does not follow from the inlier band (a band says where a
point may lie, not how well many points fix a slope): it follows from the residuals the
points leave about the fitted side. The side is taken as a surface of revolution whose
radius is linear along its axis, ``rho(t) = r + k t`` (``t`` from the side's mid-height),
linearised about the RANSAC cone: six parameters (the axis moved across itself, two; tilted
about its mid-point, two; ``r``; ``k``), solved by least squares over the side's points.
The slope's spread is the delete-a-block jackknife over blocks of the side (:data:`SECTORS`
around the axis times :data:`LAYERS` along it): the side is fitted again without each
block in turn, and the slopes' scatter is the spread. Residuals correlated within a block
-- a sensor's slowly varying range error, mixed pixels along one silhouette, a dent --
then count as one observation per block instead of one per point, and a taper that one
block alone makes (its slope without that block differing by all of it) is never
significant: its t statistic is G / (G - 1). The taper is
significant when its estimate exceeds the one-sided Student quantile (G - 1 degrees of
freedom for G blocks) at :data:`TAPER_LEVEL` times that spread.

What a slow error common to the whole side does (one end of it nearer the camera than the
other) no block structure shows; that part is measured on the frame's support instead
(:mod:`~.slow_taper`).

The same fit with one term more, ``c t^2``, tells whether the profile is straight at all
(a cylinder's, cone's or frustum's) or curved (a torus's, a sphere's, a barrel's): its
bow (the middle off the chord through the ends) and the turn of its tangent between the
ends (:func:`profile_bow`), the bow judged by the same jackknife (:func:`least_bow`). A
cylinder is fitted as the side of slope 0 about its axis point (:func:`_profile`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from geomodel_ros.core.fitting.slow_bend import NULL_PATCHES
from geomodel_ros.core.geometry import frame_with_z
from geomodel_ros.core.ransac import ConeModel, CylinderModel

__all__ = ["SECTORS", "LAYERS", "TAPER_LEVEL", "MIN_BLOCK_POINTS", "MIN_BLOCKS", "taper_estimate",
           "least_taper", "PROFILE_SAMPLE", "ProfileBow",
           "profile_bow", "least_bow"]

#: Blocks around the axis (equal shares of the side's points by angle). The taper is told
#: from an axis tilt or offset by the silhouettes against the front, and the fit without a
#: block must still see both silhouettes nearly whole: a block is an eighth of the seen
#: arc. (With quarters, leaving out one silhouette's lowest block moved the taper of the
#: suite's pot at 0.5 m by 5 mm either way: a spread of 8 mm for a true 18 mm taper.)
SECTORS = 8
#: Blocks along the axis (equal shares of the points by height): the slope is measured by
#: the ends against the middle; four layers leave two of them when one end is left out.
#: With SECTORS, 32 blocks: 31 degrees of freedom, the Student quantile within 4 % of the
#: normal's.
LAYERS = 4
#: One-sided level of the taper test: the slow-error nulls' (a Monte-Carlo test over
#: NULL_PATCHES patches, level 1 / (NULL_PATCHES + 1)), so that the two terms of the
#: frustum's least taper are judged alike.
TAPER_LEVEL = 1.0 / (NULL_PATCHES + 1)
#: Fewest points per block: fewer blocks than parameters leave the spread undetermined,
#: so sides of fewer than SECTORS * LAYERS * MIN_BLOCK_POINTS points are not judged.
MIN_BLOCK_POINTS = 10
#: The profile's bow and turn (:func:`profile_bow`, a magnitude compared with ``min_arc``)
#: are measured on at most this many of the side's points (every n-th): its cost then
#: stays a fraction of a millisecond per side (2 ms on an 11k-point side), and its
#: least-squares spread on 2000 points stays a few hundredths of a radian (the
#: turns that decide lie 0.15 rad or more from ``min_arc``, measured).
PROFILE_SAMPLE = 2000
#: Parameters of the linearised side (axis offset 2, axis tilt 2, radius, slope).
_PARAMS = 6
#: Fewest blocks holding points for a judgement: twice the parameters, the jackknife's
#: spread from G blocks being itself unsure by about 1 / sqrt(2 (G - 1)) (21 % at 12
#: blocks). A side with fewer (seen as a sliver) is not judged.
MIN_BLOCKS = 2 * _PARAMS


def _profile(model: ConeModel | CylinderModel) -> tuple[NDArray[np.float64], float, float]:
    """Origin (3,) [m] on the axis, slope and radius [m] there of a round side's straight profile.

    The radius at ``s`` [m] along ``model.axis`` from the origin is ``radius + slope s``: a
    cone's apex with ``tan(half_angle)`` and 0, a cylinder's axis point with 0 and its radius.
    """
    if isinstance(model, ConeModel):
        return model.apex, math.tan(model.half_angle), 0.0
    return model.point, 0.0, model.radius


def _design(points: NDArray[np.float64], model: ConeModel | CylinderModel, mid: float
            ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                       NDArray[np.float64]]:
    """Jacobian (K, 6), residuals (K,) [m], heights (K,) [m] and angles (K,) [rad] of a side.

    The side of ``model`` at ``mid`` [m] along its axis from its origin (:func:`_profile`):
    ``rho = r + k t`` with ``k`` the side's slope and ``r`` its radius at ``mid``; residual
    ``rho_i - r - k t_i``.
    """
    origin, k, base = _profile(model)
    frame = frame_with_z(model.axis)
    e1, e2, a = frame[:, 0], frame[:, 1], frame[:, 2]
    v = points - (origin + a * mid)
    t = v @ a
    radial = v - t[:, None] * a
    rho = np.maximum(np.linalg.norm(radial, axis=1), np.finfo(float).tiny)
    u1, u2 = (radial @ e1) / rho, (radial @ e2) / rho
    jac = np.stack([-u1, -u2, -t * u1 - k * (v @ e1), -t * u2 - k * (v @ e2),
                    -np.ones_like(t), -t], axis=1)
    return jac, rho - (base + k * mid) - k * t, t, np.arctan2(u2, u1)


def _blocks(t: NDArray[np.float64], angle: NDArray[np.float64]) -> NDArray[np.int64]:
    """Block index (K,) of each point: SECTORS by angle around the axis times LAYERS by height.

    Angles are measured from the middle of the largest gap of the seen arc, so that a
    sector never straddles the unseen back of the side.
    """
    order = np.sort(angle)
    gaps = np.diff(np.r_[order, order[0] + 2.0 * math.pi])
    start = order[int(np.argmax(gaps))] + gaps.max() / 2.0
    around = np.mod(angle - start, 2.0 * math.pi)
    sector = np.minimum((_ranks(around) * SECTORS) // len(t), SECTORS - 1)
    layer = np.minimum((_ranks(t) * LAYERS) // len(t), LAYERS - 1)
    return sector * LAYERS + layer


def _ranks(values: NDArray[np.float64]) -> NDArray[np.int64]:
    """Rank (K,) of each of ``values`` (K,) in ascending order, 0 .. K - 1."""
    ranks = np.empty(len(values), dtype=np.int64)
    ranks[np.argsort(values)] = np.arange(len(values))
    return ranks


def taper_estimate(points: NDArray[np.float64], model: ConeModel, lo: float, hi: float
                   ) -> tuple[float, float, int] | None:
    """Least-squares taper [m] of a side, its delete-a-block jackknife spread [m], its blocks.

    Parameters
    ----------
    points : (K, 3) float64 [m]
        The side's points.
    model : ConeModel
        The side's cone (RANSAC), apex and axis towards the base.
    lo, hi : float [m]
        The side's extent along the axis from the apex.

    Returns
    -------
    (taper, spread, blocks) or None
        ``taper = k (hi - lo)`` with the least-squares slope ``k`` (positive: widening
        towards the base); the jackknife estimate of its standard deviation over the side's
        G blocks (:func:`_blocks`), ``sqrt((G - 1) / G sum_g (k_(-g) - mean k_(-g))^2)``
        times ``hi - lo``, with ``k_(-g)`` the slope fitted without block g; and G, the
        blocks holding points. None when the side has too few points or blocks, or when
        leaving a block out leaves the side undetermined.
    """
    if len(points) < SECTORS * LAYERS * MIN_BLOCK_POINTS or hi <= lo:
        return None
    jac, res, t, angle = _design(points, model, (lo + hi) / 2.0)
    judged = _last_jackknifed(jac, res, _blocks(t, angle))
    if judged is None:
        return None
    step, spread, n_blocks = judged
    slope = math.tan(model.half_angle) + step
    return slope * (hi - lo), spread * (hi - lo), n_blocks


@dataclass(frozen=True)
class ProfileBow:
    """How far a round side's profile is from straight (:func:`profile_bow`).

    Attributes
    ----------
    bow : float [m]
        The least-squares profile's middle off the chord through its ends (positive:
        bulging, as a torus's or a barrel's side; negative: waisted).
    turn : float [rad]
        How far the profile's tangent turns between the side's two ends.
    ends : (2, 3) float64 [m]
        The points of the axis at the two ends of the side's points.
    radius : float [m]
        The straight profile's radius at the middle.
    """

    bow: float
    turn: float
    ends: NDArray[np.float64]
    radius: float


def _bow_design(points: NDArray[np.float64], model: ConeModel | CylinderModel
                ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                           NDArray[np.float64], float, float] | None:
    """Linearise the side with a curved profile: jacobian (K, 7), residuals, heights, angles.

    :func:`_design` with one column more, for ``c`` in ``rho = r + k t + c (t^2 - h^2 / 3)``
    (``t`` from the middle of the points' extent ``2 h`` along the axis; ``h^2 / 3`` is
    ``t^2``'s mean over an even spread of heights, so that the column stays apart from
    ``r``'s). Also returns ``h`` [m] and the middle's distance [m] from the model's origin
    (:func:`_profile`); None when the points span no height.
    """
    origin = _profile(model)[0]
    along = (points - origin) @ model.axis
    lo, hi = float(along.min()), float(along.max())
    if hi <= lo:
        return None
    mid, half = (lo + hi) / 2.0, (hi - lo) / 2.0
    jac, res, t, angle = _design(points, model, mid)
    return np.column_stack([jac, -(t * t - half * half / 3.0)]), res, t, angle, half, mid


def profile_bow(points: NDArray[np.float64], model: ConeModel | CylinderModel
                ) -> ProfileBow | None:
    """Measure the least-squares bow and turn of a round side's profile.

    ``points`` (K, 3) [m] are the side's points, ``model`` its cone or cylinder. The
    profile ``rho = r + k t + c t^2`` (:func:`_bow_design`, one least-squares step about
    the model) bows by ``-c h^2`` at its middle and its slope runs from ``k - 2 c h`` to
    ``k + 2 c h``: the turn is the difference of the two slopes' angles. Measured on every
    n-th point, at most PROFILE_SAMPLE of them. None when the points span no height or
    the fit is undetermined.
    """
    design = _bow_design(points[::max(1, -(-len(points) // PROFILE_SAMPLE))], model)
    if design is None:
        return None
    jac, res, _, _, half, mid = design
    step = np.linalg.lstsq(jac.T @ jac, -(jac.T @ res), rcond=None)[0]
    origin, slope, base = _profile(model)
    k, c = slope + float(step[5]), float(step[6])
    turn = abs(math.atan(k + 2.0 * c * half) - math.atan(k - 2.0 * c * half))
    ends = origin + np.outer([mid - half, mid + half], model.axis)
    return ProfileBow(-c * half * half, turn, ends, base + slope * mid)


def least_bow(points: NDArray[np.float64], model: ConeModel | CylinderModel
              ) -> tuple[float, float] | None:
    """Least-squares bow [m] of a side's profile and the least [m] a significant bow exceeds.

    The bow as in :func:`profile_bow`; its spread is the delete-a-block jackknife over the
    side's blocks (:func:`_blocks`) as the taper's, and the least significant bow the
    two-sided Student quantile at TAPER_LEVEL (blocks - 1 degrees of freedom) times it: a
    profile may bow either way. None when the side is not judged (too few points or
    blocks, as :func:`taper_estimate`).
    """
    if len(points) < SECTORS * LAYERS * MIN_BLOCK_POINTS:
        return None
    design = _bow_design(points, model)
    if design is None:
        return None
    jac, res, t, angle, half, _ = design
    judged = _last_jackknifed(jac, res, _blocks(t, angle))
    if judged is None:
        return None
    curvature, spread, n_blocks = judged
    quantile = float(stats.t.ppf(1.0 - TAPER_LEVEL / 2.0, n_blocks - 1))
    return -curvature * half * half, quantile * spread * half * half


def _last_jackknifed(jac: NDArray[np.float64], res: NDArray[np.float64],
                     block: NDArray[np.int64]) -> tuple[float, float, int] | None:
    """Least-squares step of the last parameter, its delete-a-block jackknife spread, blocks.

    ``jac`` (K, P), ``res`` (K,) [m], ``block`` (K,): the linearised fit of the side
    (:func:`_design`, possibly with more columns). Returns the whole side's least-squares
    step of parameter P - 1, ``sqrt((G - 1) / G sum_g (x_(-g) - mean x_(-g))^2)`` over the
    G blocks holding points, and G; None with fewer than MIN_BLOCKS blocks or when leaving
    a block out leaves the side undetermined.
    """
    n_par = jac.shape[1]
    sums = _block_sums(jac, res, block)
    if len(sums) < MIN_BLOCKS:
        return None
    normal = sums[:, :n_par * n_par].reshape(len(sums), n_par, n_par)
    rhs = sums[:, n_par * n_par:]
    # A block's deletion is the whole's normal equations minus its own. (The jackknife,
    # not the sandwich of the residuals: a block that pulls the fit leaves small residuals
    # of its own, and the sandwich misses it.)
    whole = np.linalg.lstsq(normal.sum(axis=0), rhs.sum(axis=0), rcond=None)[0]
    try:
        left = np.linalg.solve(normal.sum(axis=0) - normal,
                               (rhs.sum(axis=0) - rhs)[..., None])
    except np.linalg.LinAlgError:   # a block alone fixes the side: no spread to measure
        return None
    steps = left[:, n_par - 1, 0]
    n_blocks = len(sums)
    spread = math.sqrt((n_blocks - 1) / n_blocks * float(np.sum((steps - steps.mean()) ** 2)))
    return float(whole[n_par - 1]), spread, n_blocks


def _block_sums(jac: NDArray[np.float64], res: NDArray[np.float64], block: NDArray[np.int64]
                ) -> NDArray[np.float64]:
    """Per block holding points, the sums (G, P^2 + P) of ``J_i^T J_i`` and ``-J_i r_i``.

    ``jac`` (K, P), ``res`` (K,) [m], ``block`` (K,) in [0, SECTORS * LAYERS): the angle
    and height shares are equal, but a block of both may be empty (a flank seen only
    along part of the height).
    """
    terms = np.concatenate([(jac[:, :, None] * jac[:, None, :]).reshape(len(jac), -1),
                            -jac * res[:, None]], axis=1)
    order = np.argsort(block, kind="stable")
    # The first row of each block holding points, in the sorted order.
    _, starts = np.unique(block[order], return_index=True)
    return np.add.reduceat(terms[order], starts, axis=0)


def least_taper(points: NDArray[np.float64], model: ConeModel, lo: float, hi: float
                ) -> tuple[float, float] | None:
    """Least-squares taper [m] of a side and the least [m] a significant taper exceeds.

    The least taper is the one-sided Student quantile at TAPER_LEVEL (blocks - 1 degrees
    of freedom) times the taper's spread (:func:`taper_estimate`); None when the side is
    not judged (too few points).
    """
    est = taper_estimate(points, model, lo, hi)
    if est is None:
        return None
    taper, spread, n_blocks = est
    return taper, float(stats.t.ppf(1.0 - TAPER_LEVEL, n_blocks - 1)) * spread
