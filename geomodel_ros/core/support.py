"""Support surfaces of a scene (desk, floor, walls): large planes found before the objects.

:func:`support_planes` finds them on the working cloud (RANSAC planes with normals whose
connected inlier area exceeds ``seg_min_support_area``); :func:`support_plane_equation`
refits one on its own input points for the final labels and the modeling.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.fastmath import link_components, take_rows
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.ransac import PlaneModel, fit_plane_svd, ransac, refine

__all__ = ["SUPPORT_SCORE_POINTS", "support_planes", "support_plane_equation"]

#: Support-plane hypotheses are scored on this many random working points (a plane
#: that holds a share w of them holds about that share of the whole cloud).
SUPPORT_SCORE_POINTS = 5000
#: Points that define a plane: fewer free points end the search, and a RANSAC fit with
#: fewer inliers keeps its hypothesis instead of a least-squares refit.
PLANE_MIN_POINTS = 3
#: Inliers of a support plane are connected when closer than this many voxels (a voxel
#: grid's neighbours are 1 to sqrt(3) voxels apart; 2.5 bridges single missing voxels).
SUPPORT_LINK_VOXELS = 2.5
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


def _components(n: int, sel: NDArray[np.int64], radius: float, neighbors: NDArray[np.int64],
                sqdist: NDArray[np.float64]) -> tuple[int, NDArray[np.int64]]:
    """Label the connected components of the points ``sel`` (of ``n``).

    Each point is linked to those of its ``neighbors`` (n, k) (squared distances
    ``sqdist`` [m^2]) that are in ``sel`` and closer than ``radius`` [m].
    """
    m = len(sel)
    local = np.full(n, -1, dtype=np.int64)
    local[sel] = np.arange(m)
    nb = local[take_rows(neighbors, sel)]
    keep = (nb >= 0) & (take_rows(sqdist, sel) <= radius * radius)
    return link_components(nb, keep)


def support_planes(wp: NDArray[np.float64], wn: NDArray[np.float64],
                   nbrs: NDArray[np.int64], sqdist: NDArray[np.float64],
                   params: ModelingParams, rng: np.random.Generator
                   ) -> list[NDArray[np.int64]]:
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
        keep = _large_pieces(len(wp), inl, nbrs, sqdist, params)
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


def _large_pieces(m: int, inl: NDArray[np.int64], nbrs: NDArray[np.int64],
                  sqdist: NDArray[np.float64], params: ModelingParams) -> NDArray[np.int64]:
    """Keep the points of ``inl`` (of ``m`` working points) in large connected pieces."""
    v = params.seg_voxel_size
    n_comp, comp = _components(m, inl, SUPPORT_LINK_VOXELS * v, nbrs, sqdist)
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
