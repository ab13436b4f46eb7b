"""Surface type of a face (paper section 3.1) and principal curvatures.

A face is planar or curved by its multi-scale covariance feature CF:

* spherical neighbourhoods centred at the face centre (the face point nearest the face
  centroid), three radii uniformly spaced up to a fraction of the face's minimum width;
* per neighbourhood the covariance eigenvalues l1 >= l2 >= l3 give
  P = (sqrt l2 - sqrt l3) / sqrt l1 (eq. 1), C = sqrt l3 / (sqrt l1 + sqrt l2 + sqrt l3)
  (eq. 2), b = (1 - C)^2 (eq. 3) and cf = P * b (eq. 4);
* CF = sum w_i cf_i (eq. 5) with w = (e^-t, 1 - e^-t, 2 (1 - e^-t)) (eq. 6), t the noise
  amplitude. The face is planar iff CF / sum(w) > CF_th (dividing by the weight sum keeps
  CF in [0, 1] whatever t is).

With t -> 0 only the smallest neighbourhood counts, where gently curved faces look flat;
the pipeline therefore verifies every face's type with a plane fit (paper 3.2: a fit that
fails rejects the type).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from scipy.special import fdtri

from geomodel_ros.core.geometry import perpendicular_basis, perpendicular_bases

__all__ = ["FaceFeature", "FaceBend", "covariance_features", "face_feature", "face_bend",
           "patch_bends", "principal_curvatures", "MIN_NEIGHBOURHOOD_POINTS", "BEND_SIGNIFICANCE",
           "BEND_EXTENT_PERCENTILES"]

#: A neighbourhood needs this many points for its cf (fewer: NaN, and its weight is left
#: out of the normalisation): the covariance of 3 or 4 points is planar or degenerate
#: whatever the surface.
MIN_NEIGHBOURHOOD_POINTS = 5
#: The face's principal axes (for its minimum width) are estimated from at most about
#: this many points (every k-th point): plenty for three axes, and the SVD of large
#: faces stays cheap.
_WIDTH_SAMPLE_POINTS = 20000
#: The three CF radii are uniformly spaced up to the largest (paper section 3.1): these
#: multiples of the largest radius / 3.
_RADIUS_STEPS = np.array([1.0, 2.0, 3.0])
#: Ridge added to the quadric normal equations (in scaled units, where the design
#: matrix entries are of order 1): keeps neighbourhoods with repeated points solvable
#: without changing well-posed fits measurably.
_QUADRIC_RIDGE = 1e-9
#: Significance level of the bend test (:func:`face_bend`): a plane leaves a systematic
#: bend (the quadric terms' reduction of the residual) this unlikely by chance under
#: independent noise only where the face is bent. 1e-3 keeps chance "bends" of truly
#: flat faces to one in a thousand while a real bend of a few noise sigmas over a few
#: hundred points lies many orders of magnitude beyond it.
BEND_SIGNIFICANCE = 1e-3
#: The face's width along its direction of strongest bending is taken between these
#: percentiles of its points (a few strays do not widen it).
BEND_EXTENT_PERCENTILES = (2.0, 98.0)
#: Parameters of a quadric height field h = a x^2 + b x y + c y^2 + d x + e y + f and of
#: the plane h = d x + e y + f it extends.
_QUADRIC_TERMS = 6
_PLANE_TERMS = 3
#: A face whose heights over its plane stay within this share of its lateral spread is
#: flat to rounding (an exact plane): the F ratio of two rounding-level residuals says
#: nothing, and the face is not bent.
_FLAT_TO_ROUNDING = 1e-9


def covariance_features(points: NDArray[np.float64], mass: NDArray[np.float64] | None = None
                        ) -> tuple[float, float, float]:
    """Planarity P (eq. 1), curvature C (eq. 2) and cf = P * (1 - C)^2 (eqs. 3-4).

    Parameters
    ----------
    points : (n, 3) float64 array [m], n >= 3
    mass : (n,) float64 array, optional
        Weight of each point (e.g. input points a voxel centroid stands for).

    Returns
    -------
    (P, C, cf) : floats in [0, 1]
    """
    w = np.ones(len(points)) if mass is None else np.asarray(mass, dtype=np.float64)
    mean = w @ points / w.sum()
    centered = points - mean
    cov = (centered * w[:, None]).T @ centered / w.sum()
    evals = np.linalg.eigvalsh(cov)[::-1]
    s = np.sqrt(np.clip(evals, 0.0, None))
    if s[0] <= 0:
        return 0.0, 0.0, 0.0
    planarity = (s[1] - s[2]) / s[0]
    curvature = s[2] / s.sum()
    return float(planarity), float(curvature), float(planarity * (1.0 - curvature) ** 2)


@dataclass(frozen=True)
class FaceFeature:
    """Multi-scale feature of one face.

    Attributes
    ----------
    center : (3,) float64 [m]
        Face point nearest the centroid (the neighbourhood centre).
    min_width : float [m]
        Extent of the face along its second principal axis.
    radii : (3,) float64 [m]
    cf : (3,) float64
        cf_i per radius (NaN where the neighbourhood had fewer than
        :data:`MIN_NEIGHBOURHOOD_POINTS` points).
    cf_total : float
        Normalised CF = sum w_i cf_i / sum w_i over the valid radii.
    planar : bool
        cf_total > CF_th.
    """

    center: NDArray[np.float64]
    min_width: float
    radii: NDArray[np.float64]
    cf: NDArray[np.float64]
    cf_total: float
    planar: bool


def face_feature(points: NDArray[np.float64], weights: tuple[float, float, float],
                 cf_threshold: float, radius_fraction: float,
                 mass: NDArray[np.float64] | None = None) -> FaceFeature:
    """Classify one face as planar or curved (paper eqs. 1-6).

    Parameters
    ----------
    points : (n, 3) float64 array [m]
        Points of the face (all input points, or voxel centroids with ``mass``).
    weights : (w1, w2, w3)
        Eq. 6 weights for the smallest to the largest radius.
    cf_threshold : float
        CF_th in [0, 1] (applied to the normalised CF).
    radius_fraction : float
        Largest radius as a fraction of the face's minimum width.
    mass : (n,) float64 array, optional
        Input points each of ``points`` stands for; covariances are weighted by it so that
        voxel centroids give the covariance of the full-resolution face.
    """
    w_pts = np.ones(len(points)) if mass is None else np.asarray(mass, dtype=np.float64)
    centroid = w_pts @ points / w_pts.sum()
    centered = points - centroid
    d2c = np.einsum("ij,ij->i", centered, centered)
    center = points[int(np.argmin(d2c))]
    sample = centered[:: max(1, len(points) // _WIDTH_SAMPLE_POINTS)]
    if len(sample) < 2:  # a single point has no second direction: no width
        min_width = 0.0
    else:
        _, _, vt = np.linalg.svd(sample, full_matrices=False)
        proj = centered @ vt[1]
        min_width = float(proj.max() - proj.min())
    radii = min_width * radius_fraction * _RADIUS_STEPS / len(_RADIUS_STEPS)
    dist2 = np.einsum("ij,ij->i", points - center, points - center)
    cf = np.full(3, np.nan)
    for i, r in enumerate(radii):
        inside = dist2 <= r * r
        if inside.sum() >= MIN_NEIGHBOURHOOD_POINTS:
            cf[i] = covariance_features(points[inside], w_pts[inside])[2]
    w = np.asarray(weights, dtype=np.float64)
    valid = np.isfinite(cf) & (w > 0)
    if not valid.any():
        total = 0.0
    else:
        total = float(np.sum(w[valid] * cf[valid]) / np.sum(w[valid]))
    return FaceFeature(center, min_width, radii, cf, total, total > cf_threshold)


@dataclass(frozen=True)
class FaceBend:
    """How a face bends away from its plane (:func:`face_bend`).

    Attributes
    ----------
    f_statistic : float
        F of the quadric height field against the plane (NaN with too few points).
    significant : bool
        F beyond its (1 - BEND_SIGNIFICANCE) quantile: the bend is not noise.
    turn : float [rad]
        Angle by which the quadric's normal turns across the face along its direction of
        strongest curvature (curvature times the face's width that way).
    height : float [m]
        RMS height of the quadric's bend over the plane: the root of the quadric's
        reduction of the (mass-weighted) mean square residual. Slow sensor errors bend a
        flat face by an amount of this kind, whatever the number of points.
    """

    f_statistic: float
    significant: bool
    turn: float
    height: float = 0.0


def _weighted_lstsq(design: NDArray[np.float64], h: NDArray[np.float64],
                    sw: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
    """Weighted least squares (row weights ``sw`` squared): coefficients and residual sum."""
    coef = np.linalg.lstsq(design * sw[:, None], h * sw, rcond=None)[0]
    r = (h - design @ coef) * sw
    return coef, float(r @ r)


def face_bend(points: NDArray[np.float64], normal: NDArray[np.float64],
              mass: NDArray[np.float64] | None = None,
              significance: float = BEND_SIGNIFICANCE, correlation: float = 1.0) -> FaceBend:
    """Test whether a face bends beyond its noise: quadric against plane (F-test).

    In the frame of the face's plane (``normal``), the heights h of its points over the
    plane are fitted by a plane h = d x + e y + f and by a quadric that adds
    a x^2 + b x y + c y^2. Under independent noise of any sigma, the quadric's reduction
    of the residual sum, per added term, over the quadric's residual per degree of
    freedom follows F(3, m - 6): the test needs no noise estimate (the residual itself
    measures the noise at the face's range and incidence), and its power grows with the
    face's points and with the bend's sagitta over the noise.

    Parameters
    ----------
    points : (m, 3) float64 array [m]
        The face's points (or voxel centroids with ``mass``).
    normal : (3,) float64, unit
        Normal of the face's plane.
    mass : (m,) float64 array, optional
        Input points each of ``points`` stands for: a centroid of c points has 1/c of
        their noise variance, so it is weighted by c.
    significance : float
        Level of the test.
    correlation : float, >= 1
        Ratio of the noise a model fitted across a whole surface meets to the local noise
        (``NoiseEstimate.scale``: slowly varying errors of real sensors). The quadric's
        residual measures the local noise only; slow errors bend a face as much as
        ``correlation**2`` times that variance, so F is divided by it (1: independent
        noise, the F-test as it stands).

    Returns
    -------
    FaceBend
        Not significant (F NaN, turn 0) with fewer than seven points.
    """
    m = len(points)
    if m <= _QUADRIC_TERMS:
        return FaceBend(math.nan, False, 0.0)
    w = np.ones(m) if mass is None else np.asarray(mass, dtype=np.float64)
    u, v = perpendicular_basis(np.asarray(normal, dtype=np.float64))
    q = points - w @ points / w.sum()
    x, y, h = q @ u, q @ v, q @ normal
    scale = max(float(np.sqrt(np.mean(x * x + y * y))), np.finfo(float).tiny)
    xs, ys = x / scale, y / scale
    design = np.column_stack([xs * xs, xs * ys, ys * ys, xs, ys, np.ones(m)])
    sw = np.sqrt(w)
    coef, rss_q = _weighted_lstsq(design, h, sw)
    _, rss_p = _weighted_lstsq(design[:, _PLANE_TERMS:], h, sw)
    dof = m - _QUADRIC_TERMS
    added = _QUADRIC_TERMS - _PLANE_TERMS
    if rss_p <= (_FLAT_TO_ROUNDING * scale) ** 2 * float(w.sum()):
        return FaceBend(0.0, False, 0.0)
    height = math.sqrt(max(rss_p - rss_q, 0.0) / float(w.sum()))
    f_stat = math.inf if rss_q <= 0.0 else \
        max(rss_p - rss_q, 0.0) / added / (rss_q / dof) / max(correlation, 1.0) ** 2
    crit = float(fdtri(added, dof, 1.0 - significance))   # F(added, dof) quantile
    hess = np.array([[2 * coef[0], coef[1]], [coef[1], 2 * coef[2]]]) / (scale * scale)
    evals, evecs = np.linalg.eigh(hess)
    k = int(np.argmax(np.abs(evals)))
    along = np.column_stack([x, y]) @ evecs[:, k]
    lo, hi = np.percentile(along, list(BEND_EXTENT_PERCENTILES))
    return FaceBend(float(f_stat), bool(f_stat > crit), float(abs(evals[k]) * (hi - lo)), height)


def _normal_equations(design: NDArray[np.float64], rhs: NDArray[np.float64]
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Return the normal equations A^T A (P, t, t) and A^T b (P, t) of P least-squares fits.

    ``design`` (P, m, t) holds each fit's m rows of t terms, ``rhs`` (P, m) its right-hand
    sides. As batched matrix products (several times faster than the equivalent ``einsum``
    over small matrices).
    """
    at = design.transpose(0, 2, 1)
    return at @ design, (at @ rhs[..., None])[..., 0]


def patch_bends(points: NDArray[np.float64], normal: NDArray[np.float64]
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Bend height and turn (:class:`FaceBend`) of many patches of one plane at once.

    The same quadric-against-plane fit as :func:`face_bend`, unweighted, for P patches of
    m points each (vectorised: the null patches of a frame's support, ``slow_bend``).

    Parameters
    ----------
    points : (P, m, 3) float64 array [m], m > 6
    normal : (3,) float64, unit
        Normal of the plane the patches lie on.

    Returns
    -------
    height : (P,) float64 [m]
        RMS height of each patch's quadric bend over its plane.
    turn : (P,) float64 [rad]
        Turn of each quadric's normal across its patch along its strongest curvature.
    """
    u, v = perpendicular_basis(np.asarray(normal, dtype=np.float64))
    q = points - points.mean(axis=1, keepdims=True)
    x, y, h = q @ u, q @ v, q @ normal
    scale = np.maximum(np.sqrt(np.mean(x * x + y * y, axis=1, keepdims=True)),
                       np.finfo(float).tiny)
    xs, ys = x / scale, y / scale
    design = np.stack([xs * xs, xs * ys, ys * ys, xs, ys, np.ones_like(xs)], axis=2)
    ata, atb = _normal_equations(design, h)
    ata = ata + _QUADRIC_RIDGE * np.eye(_QUADRIC_TERMS)
    coef = np.linalg.solve(ata, atb[..., None])[..., 0]
    flat = np.linalg.solve(ata[:, _PLANE_TERMS:, _PLANE_TERMS:],
                           atb[:, _PLANE_TERMS:, None])[..., 0]
    # Least squares: the residual sum is |h|^2 - coef . (A^T h); the reduction is the
    # difference of the two fits' explained sums.
    gain = np.einsum("pi,pi->p", coef, atb) - np.einsum("pi,pi->p", flat, atb[:, _PLANE_TERMS:])
    height = np.sqrt(np.maximum(gain, 0.0) / points.shape[1])
    s2 = scale[:, 0] ** 2
    h11, h12, h22 = 2 * coef[:, 0] / s2, coef[:, 1] / s2, 2 * coef[:, 2] / s2
    disc = np.sqrt(0.25 * (h11 - h22) ** 2 + h12 ** 2)
    mean = 0.5 * (h11 + h22)
    k = np.where(np.abs(mean + disc) >= np.abs(mean - disc), mean + disc, mean - disc)
    # Eigenvector of [[h11, h12], [h12, h22]] for k (either row; the larger is stabler).
    ex = np.where(np.abs(h12) + np.abs(k - h11) > 0, h12, 1.0)
    ey = np.where(np.abs(h12) + np.abs(k - h11) > 0, k - h11, 0.0)
    norm = np.maximum(np.hypot(ex, ey), np.finfo(float).tiny)
    along = (x * ex[:, None] + y * ey[:, None]) / norm[:, None]
    lo, hi = np.percentile(along, list(BEND_EXTENT_PERCENTILES), axis=1)
    return height, np.abs(k) * (hi - lo)


def principal_curvatures(points: NDArray[np.float64], normals: NDArray[np.float64],
                         neighbors: NDArray[np.int64], rows: NDArray[np.int64] | None = None
                         ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Principal curvatures per point from a local quadric fit (vectorised).

    In each point's tangent frame the neighbours are fitted with
    z = a x^2 + b x y + c y^2 + d x + e y + f; the eigenvalues of [[2a, b], [b, 2c]] are
    the principal curvatures.

    Parameters
    ----------
    points : (M, 3) float64 array [m]
    normals : (M, 3) float64 array, unit
    neighbors : (M, k) int64 array, k >= 6
    rows : (R,) int64 array, optional
        The points whose curvatures are computed (default: all M); each one's own fit is
        the same as with all.

    Returns
    -------
    k_max, k_min : (M,) or (R,) float64 arrays [1/m]
        Curvature of largest and smallest magnitude (signs kept), per point of ``rows``.
    """
    if rows is not None:
        centres, normals, neighbors = points[rows], normals[rows], neighbors[rows]
    else:
        centres = points
    m = len(centres)
    u, v = perpendicular_bases(normals)
    d = points[neighbors] - centres[:, None, :]
    x = np.einsum("mki,mi->mk", d, u)
    y = np.einsum("mki,mi->mk", d, v)
    z = np.einsum("mki,mi->mk", d, normals)
    scale = np.sqrt(np.mean(x * x + y * y, axis=1, keepdims=True))
    scale = np.where(scale > 0, scale, 1.0)
    xs, ys, zs = x / scale, y / scale, z / scale
    design = np.stack([xs * xs, xs * ys, ys * ys, xs, ys, np.ones_like(xs)], axis=2)
    ata, atb = _normal_equations(design, zs)
    ata = ata + _QUADRIC_RIDGE * np.eye(6)
    coef = np.linalg.solve(ata, atb[..., None])[..., 0]
    a, b, c = coef[:, 0], coef[:, 1], coef[:, 2]
    s = scale[:, 0]
    # Curvatures in scaled units -> divide by the scale to get 1/m.
    h11, h12, h22 = 2 * a / s, b / s, 2 * c / s
    mean = 0.5 * (h11 + h22)
    disc = np.sqrt(np.maximum(0.25 * (h11 - h22) ** 2 + h12 ** 2, 0.0))
    k1, k2 = mean + disc, mean - disc
    swap = np.abs(k2) > np.abs(k1)
    k_max = np.where(swap, k2, k1)
    k_min = np.where(swap, k1, k2)
    return k_max[:m], k_min[:m]
