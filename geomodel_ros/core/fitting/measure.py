"""Robust measurements on an object's points that verification and sizing share."""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.geometry import frame_with_z
from geomodel_ros.core.noise import MIN_INCIDENCE_COS

__all__ = ["STATS_SAMPLE", "every_kth", "bulk_extent", "side_bulk", "bulk_reach", "arc_span",
           "steep_arc_span", "without_strays", "nearest_surface", "rms", "ray_incidence",
           "noise_scatter_ratio", "scatter_incidence", "MAD_TO_SIGMA", "SCATTER_SAMPLE"]

#: Percentile statistics over an object's points (bulk reach, strays, support test,
#: degeneracy) use every k-th point, k chosen so that about this many remain: a robust
#: percentile needs a few thousand samples, not the hundreds of thousands a near object
#: has.
STATS_SAMPLE = 5000
#: The arc a curved side spans is measured on about this many of its points: enough that
#: no real gap between them is missed.
ARC_SAMPLE = 20000
#: Fewest points for which an arc around an axis is measured (fewer span none).
MIN_ARC_POINTS = 3
#: The bulk of an object along an axis lies between these percentiles of its projections.
BULK_PERCENTILES = (2.0, 98.0)
#: The bulk of an object round an axis lies within this percentile of its distances.
REACH_PERCENTILE = 98.0

#: Sizing ignores projections farther than STRAY_PAD times the bulk's extent plus
#: STRAY_MARGIN [m] beyond the bulk (STRAY_PERCENTILES) of an object's points. A side
#: must hold more than about 2 % of the points not to be cut (a box seen almost face on
#: whose sides hold less would come out too thin along the view: the cuboid sizing
#: therefore also judges each side face on its own points, ``cuboid._kept_values``).
STRAY_PAD = 0.25
STRAY_MARGIN = 0.01
STRAY_PERCENTILES = (1.0, 99.0)
#: ... and groups of at most STRAY_GROUP_SHARE of the points beyond an empty gap of
#: STRAY_GAP [m] at either end (an occluded object's parts are larger).
STRAY_GROUP_SHARE = 0.05
STRAY_GAP = 0.03


def every_kth(values: NDArray, target: int = STATS_SAMPLE) -> NDArray:
    """Every k-th row of ``values``, k = len // ``target`` (at least 1)."""
    return values[:: max(1, len(values) // target)]


def bulk_extent(points: NDArray[np.float64], axis: NDArray[np.float64]) -> float:
    """Extent [m] of the bulk (BULK_PERCENTILES) of ``points`` (N, 3) along unit ``axis``."""
    lo, hi = np.percentile(points @ axis, list(BULK_PERCENTILES))
    return float(hi - lo)


def side_bulk(points: NDArray[np.float64], side_points: NDArray[np.float64],
              axis: NDArray[np.float64]) -> float:
    """Bulk extent [m] along unit ``axis`` of an object's ``points`` or of its side's, the longer.

    A round body's length is checked against it (:func:`~.verify.check_bulk_length`). A
    flat end seen whole may hold most of the object's points at one place along the axis
    (a tall can's lid seen from above: 94 % of its points), and the bulk of all points is
    then the lid's few millimetres while the side's points (n, 3) run the can's length;
    a few strays on the side's extended surface stay outside the bulk of either.
    """
    bulk = bulk_extent(points, axis)
    return max(bulk, bulk_extent(side_points, axis)) if len(side_points) else bulk


def bulk_reach(points: NDArray[np.float64], origin: NDArray[np.float64],
               axis: NDArray[np.float64]) -> float:
    """Return the distance [m] from an axis line within which the bulk of ``points`` lie.

    The line passes through ``origin`` (3,) along unit ``axis`` (3,); the bulk is the
    REACH_PERCENTILE of the distances of ``points`` (N, 3).
    """
    v = every_kth(points) - origin
    radial = v - np.outer(v @ axis, axis)
    return float(np.percentile(np.sqrt(np.einsum("ij,ij->i", radial, radial)),
                               REACH_PERCENTILE))


def arc_span(points: NDArray[np.float64], origin: NDArray[np.float64],
             axis: NDArray[np.float64]) -> float:
    """Angle [rad] that ``points`` (N, 3) span around an axis (2 pi minus the largest gap)."""
    if len(points) < MIN_ARC_POINTS:
        return 0.0
    frame = frame_with_z(axis)
    v = every_kth(points, ARC_SAMPLE) - origin
    ang = np.sort(np.arctan2(v @ frame[:, 1], v @ frame[:, 0]))
    gaps = np.diff(np.r_[ang, ang[0] + 2.0 * math.pi])
    return float(2.0 * math.pi - gaps.max())


def _without_small_end_groups(vals: NDArray[np.float64]) -> NDArray[np.float64]:
    """``vals`` without groups of at most STRAY_GROUP_SHARE of them beyond a STRAY_GAP gap."""
    # Flying pixels between an edge and the far background come in such clusters, a few
    # per cent of a small box's points.
    n, k = len(vals), int(STRAY_GROUP_SHARE * len(vals))
    if k < 1:
        return vals
    # Only the k + 1 smallest and largest values matter: sorted after a partition, they
    # are the ends of the sorted values (a full sort costs several times more).
    split = np.partition(vals, [k, n - 1 - k])
    bottom, top = np.sort(split[:k + 1]), np.sort(split[n - 1 - k:])
    low = np.flatnonzero(np.diff(bottom) > STRAY_GAP)
    high = np.flatnonzero(np.diff(top) > STRAY_GAP)
    if not low.size and not high.size:
        return vals
    lo = bottom[low[-1] + 1] if low.size else bottom[0]
    hi = top[high[0]] if high.size else top[-1]
    return vals[(vals >= lo) & (vals <= hi)]


def without_strays(vals: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return ``vals`` (n,) [m], one axis's projections of an object, without strays.

    Strays lie beyond the bulk by more than STRAY_PAD, STRAY_MARGIN or form small groups
    beyond a gap. On depth images these are flying pixels along the viewing rays past
    an edge, which lie close to the extension of a side face seen at a grazing angle
    and would stretch the box. ``vals`` itself is returned when nothing is dropped.
    """
    lo, hi = np.percentile(every_kth(vals), list(STRAY_PERCENTILES))
    pad = STRAY_PAD * (hi - lo) + STRAY_MARGIN
    keep = (vals >= lo - pad) & (vals <= hi + pad)
    vals = vals if keep.all() else vals[keep]
    return _without_small_end_groups(vals)


def nearest_surface(dists: list[NDArray[np.float64]]
                    ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Index of the smallest of several per-point distance arrays (n,), and that distance.

    Ties go to the first; no (n, k) array is stacked.
    """
    best = dists[0].copy()
    which = np.zeros(len(best), dtype=np.int64)
    for i, d in enumerate(dists[1:], start=1):
        closer = d < best
        which[closer] = i
        np.minimum(best, d, out=best)
    return which, best


def rms(d: NDArray[np.float64]) -> float:
    """Root mean square of distances ``d`` (n,) [m]; 0 for none."""
    return float(np.sqrt(np.mean(d * d))) if d.size else 0.0


#: 1.4826 median absolute deviation is the standard deviation of a Gaussian.
MAD_TO_SIGMA = 1.4826
#: The scatter of a fitted surface's points is measured on about this many of them (a
#: median of 2000 has a relative standard error of about 3 %).
SCATTER_SAMPLE = 2000
#: The scatter is judged only when at least this share of the points measured are seen
#: steeply enough (MIN_INCIDENCE_COS): a side seen only at grazing incidence (a can from
#: 70 deg or more above the desk) has its few steep points on the rounded rim of its lid,
#: which do not sample the side (kinect-real clutter seed 20: 2 % of a can's side points,
#: 3.2 times the noise about a cylinder within 0.7 mm of the can's). Shares from 0.05 to
#: 0.2 judge the same (BENCHMARKS.md section 47).
MIN_STEEP_SHARE = 0.1
#: Step [m] of the central differences that give a fitted surface's normal from its
#: distance function (far below any radius the units accept, far above rounding).
NORMAL_STEP = 1e-5


def ray_incidence(distance: Callable[[NDArray[np.float64]], NDArray[np.float64]],
                  points: NDArray[np.float64]) -> NDArray[np.float64]:
    """|cos| of the angle between each point's viewing ray and the surface normal there.

    ``distance`` is a fitted surface's signed distance function (n, 3) -> (n,); its
    gradient (central differences) is the normal. The sensor is at the origin: depth
    noise along the ray moves a point off the surface by |cos| times the noise.

    Parameters
    ----------
    distance : callable
    points : (n, 3) float64 array [m]

    Returns
    -------
    (n,) float64 array in [0, 1]
    """
    grad = np.empty_like(points)
    for i in range(3):
        step = np.zeros(3)
        step[i] = NORMAL_STEP
        grad[:, i] = distance(points + step) - distance(points - step)
    norm = np.linalg.norm(grad, axis=1) * np.linalg.norm(points, axis=1)
    cos = np.abs(np.einsum("ij,ij->i", grad, points)) / np.maximum(norm, np.finfo(float).tiny)
    return np.minimum(cos, 1.0)


def steep_arc_span(points: NDArray[np.float64], origin: NDArray[np.float64],
                   axis: NDArray[np.float64],
                   distance: Callable[[NDArray[np.float64]], NDArray[np.float64]],
                   incidence: NDArray[np.float64] | None = None) -> float:
    """Angle [rad] around an axis spanned by the ``points`` seen steeply enough to judge.

    :func:`arc_span` of those of ``points`` (N, 3) [m] (about SCATTER_SAMPLE of them, as
    the scatter test's: the incidence costs six evaluations of the model's distance per
    point, 9 ms on a 15k-point side at ARC_SAMPLE; a sparser sample only widens gaps, and
    the smallest arcs of the sides verified on the suite and osd_learn -- the torus's 42
    deg, then 76 and 86 deg -- are ARC_SAMPLE's within 0.5 deg, measured) whose viewing
    rays meet the fitted surface (signed ``distance`` (n, 3) -> (n,) [m]) within
    acos(MIN_INCIDENCE_COS) of its normal (:func:`ray_incidence`), the axis through
    ``origin`` (3,) along unit ``axis`` (3,). Depth noise of sigma along a ray moves a
    point off the surface by only sigma times the cosine: where the rays graze the model
    (towards its silhouette) the inlier band along them is long, and points of another
    surface lie in it -- a torus's lower outer wall within a wide cylinder's band through
    its two tubes, which widens the arc its points span from 42 to 59 deg. The scatter
    test leaves the same points out (:func:`noise_scatter_ratio`). ``incidence``: the
    :func:`ray_incidence` of those points when already known (:func:`scatter_incidence`).
    """
    sub = every_kth(points, SCATTER_SAMPLE)
    cos = ray_incidence(distance, sub) if incidence is None else incidence
    return arc_span(sub[cos >= MIN_INCIDENCE_COS], origin, axis)


def scatter_incidence(distance: Callable[[NDArray[np.float64]], NDArray[np.float64]],
                      points: NDArray[np.float64]) -> NDArray[np.float64]:
    """:func:`ray_incidence` of the sample of ``points`` (n, 3) [m] the scatter tests use.

    The same sample (about SCATTER_SAMPLE of them) for :func:`steep_arc_span` and
    :func:`noise_scatter_ratio`, which take it instead of computing it again.
    """
    return ray_incidence(distance, every_kth(points, SCATTER_SAMPLE))


def noise_scatter_ratio(distance: Callable[[NDArray[np.float64]], NDArray[np.float64]],
                        points: NDArray[np.float64], sigma: float,
                        incidence: NDArray[np.float64] | None = None) -> float:
    """Robust scatter of ``points`` about a fitted surface along the rays, over ``sigma``.

    Depth noise of sigma along the rays moves a point off the surface by sigma times its
    :func:`ray_incidence`; each distance divided by the incidence is the point's offset
    along its ray, and 1.4826 times their median absolute value (robust to the minority
    of points a model does not describe: a rim, an undetected cap) estimates the noise
    sigma the model leaves. About 1 for the right model; a wrong model adds its
    systematic misfit. Points seen at more than acos(MIN_INCIDENCE_COS) from the
    surface's normal (near a silhouette) are left out: the division would magnify their
    errors; when fewer than MIN_STEEP_SHARE of them are left, nothing is judged.

    Parameters
    ----------
    distance : callable, the surface's signed distance (n, 3) -> (n,) [m]
    points : (n, 3) float64 array [m], the points on the surface (about SCATTER_SAMPLE used)
    sigma : float [m], depth noise along the rays at the object's range (> 0)
    incidence : (m,) float64 array, optional
        :func:`scatter_incidence` of ``distance`` and ``points`` when already known.

    Returns
    -------
    float (0 when too few points are seen steeply enough)
    """
    sub = every_kth(points, SCATTER_SAMPLE)
    cos = ray_incidence(distance, sub) if incidence is None else incidence
    steep = cos >= MIN_INCIDENCE_COS
    if not steep.any() or np.count_nonzero(steep) < MIN_STEEP_SHARE * len(steep):
        return 0.0
    along = np.abs(distance(sub[steep])) / cos[steep]
    return MAD_TO_SIGMA * float(np.median(along)) / sigma
