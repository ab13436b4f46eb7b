"""Per-object confidence: how well the fitted shape explains the object's points.

Three terms, each measured on the object's points against the fitted surface (the
primitive's own solid: bounded box, capped cylinder, cone with its base, sphere, plane),
and one value a planner can threshold::

    confidence = inlier_ratio * 1 / (1 + rmse_ratio**2) * min(1, coverage / VIEW_COVERAGE)

* ``inlier_ratio`` in [0, 1]: share of the points within the noise scale of the surface;
* ``rmse_ratio`` >= 0: the RMS distance of the points near the surface (within
  OUTLIER_FACTOR noise scales, the band the fitting units size from; farther points are
  outliers, which the inlier ratio counts) divided by the noise scale (1 / (1 + x^2): 1
  for a perfect fit, 1/2 when the RMS error equals the noise scale);
* ``coverage`` in [0, 1], round shapes only (the factor is 1 for planes and cuboids):
  cylinder and cone, the share of the full circle round the axis that the side's points
  span (:func:`~geomodel_ros.core.fitting.measure.arc_span`); sphere, the share of its
  directions (solid angle) the points cover, as the spherical cap round their mean
  direction. One viewpoint sees at most half of a round shape (VIEW_COVERAGE), which
  then counts as fully covered.

The value is monotone in each term (higher inlier ratio, lower rmse ratio, wider
coverage: never lower) and lies in [0, 1]; ``unknown`` objects get 0. The noise scale is
one argument (today the RANSAC inlier threshold; a per-frame noise estimate can be
passed instead).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.fitting.measure import arc_span, every_kth
from geomodel_ros.core.fitting.verify import OUTLIER_FACTOR
from geomodel_ros.core.primitives import Confidence, Primitive, PrimitiveType

__all__ = ["VIEW_COVERAGE", "CONFIDENCE_SAMPLE", "UNKNOWN_CONFIDENCE", "surface_distance",
           "round_outline", "surface_normals", "coverage", "confidence_value",
           "estimate_confidence", "with_confidence"]

#: One viewpoint sees at most half of a cylinder's circumference or of a sphere's surface:
#: that coverage counts as complete.
VIEW_COVERAGE = 0.5
#: The terms are measured on every k-th point, about this many (a share and an RMS need
#: no more: the standard error of a share from 2000 samples is at most 1.1 %; below a
#: few thousand points numpy's per-call overhead, not their number, sets the time).
CONFIDENCE_SAMPLE = 2000
#: The sphere's cap is bounded by this percentile of the points' angles from their mean
#: direction (a few stray points do not widen it).
CAP_PERCENTILE = 98.0
#: Confidence of an object no shape was fitted to.
UNKNOWN_CONFIDENCE = Confidence()

_TINY = np.finfo(float).tiny


def _segment_distance(rho: NDArray[np.float64], z: NDArray[np.float64],
                      a: tuple[float, float], b: tuple[float, float]) -> NDArray[np.float64]:
    """Distance [m] of the points (rho, z) (n,) to the segment a -> b in the (rho, z) plane."""
    dr, dz = b[0] - a[0], b[1] - a[1]
    t = np.clip(((rho - a[0]) * dr + (z - a[1]) * dz) / max(dr * dr + dz * dz, _TINY), 0.0, 1.0)
    return np.hypot(rho - a[0] - t * dr, z - a[1] - t * dz)


def _profile(p: Primitive) -> list[tuple[float, float]] | None:
    """Outline (rho, z) [m] of a solid of revolution about its z axis, centred at z = 0."""
    d, kind = p.dimensions, str(p.type)
    h = d.get("height", 0.0) / 2
    if kind == "cylinder":
        r = d["radius"]
        return [(0.0, -h), (r, -h), (r, h), (0.0, h)]
    if kind == "cone":  # base at -h, apex at +h (rotation z: base -> apex)
        return [(0.0, -h), (d["radius"], -h), (0.0, h)]
    if kind == "frustum":  # base circle at -h, top circle at +h (rotation z: base -> top)
        return [(0.0, -h), (d["radius"], -h), (d["top_radius"], h), (0.0, h)]
    return None


def round_outline(p: Primitive
                  ) -> tuple[float, Callable[[NDArray[np.float64]], NDArray[np.float64]],
                             float] | None:
    """Return the outline of a solid of revolution about its z axis; None for other types.

    As (half height [m], radius [m] at heights z (n,) [m] with |z| <= half height, largest
    radius [m]).
    """
    profile = _profile(p)
    if profile is None:
        return None
    (_, low), (r_low, _), (r_high, high) = profile[0], profile[1], profile[2]

    def radius_at(z: NDArray[np.float64]) -> NDArray[np.float64]:
        return r_low + (r_high - r_low) * (z - low) / max(high - low, _TINY)

    return high, radius_at, max(r_low, r_high)


def _profile_distances(p: Primitive, local: NDArray[np.float64]
                       ) -> NDArray[np.float64] | None:
    """Distance [m] (k, n) of points in the primitive's frame (n, 3) to each outline segment.

    Segment 1 is the round side (the outline runs bottom centre, bottom rim, top rim or
    apex, top centre). None for types that are no solid of revolution.
    """
    profile = _profile(p)
    if profile is None:
        return None
    rho, z = np.hypot(local[:, 0], local[:, 1]), local[:, 2]
    return np.array([_segment_distance(rho, z, a, b) for a, b in zip(profile, profile[1:])])


def _measure(p: Primitive, points: NDArray[np.float64], noise: float | None
             ) -> tuple[NDArray[np.float64] | None, float | None]:
    """Distances [m] (n,) of ``points`` (n, 3) to the surface, and the coverage if asked.

    The coverage (see :func:`coverage`) is measured only when ``noise`` [m] is given; both
    come from the same intermediate distances.
    """
    kind = str(p.type)
    if kind == "sphere":
        v = points - p.center
        dist = np.abs(np.sqrt(np.einsum("ij,ij->i", v, v)) - p.dimensions["radius"])
        return dist, None if noise is None else _cap_share(v[dist <= noise])
    local = (points - p.center) @ p.rotation
    if kind == "plane":
        return np.abs(local[:, 2]), None
    if kind == "cuboid":
        half = 0.5 * np.array([p.dimensions[k] for k in ("length", "width", "height")])
        q = np.abs(local) - half
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
        return np.abs(outside + np.minimum(q.max(axis=1), 0.0)), None
    per_segment = _profile_distances(p, local)
    if per_segment is None:
        return None, None
    dist = per_segment.min(axis=0)
    if noise is None:
        return dist, None
    side = (per_segment[1] == dist) & (dist <= noise)
    return dist, arc_span(points[side], p.center, p.rotation[:, 2]) / (2.0 * math.pi)


def surface_distance(p: Primitive, points: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """Distance [m] (n,) of ``points`` (n, 3) [m] to the surface of the fitted primitive.

    Plane: to its (unbounded) plane; cuboid: to the box's faces; cylinder, cone (and
    frustum): to the capped solid's outline; sphere: to the sphere. None for ``unknown``
    or a type without a surface.
    """
    return _measure(p, points, None)[0]


def surface_normals(p: Primitive, points: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """Return the unit normal (n, 3) of the fitted surface nearest to each of ``points``.

    Up to sign (compare with ``abs`` of dot products). Plane: its normal; cuboid: the
    normal of the face the point lies farthest out of (or least deep inside); cylinder,
    cone, frustum: the normal of the nearest outline segment (a cap's is the axis, the
    side's turns with the point's azimuth about the axis); sphere: radial. None for
    ``unknown`` or a type without a surface.
    """
    kind = str(p.type)
    if kind == "sphere":
        v = points - p.center
        return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), _TINY)
    rot = p.rotation
    if kind == "plane":
        return np.broadcast_to(rot[:, 2], points.shape).copy()
    local = (points - p.center) @ rot
    if kind == "cuboid":
        half = 0.5 * np.array([p.dimensions[k] for k in ("length", "width", "height")])
        return rot.T[np.argmax(np.abs(local) - half, axis=1)]
    per_segment = _profile_distances(p, local)
    profile = _profile(p)
    if per_segment is None or profile is None:
        return None
    # Each outline segment's normal in the (rho, z) plane: its direction turned by 90 deg.
    seg = np.diff(np.array(profile), axis=0)
    seg_n = np.c_[seg[:, 1], -seg[:, 0]] / np.maximum(np.linalg.norm(seg, axis=1), _TINY)[:, None]
    n_rho, n_z = seg_n[np.argmin(per_segment, axis=0)].T
    rho = np.hypot(local[:, 0], local[:, 1])
    radial = local[:, :2] / np.maximum(rho, _TINY)[:, None]
    return np.c_[n_rho[:, None] * radial, n_z] @ rot.T


def coverage(p: Primitive, points: NDArray[np.float64], noise: float) -> float | None:
    """Share [0, 1] of a round primitive's directions that ``points`` (n, 3) [m] cover.

    Cylinder, cone, frustum: the arc that the points on the round side (nearest to it,
    within ``noise`` [m]) span round the axis, over 2 pi (caps are left out: a lid covers
    every direction). Sphere: the solid angle of the cap round the mean direction of its
    points within ``noise``, bounded by the CAP_PERCENTILE of their angles theta from it,
    over 4 pi: ``(1 - cos theta) / 2``. None for other types.
    """
    return _measure(p, points, noise)[1]


def _cap_share(v: NDArray[np.float64]) -> float:
    """Share of the sphere the directions ``v`` (n, 3) from its centre cover (a cap)."""
    if len(v) == 0:
        return 0.0
    v = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), _TINY)
    mean = v.sum(axis=0)
    norm = float(np.linalg.norm(mean))
    if norm <= _TINY:
        return 1.0
    theta = float(np.percentile(np.arccos(np.clip(v @ (mean / norm), -1.0, 1.0)),
                                CAP_PERCENTILE))
    return (1.0 - math.cos(theta)) / 2.0


def confidence_value(inlier_ratio: float, rmse_ratio: float, cover: float | None) -> float:
    """Combine the terms into the confidence in [0, 1] (formula in the module docstring)."""
    fit = 1.0 / (1.0 + rmse_ratio * rmse_ratio)
    seen = 1.0 if cover is None else min(1.0, cover / VIEW_COVERAGE)
    return float(min(1.0, max(0.0, inlier_ratio)) * fit * max(0.0, seen))


def estimate_confidence(p: Primitive, points: NDArray[np.float64], noise: float) -> Confidence:
    """Confidence of the primitive ``p`` fitted to its object's ``points`` (n, 3) [m].

    Parameters
    ----------
    p : Primitive
    points : (n, 3) float64 [m]
        The object's points (every k-th of about CONFIDENCE_SAMPLE is used).
    noise : float [m]
        Noise scale: distances within it count as inliers, and the RMS distance is
        measured in it. Must be > 0.

    Returns
    -------
    Confidence; UNKNOWN_CONFIDENCE (0) for ``unknown``, no points or no surface.
    """
    if noise <= 0 or not math.isfinite(noise):
        raise ValueError(f"noise scale must be a finite number > 0 [m], got {noise!r}")
    sub = np.ascontiguousarray(every_kth(points, CONFIDENCE_SAMPLE))
    if not len(sub) or p.type == PrimitiveType.UNKNOWN:
        return UNKNOWN_CONFIDENCE
    dist, cover = _measure(p, sub, noise)
    if dist is None:
        return UNKNOWN_CONFIDENCE
    inliers = float(np.mean(dist <= noise))
    near = dist[dist <= OUTLIER_FACTOR * noise]
    rmse_ratio = float(np.sqrt(np.mean(near * near))) / noise if len(near) else math.inf
    return Confidence(confidence_value(inliers, rmse_ratio, cover), inliers, rmse_ratio, cover)


def with_confidence(p: Primitive, points: NDArray[np.float64], noise: float) -> Primitive:
    """Return ``p`` with its :func:`estimate_confidence` set."""
    return dataclasses.replace(p, confidence=estimate_confidence(p, points, noise))
