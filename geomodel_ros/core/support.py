"""Support surfaces of a scene (desk, floor, walls): large planes found before the objects.

:func:`support_planes` finds them on the working cloud (RANSAC planes with normals whose
connected inlier area exceeds ``seg_min_support_area``); :func:`support_plane_equation`
refits one on its own input points for the final labels and the modeling.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.fastmath import link_components, row_norms, take_rows
from geomodel_ros.core.noise import K_SUPPORT, NoiseEstimate
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.ransac import PlaneModel, fit_plane_svd, ransac, refine

__all__ = ["SUPPORT_SCORE_POINTS", "continued_supports", "support_planes",
           "support_plane_equation"]

#: Support-plane hypotheses are scored on this many random working points (a plane
#: that holds a share w of them holds about that share of the whole cloud).
SUPPORT_SCORE_POINTS = 5000
#: Points that define a plane: fewer free points end the search, and a RANSAC fit with
#: fewer inliers keeps its hypothesis instead of a least-squares refit.
PLANE_MIN_POINTS = 3
#: Inliers of a support plane are connected when closer than this many voxels (a voxel
#: grid's neighbours are 1 to sqrt(3) voxels apart; 2.5 bridges single missing voxels).
SUPPORT_LINK_VOXELS = 2.5
#: The incidence stretches a link along a surface at most this much (1 / cos): a surface
#: seen within 17 deg of edge-on is not followed farther.
MIN_LINK_COS = 0.3
#: A connected piece of the inliers stays in the support when its area is at least this
#: share of ``seg_min_support_area``: a desk split by the objects standing on it stays one
#: support, while small coplanar bits elsewhere (a box top at desk height far away) do not
#: join it.
SUPPORT_MIN_PIECE_SHARE = 0.1
#: The final plane of a support is refit on at most this many of its input points (a
#: random subsample: more only cost time for a plane) ...
REFIT_MAX_POINTS = 20000
#: ... as a least-squares plane refined on a tight inlier band, ``seg_plane_threshold``
#: divided by this (the voxels at the contact mix in object points; a band of a quarter
#: of the threshold keeps them out) ...
REFIT_BAND_DIVISOR = 4.0
#: ... over this many rounds of inlier re-selection.
REFIT_ROUNDS = 3


def _components(n: int, sel: NDArray[np.int64], radius: float | NDArray[np.float64],
                neighbors: NDArray[np.int64], sqdist: NDArray[np.float64]
                ) -> tuple[int, NDArray[np.int64]]:
    """Label the connected components of the points ``sel`` (of ``n``).

    Each point is linked to those of its ``neighbors`` (n, k) (squared distances
    ``sqdist`` [m^2]) that are in ``sel`` and closer than ``radius`` [m] (one value, or
    one per point of ``sel``).
    """
    m = len(sel)
    local = np.full(n, -1, dtype=np.int64)
    local[sel] = np.arange(m)
    nb = local[take_rows(neighbors, sel)]
    r2 = np.square(radius)[:, None] if np.ndim(radius) else radius * radius
    keep = (nb >= 0) & (take_rows(sqdist, sel) <= r2)
    return link_components(nb, keep)


def support_planes(wp: NDArray[np.float64], wn: NDArray[np.float64],
                   nbrs: NDArray[np.int64], sqdist: NDArray[np.float64],
                   params: ModelingParams, rng: np.random.Generator,
                   noise: NoiseEstimate | None = None) -> list[NDArray[np.int64]]:
    """Working-point indices of each support plane, largest first.

    Parameters
    ----------
    wp, wn : (M, 3) float64 arrays
        Working cloud [m] and its unit normals.
    nbrs, sqdist : (M, k) arrays
        Nearest neighbours of every working point and their squared distances [m^2].
    params : ModelingParams
        ``seg_*`` plane parameters and the RANSAC budget.
    rng : Generator
        Randomness for RANSAC.

    Returns
    -------
    list of (S_i,) int64 arrays
        At most ``seg_max_supports`` planes, each of at least ``seg_min_support_area``.
    """
    cell_area = params.seg_voxel_size * params.seg_voxel_size
    free = np.ones(len(wp), dtype=bool)
    supports: list[NDArray[np.int64]] = []
    for _ in range(params.seg_max_supports):
        idx = np.flatnonzero(free)
        if len(idx) < PLANE_MIN_POINTS or len(idx) * cell_area < params.seg_min_support_area:
            break
        inl = _plane_inliers(wp, wn, idx, params, rng)
        if inl is None or len(inl) * cell_area < params.seg_min_support_area:
            break
        keep = _large_pieces(len(wp), inl, nbrs, sqdist, params,
                             _link_radii(wp, wn, inl, params, noise))
        if len(keep) * cell_area < params.seg_min_support_area:
            free[inl] = False  # not a support; do not find the same plane again
            continue
        supports.append(keep)
        free[keep] = False
    return supports


def _plane_inliers(wp: NDArray[np.float64], wn: NDArray[np.float64], idx: NDArray[np.int64],
                   params: ModelingParams, rng: np.random.Generator) -> NDArray[np.int64] | None:
    """Inliers (indices into ``wp``) of the largest plane among the points ``idx``, or None.

    The RANSAC plane is refit by least squares on its inliers, and the inliers (within
    ``seg_plane_threshold`` and ``seg_plane_normal_angle``) taken again.
    """
    pts, nrm = take_rows(wp, idx), take_rows(wn, idx)
    fit = ransac(PlaneModel, pts, nrm, params.seg_plane_threshold,
                 params.seg_plane_normal_angle, params.ransac_max_iterations,
                 params.ransac_confidence, rng, max_score_points=SUPPORT_SCORE_POINTS)
    if fit is None:
        return None
    model = fit_plane_svd(take_rows(pts, fit.inliers)) \
        if fit.inliers.sum() >= PLANE_MIN_POINTS else fit.model
    dist = np.abs(pts @ model.normal + model.d)
    cos = np.abs(nrm @ model.normal)
    return idx[(dist <= params.seg_plane_threshold)
               & (cos >= math.cos(params.seg_plane_normal_angle))]


def _link_radii(wp: NDArray[np.float64], wn: NDArray[np.float64], inl: NDArray[np.int64],
                params: ModelingParams, noise: NoiseEstimate | None) -> NDArray[np.float64]:
    """Link radius [m] of each inlier ``inl`` of a support plane.

    SUPPORT_LINK_VOXELS spacings of the points on the surface: the voxel, or where the
    sensor's pixels lie farther apart, their footprint at the point's range stretched by
    the incidence (a floor seen at a grazing angle has its image rows several footprints
    apart on the floor).
    """
    v = params.seg_voxel_size
    if noise is None or noise.spacing_per_m <= 0.0:
        return np.full(len(inl), SUPPORT_LINK_VOXELS * v)
    p, n = take_rows(wp, inl), take_rows(wn, inl)
    r = row_norms(p)
    cos = np.abs(np.einsum("ij,ij->i", p, n)) / np.maximum(r, 1e-12)
    along = noise.spacing_per_m * r / np.maximum(cos, MIN_LINK_COS)
    return SUPPORT_LINK_VOXELS * np.maximum(v, along)


def _large_pieces(m: int, inl: NDArray[np.int64], nbrs: NDArray[np.int64],
                  sqdist: NDArray[np.float64], params: ModelingParams,
                  radius: NDArray[np.float64]) -> NDArray[np.int64]:
    """Keep the points of ``inl`` (of ``m`` working points) in large connected pieces.

    Two are connected when closer than ``radius`` (one per point of ``inl``) [m].
    """
    v = params.seg_voxel_size
    n_comp, comp = _components(m, inl, radius, nbrs, sqdist)
    sizes = np.bincount(comp, minlength=n_comp)
    big = sizes * (v * v) >= SUPPORT_MIN_PIECE_SHARE * params.seg_min_support_area
    return inl[big[comp]]


def support_plane_equation(own_pts: NDArray[np.float64], params: ModelingParams
                           ) -> tuple[NDArray[np.float64], float]:
    """Plane n . x + d = 0 of a support's own input points, normal towards the sensor.

    Parameters
    ----------
    own_pts : (P, 3) float64 array [m]
        The support's input points (at most :data:`REFIT_MAX_POINTS`), sensor at the origin.
    params : ModelingParams
        ``seg_plane_threshold`` is used.

    Returns
    -------
    normal : (3,) float64 array
        Unit normal, pointing to the sensor's side.
    d : float
        Offset [m].
    """
    model = refine(fit_plane_svd(own_pts), own_pts,
                   params.seg_plane_threshold / REFIT_BAND_DIVISOR, rounds=REFIT_ROUNDS)
    center = own_pts.mean(axis=0)
    nrm = model.normal if model.normal @ center < 0 else -model.normal
    d = model.d if nrm @ model.normal > 0 else -model.d
    return nrm, d


#: A segment continues a support when at least this share of its points (by input points)
#: lie within the support's band of the support's plane fitted around it: the band is
#: K_SUPPORT (4) sigma, which holds 98-99 % of a real table's points
#: (:data:`geomodel_ros.core.noise.K_SUPPORT`); the rest is the margin for the tails.
CONTINUATION_MIN_SHARE = 0.95
#: Rounds of :func:`continued_supports`: a piece that joined brings the segments linked to
#: it within reach in the next round; a bent surface is cut into a few pieces at most.
CONTINUATION_ROUNDS = 3
#: The support's plane around a segment is fitted on at most about this many of its
#: points (evenly strided): its normal is then known to a few hundredths of a degree.
LOCAL_FIT_POINTS = 2000


def continued_supports(wp: NDArray[np.float64], counts: NDArray[np.int64],
                       comp: NDArray[np.int64], comp_ok: NDArray[np.bool_],
                       wlabel: NDArray[np.int64], supports: list[NDArray[np.int64]],
                       links: tuple[NDArray[np.int64], NDArray[np.float64]], link: float,
                       noise: NoiseEstimate | None, params: ModelingParams
                       ) -> NDArray[np.int64]:
    """Give the segments that continue a support surface back to it, in place.

    A support is found as one plane with a band (:func:`support_planes`), but a real
    surface is flat only locally: a floor seen out to 2 m or a desk at an image corner
    bends away from the plane by more than the band (a depth camera's distortion grows
    towards the image border and with range: 7-15 mm in osd_learn's corners and the PCL
    milk scene's far floor), and the part beyond the band was segmented as an object of
    its own. A segment is such a part when it is linked to the support (a neighbour link
    no longer than ``link`` [m]) and lies on the support's plane *fitted around it* by the
    support's own rule: its points within the band (``seg_plane_threshold``, or K_SUPPORT
    sigma along that plane's normal at the point's own range where more) for at least
    :data:`CONTINUATION_MIN_SHARE` of them, and its own plane's normal within
    ``seg_plane_normal_angle``. A flat object lying on the support is kept apart by its
    thickness wherever that exceeds the band (as the support's plane keeps it apart); an
    object standing on it leaves the plane.

    Parameters
    ----------
    wp : (M, 3) float64 array
        Working points [m], sensor at the origin.
    counts : (M,) int64 array
        Input points per working point.
    comp, comp_ok : (M,) arrays
        Segment of every object point (-1 elsewhere) and the points of the segments kept;
        a segment that joins a support leaves them (``comp_ok`` set False).
    wlabel : (M,) int64 array
        Support of every working point (-1 elsewhere); set for the joined points.
    supports : list of int64 arrays
        Working-point indices of each support; the joined points are added.
    links : (neighbors, sqdist)
        (M, k) nearest neighbours of every working point and squared distances [m^2].
    link : float
        Longest link [m] between a segment and its support.
    noise : NoiseEstimate or None
        The frame's noise (its ``sigma(z)``); None: the band is ``seg_plane_threshold``.
    params : ModelingParams

    Returns
    -------
    (J,) int64 array
        The working points that joined a support.
    """
    nbrs, sqdist = links
    taken: list[NDArray[np.int64]] = []
    around: dict[int, NDArray[np.float64]] = {}  # a support's working points
    reach = wlabel >= 0  # the support points a segment must be linked to
    for _ in range(CONTINUATION_ROUNDS):
        obj = np.flatnonzero(comp_ok)
        if not len(obj) or not supports:
            break
        nb = take_rows(nbrs, obj)
        sup = np.where((take_rows(sqdist, obj) <= link * link) & reach[nb], wlabel[nb], -1)
        row, col = np.nonzero(sup >= 0)
        if not len(row):
            break
        n_s = len(supports)
        pairs = np.unique(comp[obj[row]] * n_s + sup[row, col])
        reach[:] = False  # the next round tries the segments linked to what joins now
        for c, s in zip((pairs // n_s).tolist(), (pairs % n_s).tolist()):
            own = np.flatnonzero(comp_ok & (comp == c))
            if len(own) < PLANE_MIN_POINTS:
                continue
            pts = take_rows(wp, own)
            if s not in around:
                around[s] = take_rows(wp, supports[s])
            local = _support_around(around[s], pts)
            if local is None or not _on_plane(pts, counts[own], local, noise, params):
                continue
            comp_ok[own] = False
            wlabel[own] = s
            reach[own] = True
            supports[s] = np.concatenate([supports[s], own])
            around.pop(s, None)
            taken.append(own)
        if not reach.any():
            break
    return np.concatenate(taken) if taken else np.zeros(0, dtype=np.int64)


def _on_plane(pts: NDArray[np.float64], weights: NDArray[np.int64], plane: PlaneModel,
              noise: NoiseEstimate | None, params: ModelingParams) -> bool:
    """Tell whether a segment's points ``pts`` (P, 3) [m] lie on a support's ``plane``.

    On it by the support's rule: the segment's own plane within ``seg_plane_normal_angle``
    of it, and at least :data:`CONTINUATION_MIN_SHARE` of its input points (``weights``
    (P,) per working point) within the band: ``seg_plane_threshold``, or K_SUPPORT sigma
    of ``noise`` at each point's range along the plane's normal where more.
    """
    if abs(float(fit_plane_svd(pts).normal @ plane.normal)) < \
            math.cos(params.seg_plane_normal_angle):
        return False
    off = np.abs(pts @ plane.normal + plane.d)
    band = np.full(len(pts), params.seg_plane_threshold)
    if noise is not None:
        rng = np.linalg.norm(pts, axis=1)
        cos_ray = np.abs(pts @ plane.normal) / np.maximum(rng, 1e-12)
        band = np.maximum(band, K_SUPPORT * noise.sigma(rng) * cos_ray)
    return float(weights[off <= band].sum()) >= CONTINUATION_MIN_SHARE * float(weights.sum())


def _support_around(sup: NDArray[np.float64], pts: NDArray[np.float64]) -> PlaneModel | None:
    """Least-squares plane of the support points ``sup`` (S, 3) [m] around ``pts``.

    Around: within the segment's own extent (its bounding box's diagonal) of that box's
    centre, so the plane is that of the support where the segment lies. None with fewer
    than :data:`PLANE_MIN_POINTS` there.
    """
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    radius = float(np.linalg.norm(hi - lo))
    q = sup - 0.5 * (lo + hi)
    near = np.einsum("ij,ij->i", q, q) <= radius * radius
    idx = np.flatnonzero(near)
    if len(idx) < PLANE_MIN_POINTS:
        return None
    return fit_plane_svd(take_rows(sup, idx[::max(1, len(idx) // LOCAL_FIT_POINTS)]))
