"""How much a frame's slow sensor errors taper a cylinder: the null of the frustum's taper.

A frustum differs from a cylinder by its taper, the difference of its two radii. The
side's own points say how surely they show it (:mod:`~.taper_spread`: the least-squares
taper against its spread over blocks of the side). A real depth camera adds a range
error that varies slowly across the image (``NoiseEstimate.scale`` 1.6-2.5 on real
frames); the part of it common to the whole side (one end nearer than the other) no block
structure shows. What the slow errors do to a cylinder is measured on the frame instead,
as the bend test's null is
(:mod:`~.slow_bend`): where the error along the rays at one end of the side differs from
the other end's by ``delta``, the front of one end's cross-section moves along the rays by
``delta`` more than the other's while the silhouette lines (grazing rays) do not move
across the axis; a circle held on the axis through such an arc changes its radius by at
most ``delta``: the apparent taper of a true cylinder. Its null is measured on patches of
the frame's largest support plane (flat, seen by the same sensor): pairs of discs as far
apart in the image as the side's two ends and as wide as its radius (in the image), whose
mean range errors (off the support's plane, along the rays) differ by ``delta``, scaled to
the object's range by sigma(z_object) / sigma(z_patch). The largest over the patches is
the bound (a Monte-Carlo test at level 1 / (patches + 1), as the bends').

The correlation length of the errors is fixed in pixels (the sensor's), so a pair of the
same angular size and spacing meets the same part of the error field whatever its range.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.fitting.slow_bend import (MIN_NULL_PATCHES, MIN_PATCH_POINTS, NULL_PATCHES,
                                                  NULL_SEED, SlowBendNull)

__all__ = ["MAX_END_OFFSET", "MIN_RAY_COS", "CANDIDATE_CENTRES", "slow_taper", "slow_bow"]

#: An end disc whose points' mean direction lies farther than this share of its angular
#: radius from its centre is cut by the support's border (a disc cut by a chord half its
#: radius from the centre, a fifth of it missing, moves its centroid by 0.17 of its radius,
#: a half disc by 0.42) and its pair is left out.
MAX_END_OFFSET = 0.25
#: Range errors are the support's residuals divided by the cosine between its normal and
#: the ray; rays more grazing than this cosine (78 deg) are divided by it instead (the
#: errors along them are not measured better than this).
MIN_RAY_COS = 0.2
#: Candidate centres of the pairs, drawn (fixed seed) from the support's sample; the first
#: NULL_PATCHES usable ones (both discs whole on the support) are measured. Pairs span
#: the side's height and reach farther than the bend's single discs: on a desk a few
#: times the object's height across, most random centres lie too near its border.
CANDIDATE_CENTRES = 8 * NULL_PATCHES


def _unit(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rows of ``v`` (..., 3) divided by their norms."""
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), np.finfo(float).tiny)


def _range_errors(null: SlowBendNull) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Directions (P, 3) of the support sample's points and their range errors (P,) [m].

    The error of each point is its distance from the support's least-squares plane
    (through the sample, normal ``null.normal`` refined), divided by the cosine of its ray
    with that normal (at least MIN_RAY_COS): the error along the ray.
    """
    p = null.points
    c = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - c, full_matrices=False)
    n = vt[2] if vt[2] @ null.normal >= 0.0 else -vt[2]
    u = _unit(p)
    cos = np.maximum(np.abs(u @ n), MIN_RAY_COS)
    return u, ((p - c) @ n) / cos


def _end_means(u: NDArray[np.float64], err: NDArray[np.float64], ends: NDArray[np.float64],
               width: float) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Mean range error [m] in discs of angular radius ``width`` about ``ends`` (E, 3).

    Returns the means (E,) and whether each disc is usable (MIN_PATCH_POINTS points or more,
    not cut by the support's border: :data:`MAX_END_OFFSET`).
    """
    inside = ((ends @ u.T) >= math.cos(width)).astype(np.float64)   # BLAS products below
    count = inside.sum(axis=1)
    safe = np.maximum(count, 1)
    mean = (inside @ err) / safe
    offset = np.linalg.norm((inside @ u) / safe[:, None] - ends, axis=1)
    return mean, (count >= MIN_PATCH_POINTS) & (offset <= MAX_END_OFFSET * width)


def slow_taper(null: SlowBendNull, end_a: NDArray[np.float64], end_b: NDArray[np.float64],
               radius: float) -> float:
    """Largest apparent taper [m] the frame's slow errors give a cylinder like this one.

    Parameters
    ----------
    null : SlowBendNull
        The frame's support sample (sensor at the origin) and its noise.
    end_a, end_b : (3,) float64 [m]
        The centres of the side's two ends (points of its axis).
    radius : float [m]
        The side's mean radius: the end discs' radius at the object's range.

    Returns
    -------
    float
        The largest difference of mean range error between the two end discs of the
        support's pairs (as far apart in the image as ``end_a`` and ``end_b``, centred on
        points of the support: :data:`CANDIDATE_CENTRES`), scaled to the object's range
        by the ratio of sigma(z); infinite when fewer than MIN_NULL_PATCHES pairs are
        usable (nothing is known of the errors: no taper is beyond them).
    """
    return _slow_contrast(null, end_a, end_b, radius, _TAPER_WEIGHTS)


def slow_bow(null: SlowBendNull, end_a: NDArray[np.float64], end_b: NDArray[np.float64],
             radius: float) -> float:
    """Largest apparent bow [m] the frame's slow errors give a straight profile like this one.

    As :func:`slow_taper`, with three discs per pair (the two ends' and the middle's): the
    bow is the middle disc's mean range error off the mean of the two ends' (a circle held
    on the axis through the middle's arc changes its radius by at most that much, the
    profile's middle leaves the chord through its ends by as much).
    """
    return _slow_contrast(null, end_a, end_b, radius, _BOW_WEIGHTS)


#: Weights of the mean range errors of the discs at the first end, the middle and the
#: second end: the taper is the ends' difference, the bow the middle off the ends' mean.
_TAPER_WEIGHTS = (1.0, 0.0, -1.0)
_BOW_WEIGHTS = (-0.5, 1.0, -0.5)


def _slow_contrast(null: SlowBendNull, end_a: NDArray[np.float64], end_b: NDArray[np.float64],
                   radius: float, weights: tuple[float, float, float]) -> float:
    """Largest weighted sum [m] of three discs' mean range errors over the support's pairs.

    Discs of angular radius ``radius`` over the range at ``end_a``, the middle and
    ``end_b``'s positions in the image relative to each candidate centre; discs of zero
    weight are not measured. Scaled to the object's range by sigma(z); infinite with
    fewer than MIN_NULL_PATCHES usable pairs.
    """
    depth = float(np.linalg.norm((end_a + end_b) / 2.0))
    if radius <= 0.0 or depth <= 0.0:
        return math.inf
    half = (_unit(np.asarray(end_b, float)) - _unit(np.asarray(end_a, float))) / 2.0
    pick = np.random.default_rng(NULL_SEED).permutation(len(null.points))[:CANDIDATE_CENTRES]
    u, err = _range_errors(null)
    at, delta = [], []
    # Chunks of NULL_PATCHES candidates until as many pairs are usable: a (chunk, P) matrix
    # at a time, and usually one or two chunks.
    for start in range(0, len(pick), NULL_PATCHES):
        centres = null.points[pick[start:start + NULL_PATCHES]]
        total = np.zeros(len(centres))
        ok = np.ones(len(centres), dtype=bool)
        for shift, weight in zip((-1.0, 0.0, 1.0), weights):
            if weight == 0.0:
                continue
            mean, usable = _end_means(u, err, _unit(_unit(centres) + shift * half),
                                      radius / depth)
            total += weight * mean
            ok &= usable
        at.extend(np.linalg.norm(centres[ok], axis=1))
        delta.extend(np.abs(total[ok]))
        if len(delta) >= NULL_PATCHES:
            break
    if len(delta) < MIN_NULL_PATCHES:
        return math.inf
    at, delta = np.array(at[:NULL_PATCHES]), np.array(delta[:NULL_PATCHES])
    sigma_at = np.maximum(null.noise.sigma(at), np.finfo(float).tiny)
    return float(np.max(delta * null.noise.sigma(depth) / sigma_at))
