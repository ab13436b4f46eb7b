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

from .errors import as_points
from .faces import WorkingCloud, estimate_normals, split_faces, voxelize
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


def _convex_objects(points: NDArray[np.float64], params: ModelingParams) -> NDArray[np.int64]:
    """Object label of every point of a support-free working cloud (local convexity).

    Patches are smooth regions (:func:`geomodel_ros.faces.split_faces`). Across the border
    of two adjacent patches every neighbour link votes with its convexity
    (n_i - n_j) . (p_i - p_j) / |p_i - p_j| (~0 flat, > 0 convex, < 0 concave); the patches
    belong to one object when at least half the votes are above ``-seg_concavity_tolerance``.
    Links longer than ``seg_max_edge_factor`` voxels (depth jumps) do not vote.
    """
    m = len(points)
    tree = cKDTree(points)
    normals, variation, nbrs = estimate_normals(points, params.normal_neighbors, tree=tree)
    cloud = WorkingCloud(points, normals, variation, nbrs, np.ones(m, dtype=np.int64),
                         np.arange(m))
    max_edge = params.seg_max_edge_factor * params.seg_voxel_size
    patches = split_faces(cloud, params.face_angle_threshold, params.edge_variation_threshold,
                          params.min_face_points, max_edge).labels
    k = nbrs.shape[1]
    i = np.repeat(np.arange(m), k)
    j = nbrs.ravel()
    d = points[i] - points[j]
    dist = np.linalg.norm(d, axis=1)
    ok = (i != j) & (dist <= max_edge)
    i, j, d, dist = i[ok], j[ok], d[ok], dist[ok]
    convexity = np.einsum("ij,ij->i", normals[i] - normals[j], d) / np.maximum(dist, 1e-12)
    pi, pj = patches[i], patches[j]
    cross = pi != pj
    n_p = int(patches.max()) + 1
    key = np.minimum(pi[cross], pj[cross]) * n_p + np.maximum(pi[cross], pj[cross])
    good = convexity[cross] >= -params.seg_concavity_tolerance
    pairs, inv = np.unique(key, return_inverse=True)
    votes = np.bincount(inv, minlength=len(pairs))
    yes = np.bincount(inv, weights=good, minlength=len(pairs))
    obj = _merge_patches(n_p, pairs // n_p, pairs % n_p, votes, yes)
    return obj[patches].astype(np.int64)


def _merge_patches(n: int, a: NDArray[np.int64], b: NDArray[np.int64], votes: NDArray,
                   yes: NDArray, min_cut_votes: int = 20, cut_share: float = 0.3
                   ) -> NDArray[np.int64]:
    """Group patches into objects from their border votes.

    Pairs with at least half the votes flat/convex are joined, strongest evidence first
    (union-find); a join is refused when the two groups already share a clearly concave
    border (at least ``min_cut_votes`` votes, less than ``cut_share`` of them convex), so
    a weak convex contact cannot glue together two objects that meet at a concave crease
    elsewhere. Loops over patch pairs only (tens to hundreds), never over points.
    """
    parent = np.arange(n)

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    share = yes / np.maximum(votes, 1)
    cut = (votes >= min_cut_votes) & (share < cut_share)
    cannot: dict[int, set[int]] = {}
    for x, y in zip(a[cut].tolist(), b[cut].tolist()):
        cannot.setdefault(x, set()).add(y)
        cannot.setdefault(y, set()).add(x)
    members: dict[int, set[int]] = {}
    order = np.argsort(-yes, kind="stable")
    for e in order[share[order] >= 0.5].tolist():
        ra, rb = find(int(a[e])), find(int(b[e]))
        if ra == rb:
            continue
        ma, mb = members.get(ra, {ra}), members.get(rb, {rb})
        blocked = any(cannot.get(x, set()) & mb for x in ma)
        if blocked:
            continue
        parent[rb] = ra
        members[ra] = ma | mb
        members.pop(rb, None)
    roots = np.array([find(i) for i in range(n)])
    return np.unique(roots, return_inverse=True)[1].ravel()


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
    pts = as_points(points, allow_organized=True)
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

    # Objects: smooth patches of the remaining working points (normals recomputed without
    # the supports, so they do not blend into the desk), then patches joined where most
    # links along their common border are flat or convex.
    rest_idx = np.flatnonzero(wlabel < 0)
    comp = np.full(m, -1, dtype=np.int64)
    if len(rest_idx) >= 4:
        comp[rest_idx] = _convex_objects(wp[rest_idx], params)
    rest = comp >= 0
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
