"""Scene segmentation: raw cloud -> support planes and objects (paper section 3, Figure 1).

1. The cloud is reduced to a voxel grid (the *working cloud*) with normals.
2. Support surfaces (desk, floor, walls) are found first: RANSAC planes, with normals,
   whose connected inlier area exceeds ``seg_min_support_area``.
3. The rest is split into objects by local convexity (as in LCCP, Stein et al. 2014):
   neighbouring working points are linked unless they meet at a concave crease (object
   on object, object against the desk) or across a depth jump (occlusion boundary). Objects are the connected components
   (:func:`scipy.sparse.csgraph.connected_components`); tiny ones are noise.
4. Labels go back to every input point through the voxel map.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .faces import estimate_normals, voxelize
from .params import ModelingParams
from .ransac import PlaneModel, fit_plane_svd, ransac, refine

__all__ = ["Segmentation", "segment_scene"]


@dataclass
class Segmentation:
    """Result of :func:`segment_scene`.

    Attributes
    ----------
    labels : (N,) int64
        Object id of every input point (row of the input), -1 for invalid points and noise.
    support_ids : list[int]
        Ids of the support planes (desk, floor, walls), which come first.
    support_planes : dict[int, (normal (3,), d)]
        Plane n . x + d = 0 of each support, normal towards the sensor.
    timing : dict[str, float]
        Seconds per stage.
    """

    labels: NDArray[np.int64]
    support_ids: list[int] = field(default_factory=list)
    timing: dict[str, float] = field(default_factory=dict)
    support_planes: dict[int, tuple[NDArray[np.float64], float]] = field(default_factory=dict)

    @property
    def object_ids(self) -> NDArray[np.int64]:
        ids = np.unique(self.labels)
        return ids[ids >= 0]


def _components(points: NDArray[np.float64], sel: NDArray[np.int64], radius: float
                ) -> tuple[int, NDArray[np.int64]]:
    """Connected components of ``points[sel]`` linking points closer than ``radius``."""
    tree = cKDTree(points[sel])
    pairs = tree.query_pairs(radius, output_type="ndarray")
    m = len(sel)
    graph = coo_matrix((np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])),
                       shape=(m, m))
    return connected_components(graph, directed=False)


def _support_planes(wp: NDArray[np.float64], wn: NDArray[np.float64], counts: NDArray[np.int64],
                    params: ModelingParams, rng: np.random.Generator) -> list[NDArray[np.int64]]:
    """Working-point indices of each support plane, largest first."""
    v = params.seg_voxel_size
    cell_area = v * v
    free = np.ones(len(wp), dtype=bool)
    supports: list[NDArray[np.int64]] = []
    for _ in range(params.seg_max_supports):
        idx = np.flatnonzero(free)
        if len(idx) < 3 or len(idx) * cell_area < params.seg_min_support_area:
            break
        fit = ransac(PlaneModel, wp[idx], wn[idx], params.seg_plane_threshold,
                     params.seg_plane_normal_angle, params.ransac_max_iterations,
                     params.ransac_confidence, rng)
        if fit is None:
            break
        model = fit_plane_svd(wp[idx[fit.inliers]]) if fit.inliers.sum() >= 3 else fit.model
        dist = np.abs(wp[idx] @ model.normal + model.d)
        cos = np.abs(wn[idx] @ model.normal)
        inl = idx[(dist <= params.seg_plane_threshold)
                  & (cos >= math.cos(params.seg_plane_normal_angle))]
        if len(inl) * cell_area < params.seg_min_support_area:
            break
        # Keep the connected pieces of the inliers that are large themselves (a desk split
        # by the objects standing on it stays one support; far coplanar bits do not join).
        n_comp, comp = _components(wp, inl, 2.5 * v)
        sizes = np.bincount(comp, minlength=n_comp)
        big = sizes * cell_area >= 0.1 * params.seg_min_support_area
        keep = inl[big[comp]]
        if len(keep) * cell_area < params.seg_min_support_area:
            free[inl] = False  # not a support; do not find the same plane again
            continue
        supports.append(keep)
        free[keep] = False
    return supports


def segment_scene(points: NDArray, params: ModelingParams | None = None, *,
                  rng: np.random.Generator | int | None = None) -> Segmentation:
    """Segment a scene cloud into support planes and objects.

    Parameters
    ----------
    points : (N, 3) or (H, W, 3) float array [m]
        Scene cloud in the sensor frame; non-finite points (NaN for invalid pixels of an
        organized cloud) are allowed and get label -1.
    params : ModelingParams, optional
        ``seg_*`` parameters are used.
    rng : Generator, seed or None
        Randomness for the plane RANSAC; defaults to ``params.seed``.

    Returns
    -------
    Segmentation with labels aligned with the input rows (row-major for organized input).
    """
    t0 = time.perf_counter()
    params = params if params is not None else ModelingParams()
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim == 3 and pts.shape[2] == 3:
        pts = pts.reshape(-1, 3)
    if pts.ndim != 2 or pts.shape[1] != 3:
        from .pipeline import InputError

        raise InputError(f"points must be (N, 3) or (H, W, 3), got shape {np.shape(points)}")
    rng = np.random.default_rng(params.seed if rng is None else rng)
    n = len(pts)
    labels = np.full(n, -1, dtype=np.int64)
    finite = np.flatnonzero(np.all(np.isfinite(pts), axis=1))
    timing: dict[str, float] = {}
    if len(finite) < 3:
        timing["segmentation_s"] = time.perf_counter() - t0
        return Segmentation(labels, [], timing)
    p = pts[finite]
    wp, inverse, counts = voxelize(p, params.seg_voxel_size)
    m = len(wp)
    if m < 4:
        timing["segmentation_s"] = time.perf_counter() - t0
        return Segmentation(labels, [], timing)
    tree = cKDTree(wp)
    wn, variation, nbrs = estimate_normals(wp, params.normal_neighbors, tree=tree)
    t1 = time.perf_counter()
    timing["seg_normals_s"] = t1 - t0

    wlabel = np.full(m, -1, dtype=np.int64)
    supports = _support_planes(wp, wn, counts, params, rng)
    for sid, sel in enumerate(supports):
        wlabel[sel] = sid
    t2 = time.perf_counter()
    timing["seg_supports_s"] = t2 - t1

    # Objects: local convexity on the remaining working points.
    rest = wlabel < 0
    k = nbrs.shape[1]
    i = np.repeat(np.arange(m), k)
    j = nbrs.ravel()
    ok = rest[i] & rest[j] & (i != j)
    i, j = i[ok], j[ok]
    d = wp[i] - wp[j]
    dist = np.linalg.norm(d, axis=1)
    near = dist <= params.seg_max_edge_factor * params.seg_voxel_size
    i, j, d, dist = i[near], j[near], d[near], dist[near]
    # Convexity of the link: (n_i - n_j) . (p_i - p_j) / |p_i - p_j| is ~0 on a smooth
    # surface, positive across a convex edge and negative across a concave crease.
    convexity = np.einsum("ij,ij->i", wn[i] - wn[j], d) / np.maximum(dist, 1e-12)
    link = convexity >= -params.seg_concavity_tolerance
    graph = coo_matrix((np.ones(int(link.sum()), dtype=np.int8), (i[link], j[link])),
                       shape=(m, m))
    _, comp = connected_components(graph, directed=False)
    # Component sizes in input points; small ones are noise.
    comp_rest = np.where(rest, comp, -1)
    size = np.bincount(comp_rest[rest], weights=counts[rest], minlength=int(comp.max()) + 1)
    good = size >= params.seg_min_cluster_points
    comp_ok = rest & good[np.where(rest, comp, 0)]
    uniq, compact = np.unique(comp[comp_ok], return_inverse=True)
    # Order objects by size (largest first) for stable, meaningful ids.
    sizes = np.bincount(compact.ravel(), weights=counts[comp_ok], minlength=len(uniq))
    rank = np.empty(len(uniq), dtype=np.int64)
    rank[np.argsort(-sizes, kind="stable")] = np.arange(len(uniq))
    wlabel[comp_ok] = len(supports) + rank[compact.ravel()]
    labels[finite] = wlabel[inverse]
    # Contact rims: object points within the plane band of a support belong to it (the
    # voxel normals there blend desk and object, so they may have joined the object).
    planes: dict[int, tuple[NDArray[np.float64], float]] = {}
    for sid, sel in enumerate(supports):
        # Plane refit on the support's own input points (voxels at the contact mix in
        # object points): a tight inlier band on a subsample.
        own = np.flatnonzero(labels[finite] == sid)
        if len(own) > 20000:
            own = rng.choice(own, 20000, replace=False)
        model = refine(fit_plane_svd(p[own]), p[own], params.seg_plane_threshold / 4.0, rounds=3)
        center = p[own].mean(axis=0)
        nrm = model.normal if model.normal @ center < 0 else -model.normal
        d = model.d if nrm @ model.normal > 0 else -model.d
        planes[sid] = (nrm, d)
        obj_pts = labels[finite] >= len(supports)
        near = obj_pts & (np.abs(p @ nrm + d) <= params.seg_plane_threshold)
        labels[finite[near]] = sid
    timing["seg_objects_s"] = time.perf_counter() - t2
    timing["segmentation_s"] = time.perf_counter() - t0
    return Segmentation(labels, list(range(len(supports))), timing, planes)
