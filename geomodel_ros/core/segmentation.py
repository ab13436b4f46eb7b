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
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from geomodel_ros.core.errors import as_points
from geomodel_ros.core.faces import WorkingCloud, estimate_normals, link_graph, split_faces, voxelize
from geomodel_ros.core.geometry import perpendicular_basis
from geomodel_ros.core.input import without_far_points
from geomodel_ros.core.fastmath import row_norms, rows_finite, take_rows
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.ransac import PlaneModel, fit_plane_svd, ransac, refine

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


def _components(n: int, sel: NDArray[np.int64], radius: float, neighbors: NDArray[np.int64],
                sqdist: NDArray[np.float64]) -> tuple[int, NDArray[np.int64]]:
    """Connected components of the points ``sel`` (of ``n``), linking each point to those
    of its ``neighbors`` (n, k) (squared distances ``sqdist``) that are in ``sel`` and
    closer than ``radius``."""
    m = len(sel)
    local = np.full(n, -1, dtype=np.int64)
    local[sel] = np.arange(m)
    nb = local[neighbors[sel]]
    keep = (nb >= 0) & (sqdist[sel] <= radius * radius)
    return connected_components(link_graph(nb, keep, m), directed=False)


#: Support-plane hypotheses are scored on this many random working points (a plane
#: that holds a share w of them holds about that share of the whole cloud).
SUPPORT_SCORE_POINTS = 5000


def _support_planes(wp: NDArray[np.float64], wn: NDArray[np.float64], counts: NDArray[np.int64],
                    nbrs: NDArray[np.int64], sqdist: NDArray[np.float64],
                    params: ModelingParams, rng: np.random.Generator
                    ) -> list[NDArray[np.int64]]:
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
                     params.ransac_confidence, rng, max_score_points=SUPPORT_SCORE_POINTS)
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
        n_comp, comp = _components(len(wp), inl, 2.5 * v, nbrs, sqdist)
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

    Patches are smooth regions (:func:`geomodel_ros.core.faces.split_faces`). Across the border
    of two adjacent patches every neighbour link votes with its convexity
    (n_i - n_j) . (p_i - p_j) / |p_i - p_j| (~0 flat, > 0 convex, < 0 concave); the patches
    belong to one object when at least half the votes are above ``-seg_concavity_tolerance``.
    Links longer than ``seg_max_edge_factor`` voxels (depth jumps) do not vote.
    """
    m = len(points)
    normals, variation, nbrs, sqdist = estimate_normals(points, params.normal_neighbors,
                                                        return_sqdist=True)
    cloud = WorkingCloud(points, normals, variation, nbrs, np.ones(m, dtype=np.int64),
                         np.arange(m), sqdist)
    max_edge = params.seg_max_edge_factor * params.seg_voxel_size
    patches = split_faces(cloud, params.face_angle_threshold, params.edge_variation_threshold,
                          params.min_face_points, max_edge).labels
    k = nbrs.shape[1]
    i = np.repeat(np.arange(m), k)
    j = nbrs.ravel()
    ok = (i != j) & (sqdist.ravel() <= max_edge * max_edge)
    i, j = i[ok], j[ok]
    d = take_rows(points, i) - take_rows(points, j)
    dist = row_norms(d)
    convexity = np.einsum("ij,ij->i", take_rows(normals, i) - take_rows(normals, j), d) / np.maximum(dist, 1e-12)
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


def _join_occluded_parts(points: NDArray[np.float64], normals: NDArray[np.float64],
                         comp: NDArray[np.int64], valid: NDArray[np.bool_],
                         params: ModelingParams) -> NDArray[np.int64]:
    """Join segments that are two visible parts of one surface cut by an occluder.

    Two segments are joined when their closest points are farther apart than a link
    (they do not touch) but closer than ``seg_max_occlusion_gap``, the surface continues
    across the gap (the mean normals around both ends agree and lie across the gap
    direction), and the gap is hidden: on the viewing ray (sensor at the origin) of most
    gap samples a measured point lies clearly nearer, and on none is the gap seen open.
    Rays that meet no point (holes, sensor shadows) are no evidence either way.
    Loops over segment pairs only (tens), never over points.
    """
    ids = np.unique(comp[valid])
    if len(ids) < 2:
        return comp
    v = params.seg_voxel_size
    link = params.seg_max_edge_factor * v
    depth = row_norms(points)
    ray_tree: list[cKDTree] = []  # built on first use: most scenes never need it
    members = {int(i): np.flatnonzero(valid & (comp == i)) for i in ids}
    tree_cache: dict[int, cKDTree] = {}

    def tree(seg: int) -> cKDTree:
        if seg not in tree_cache:
            tree_cache[seg] = cKDTree(points[members[seg]])
        return tree_cache[seg]

    centers = {i: points[m].mean(axis=0) for i, m in members.items()}
    radius = {i: float(np.linalg.norm(points[m] - centers[i], axis=1).max())
              for i, m in members.items()}
    parent = {i: i for i in members}

    def find(x: int) -> int:
        while parent[x] != x:
            x = parent[x]
        return x

    cos_n = math.cos(math.radians(20.0))
    sin_g = math.sin(math.radians(15.0))
    t = np.linspace(0.15, 0.85, 8)
    keys = sorted(members)
    for ai, a in enumerate(keys):
        for b in keys[ai + 1:]:
            reach = float(np.linalg.norm(centers[a] - centers[b])) - radius[a] - radius[b]
            if reach > params.seg_max_occlusion_gap or find(a) == find(b):
                continue
            small, big = (a, b) if len(members[a]) <= len(members[b]) else (b, a)
            # Only gaps up to seg_max_occlusion_gap matter: farther pairs come back inf.
            d, j = tree(big).query(points[members[small]], k=1,
                                   distance_upper_bound=params.seg_max_occlusion_gap)
            k = int(np.argmin(d))
            gap = float(d[k])
            if gap <= link or gap > params.seg_max_occlusion_gap:
                continue
            pa = members[small][k]
            pb = members[big][int(j[k])]
            g = (points[pb] - points[pa]) / gap

            def local_normal(seg: int, at: int) -> NDArray[np.float64]:
                # Mean normal around the end point (boundary normals are unreliable).
                near = members[seg][tree(seg).query_ball_point(points[at], 3.0 * link)]
                nrm = normals[near]
                nrm = nrm * np.sign(nrm @ normals[at])[:, None]
                mean = nrm.sum(axis=0)
                return mean / max(float(np.linalg.norm(mean)), 1e-12)

            na, nb = local_normal(small, pa), local_normal(big, pb)
            if abs(float(na @ nb)) < cos_n or abs(float(na @ g)) > sin_g \
                    or abs(float(nb @ g)) > sin_g:
                continue
            samples = points[pa] + t[:, None] * (points[pb] - points[pa])
            s_depth = np.linalg.norm(samples, axis=1)
            tol = 1.5 * v / s_depth
            if not ray_tree:
                ray_tree.append(cKDTree(points / np.maximum(depth, 1e-12)[:, None]))
            dist, hit = ray_tree[0].query(samples / s_depth[:, None], k=1)
            hit = np.minimum(hit, len(points) - 1)
            seen = dist <= tol  # a measured point on this ray (else a hole: no evidence)
            nearer = depth[hit] < s_depth - 2.0 * v
            # Join when most of the gap is hidden behind nearer points and no part of it
            # is seen open (a point at or behind the gap on its ray).
            if np.all(nearer[seen]) and seen.sum() >= 0.6 * len(t):
                parent[find(b)] = find(a)
    out = comp.copy()
    for i in members:
        root = find(i)
        if root != i:
            out[members[i]] = root
    return out


def _join_contained_parts(points: NDArray[np.float64], normals: NDArray[np.float64],
                          comp: NDArray[np.int64], valid: NDArray[np.bool_],
                          support: PlaneModel, min_points: int = 30) -> NDArray[np.int64]:
    """Join the inner wall of an open round container (bowl, cup, pot) to its outer wall.

    Seen from above an open container shows its outer front wall and, behind the rim,
    its inner back wall; they meet only at the hidden back rim, so local convexity keeps
    them apart. A segment is joined to a round segment when its footprint on the support
    plane lies inside the round segment's footprint circle and their heights above the
    support overlap. A segment is round when its footprint fits a circle tightly and its
    normals point along the circle's radii (a wall of revolution, not a box). Loops over
    segment pairs only.
    """
    ids = [int(i) for i in np.unique(comp[valid])]
    if len(ids) < 2:
        return comp
    n = support.normal
    e1, e2 = perpendicular_basis(n)
    members = {i: np.flatnonzero(valid & (comp == i)) for i in ids}
    foot = {i: points[m] @ np.column_stack([e1, e2]) for i, m in members.items()}
    height = {i: np.abs(points[m] @ n + support.d) for i, m in members.items()}
    circles = {}
    for i, xy in foot.items():
        if len(xy) < min_points:
            continue
        # Algebraic circle fit x^2 + y^2 + a x + b y + c = 0, then its geometric spread.
        a = np.c_[xy, np.ones(len(xy))]
        sol, *_ = np.linalg.lstsq(a, -(xy * xy).sum(axis=1), rcond=None)
        center = -0.5 * sol[:2]
        r2 = center @ center - sol[2]
        if r2 <= 0:
            continue
        r = float(np.sqrt(r2))
        offsets = xy - center
        radial = offsets / np.maximum(np.linalg.norm(offsets, axis=1), 1e-12)[:, None]
        spread = np.median(np.abs(np.linalg.norm(offsets, axis=1) - r))
        n_xy = normals[members[i]] @ np.column_stack([e1, e2])
        n_xy /= np.maximum(np.linalg.norm(n_xy, axis=1), 1e-12)[:, None]
        along = np.median(np.abs(np.einsum("ij,ij->i", n_xy, radial)))
        # A flat face is a circle of huge radius: require a container-sized circle seen
        # over a real arc.
        ang = np.arctan2(radial[:, 1], radial[:, 0])
        arc = np.ptp(np.unwrap(np.sort(ang))) if len(ang) > 1 else 0.0
        # ... and whose normals turn continuously (a box's faces give a few directions).
        azimuth = np.degrees(np.arctan2(n_xy[:, 1], n_xy[:, 0]))
        hist = np.bincount(((azimuth + 180.0) // 10).astype(int) % 36, minlength=36)
        turning = int(np.sum(hist >= 0.02 * len(azimuth)))
        if spread < 0.08 * r and along > 0.85 and r < 0.25 and arc > math.radians(60.0) \
                and turning >= 6:
            circles[i] = (center, r)
    parent = {i: i for i in ids}

    def find(x: int) -> int:
        while parent[x] != x:
            x = parent[x]
        return x

    for a_id, (center, r) in sorted(circles.items(), key=lambda kv: -len(members[kv[0]])):
        for b_id in ids:
            if len(members[b_id]) < min_points or find(a_id) == find(b_id):
                continue
            inside = np.linalg.norm(foot[b_id] - center, axis=1) <= 1.05 * r
            ha, hb = height[a_id], height[b_id]
            overlap = min(ha.max(), hb.max()) - max(ha.min(), hb.min())
            if inside.mean() >= 0.9 and overlap > 0:
                parent[find(b_id)] = find(a_id)
    out = comp.copy()
    for i in ids:
        root = find(i)
        if root != i:
            out[members[i]] = root
    return out


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
    pts = without_far_points(pts, params)
    rng = np.random.default_rng(params.seed if rng is None else rng)
    n = len(pts)
    labels = np.full(n, -1, dtype=np.int64)
    finite = np.flatnonzero(rows_finite(pts))
    timing: dict[str, float] = {}
    if len(finite) < 3:
        timing["segmentation_s"] = time.perf_counter() - t0
        return Segmentation(labels, [], timing)
    p = take_rows(pts, finite)
    wp, inverse, counts = voxelize(p, params.seg_voxel_size)
    m = len(wp)
    if m < 4:
        timing["segmentation_s"] = time.perf_counter() - t0
        return Segmentation(labels, [], timing)
    wn, variation, nbrs, sqdist = estimate_normals(wp, params.normal_neighbors,
                                                   return_sqdist=True)
    t1 = time.perf_counter()
    timing["seg_normals_s"] = t1 - t0

    wlabel = np.full(m, -1, dtype=np.int64)
    supports = _support_planes(wp, wn, counts, nbrs, sqdist, params, rng)
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
    if params.seg_max_occlusion_gap > 0:
        comp = _join_occluded_parts(wp, wn, comp, comp_ok, params)
    if params.seg_join_contained and supports:
        comp = _join_contained_parts(wp, wn, comp, comp_ok, fit_plane_svd(wp[supports[0]]))
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
        own_pts = take_rows(p, own)
        model = refine(fit_plane_svd(own_pts), own_pts, params.seg_plane_threshold / 4.0, rounds=3)
        center = own_pts.mean(axis=0)
        nrm = model.normal if model.normal @ center < 0 else -model.normal
        d = model.d if nrm @ model.normal > 0 else -model.d
        planes[sid] = (nrm, d)
        obj_pts = labels[finite] >= len(supports)
        near = obj_pts & (np.abs(p @ nrm + d) <= params.seg_plane_threshold)
        labels[finite[near]] = sid
    timing["seg_objects_s"] = time.perf_counter() - t2
    timing["segmentation_s"] = time.perf_counter() - t0
    return Segmentation(labels, list(range(len(supports))), timing, planes)
