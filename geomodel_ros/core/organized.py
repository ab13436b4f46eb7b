"""Organized fast path of the segmentation: working cloud, neighbours and normals from the image.

An organized cloud (H x W pixels, NaN where the sensor had no return) already says which
points are neighbours, so the segmentation needs neither a voxel grid nor a nearest-neighbour
search (the two costs of :func:`~geomodel_ros.core.faces.voxelize` +
:func:`~geomodel_ros.core.faces.estimate_normals` on a camera frame):

1. The image is cut into b x b pixel blocks, b chosen per frame so that neighbouring blocks
   lie about one ``seg_voxel_size`` apart on the scene's typical surface
   (:func:`block_size`). A block's working point is the mean of its pixels that lie within
   one depth jump (``seg_max_edge_factor * seg_voxel_size``) of the block's median range;
   a pixel beyond that (the other side of an object's silhouette) goes to the nearest
   working point of the 3 x 3 blocks around it, so no working point floats between a
   foreground and a background.
2. Neighbours are a fixed stencil of block offsets (the smallest disc holding at least
   ``normal_neighbors`` blocks), nearest offsets first, the block itself first. Links
   longer than a depth jump are removed: they enter neither the normals nor the neighbour
   lists (their slots hold the point itself at an infinite squared distance, which every
   consumer of the lists skips or treats as a self-link).
3. Normals and surface variation come from PCA over each point's remaining stencil
   neighbours (:func:`geomodel_ros.core.faces.smallest_eigenpairs_sym`), oriented towards
   the sensor; :meth:`GridCloud.restricted` recomputes them for a subset of the working
   points (the points left after the supports) from the same neighbour lists.

The arrays have the layout of the voxel path's (``inverse`` of every finite input row,
``counts`` of input points, (M, k) neighbours with squared distances), so the support
search, patches, border votes and joins run on them unchanged, with one difference: the
smooth patches compare normals per length (:func:`geomodel_ros.core.faces.split_faces`
with ``crease_length = seg_voxel_size``: a link shorter than a voxel may turn the normals
by its share of ``face_angle_threshold`` only). Neighbouring blocks lie ~0.8 voxel apart
and the 1-block links are shorter still; compared link by link, a concave crease that the
normals round over about a centimetre (a box stacked on a box, two cans side by side) was
crossed in several small turns (osd_learn with the defaults, ``python -m
geomodel_ros.tools.bench_organized --part osd --defaults``: 92.0 % of the objects with
IoU >= 0.8 link by link, 97.3 % per length, voxel path 98.2 %).

The stencil is a disc of blocks in the image, not the k nearest points in metres as on the
voxel path. Image blocks sample a surface seen at a slant more sparsely per area than a
voxel grid does, so the k nearest points in metres lean towards the frontal surface at a
crease; measured with the defaults on osd_learn, the k nearest of a 3k-offset stencil
(normals and lists) matched the voxel path's normals slightly better (angle to the nearest
voxel point's normal, median / 90th percentile 3.6 / 7.9 deg against 3.7 / 8.4) but let
the stacked boxes grow into one smooth patch (87.5 % of the objects with IoU >= 0.8);
weighting the points by the area of their blocks, or bounding the stencil's links by a
radius in metres, gave 89-94 %. The separation of touching objects on this path rests on
the stencil's neighbourhood together with the crease test per length.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import csr_matrix

from geomodel_ros.core.faces import smallest_eigenpairs_sym
from geomodel_ros.core.fastmath import centroid, take_rows
from geomodel_ros.core.params import ModelingParams

__all__ = ["GridCloud", "block_size", "grid_cloud", "stencil_offsets"]

#: Pixel spacing is measured on every this-many-th image row and column (a regular subset
#: of about 1/16 of the pixel pairs estimates a median as well as all of them).
SPACING_STRIDE = 4
#: Fewest finite adjacent-pixel pairs from which a spacing is estimated; with fewer the
#: cloud takes the voxel path.
MIN_SPACING_PAIRS = 16
#: Neighbouring blocks lie this share of a voxel apart, so that a surface holds as many
#: working points as on the voxel grid (counts of working points measure areas, e.g. of a
#: support): a plane of unit normal n crosses about (|nx| + |ny| + |nz|) / voxel^2 voxels
#: per unit area, 3/2 / voxel^2 on average over all orientations, hence sqrt(2/3).
BLOCK_SPACING_SHARE = math.sqrt(2.0 / 3.0)
#: Largest block edge [px]: beyond it a block spans so many pixels that the image grid
#: hardly helps (a 64-pixel block of a camera frame is a handful of working points).
MAX_BLOCK = 64


@dataclass
class GridCloud:
    """Working cloud of an organized scene, with neighbours and normals.

    Attributes
    ----------
    points : (M, 3) float64 array [m]
        Working points (means of pixel blocks).
    inverse : (F,) int64 array
        Working point of every finite input row (in the order of the rows given).
    counts : (M,) int64 array
        Input points per working point.
    normals : (M, 3) float64 array
        Unit normals, oriented towards the sensor (the origin).
    variation : (M,) float64 array
        Surface variation lambda_min / trace in [0, 1/3].
    neighbors : (M, k) int64 array
        Stencil neighbours, nearest offsets first, the point itself first; removed links
        hold the point itself.
    sqdist : (M, k) float64 array [m^2]
        Squared distances to the neighbours, ``inf`` for removed links.
    block : int
        Block edge b [px].
    """

    points: NDArray[np.float64]
    inverse: NDArray[np.int64]
    counts: NDArray[np.int64]
    normals: NDArray[np.float64]
    variation: NDArray[np.float64]
    neighbors: NDArray[np.int64]
    sqdist: NDArray[np.float64]
    block: int

    def restricted(self, subset: NDArray[np.int64]) -> tuple[NDArray, ...]:
        """Return normals and neighbours of the working points ``subset`` (S,) among themselves.

        Links to points outside ``subset`` are removed (point itself, ``inf``) and the
        normals are estimated again from the links left, so that a point beside a removed
        support does not blend into it.

        Returns
        -------
        normals : (S, 3) float64 array
        variation : (S,) float64 array
        neighbors : (S, k) int64 array
            Indices into ``subset``.
        sqdist : (S, k) float64 array [m^2]
        """
        local = np.full(len(self.points), -1, dtype=np.int64)
        local[subset] = np.arange(len(subset))
        nb = local[take_rows(self.neighbors, subset)]
        sq = take_rows(self.sqdist, subset)
        keep = (nb >= 0) & np.isfinite(sq)
        nb, sq = _without_links(nb, sq, keep)
        pts = take_rows(self.points, subset)
        normals, variation = _stencil_normals(pts, nb, keep)
        return normals, variation, nb, sq


def stencil_offsets(k: int) -> NDArray[np.int64]:
    """Block offsets (dr, dc) of the smallest disc that holds at least ``k`` of them.

    Returns
    -------
    (K, 2) int64 array
        Offsets sorted by length (ties in row-major order), (0, 0) first.
    """
    radius = max(1, math.ceil(math.sqrt(k / math.pi)))
    r = np.arange(-radius - 1, radius + 2)
    dr, dc = (v.ravel() for v in np.meshgrid(r, r, indexing="ij"))
    sq = dr * dr + dc * dc
    order = np.lexsort((dc, dr, sq))
    dr, dc, sq = dr[order], dc[order], sq[order]
    cut = sq[min(k, len(sq)) - 1]
    return np.column_stack([dr[sq <= cut], dc[sq <= cut]]).astype(np.int64)


def block_size(image: NDArray[np.float64], voxel: float) -> int | None:
    """Block edge b [px] at which neighbouring blocks lie about ``voxel`` [m] apart.

    The spacing of the scene's surfaces is the median distance between horizontally and
    vertically adjacent finite pixels of ``image`` (H, W, 3) [m] (a regular subset of rows
    and columns). None when too few adjacent pixels are finite to tell.
    """
    sub = image[::SPACING_STRIDE]
    steps = [_step_lengths(sub[:, 1:], sub[:, :-1])]
    sub = image[:, ::SPACING_STRIDE]
    steps.append(_step_lengths(sub[1:], sub[:-1]))
    d = np.concatenate(steps)
    d = d[np.isfinite(d)]
    if len(d) < MIN_SPACING_PAIRS:
        return None
    spacing = float(np.median(d))
    if spacing <= 0.0:
        return None
    return int(min(MAX_BLOCK, max(1, round(voxel * BLOCK_SPACING_SHARE / spacing))))


def _step_lengths(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distances [m] between the pixels of ``a`` and ``b`` (R, C, 3), flattened (R * C,).

    Coordinate by coordinate (numpy's norm over the short last axis is several times
    slower; the sum is the same, x^2 + y^2 first).
    """
    sq = np.zeros(a.shape[:2])
    for axis in range(3):
        diff = a[:, :, axis] - b[:, :, axis]
        sq += diff * diff
    return np.sqrt(sq).ravel()


def grid_cloud(points: NDArray[np.float64], shape: tuple[int, int], finite: NDArray[np.int64],
               params: ModelingParams) -> GridCloud | None:
    """Working cloud, neighbours and normals of an organized cloud (see the module doc).

    Parameters
    ----------
    points : (H * W, 3) float64 array [m]
        Row-major pixels, non-finite where there is no usable return.
    shape : (H, W)
        Image size [px].
    finite : (F,) int64 array
        The finite rows of ``points``, increasing.
    params : ModelingParams
        ``seg_voxel_size``, ``seg_max_edge_factor`` and ``normal_neighbors`` are used.

    Returns
    -------
    GridCloud, or None when the pixel spacing cannot be measured (too few adjacent finite
    pixels): the caller then takes the voxel path.
    """
    h, w = shape
    image = points.reshape(h, w, 3)
    b = block_size(image, params.seg_voxel_size)
    if b is None:
        return None
    jump = params.seg_max_edge_factor * params.seg_voxel_size
    hb, wb = -(-h // b), -(-w // b)
    row, col = finite // w, finite % w
    blk = (row // b) * wb + col // b
    p = take_rows(points, finite)
    dist = np.sqrt(np.einsum("ij,ij->i", p, p))
    in_layer = np.abs(dist - _block_medians(dist, row, col, (hb, wb, b))[blk]) <= jump
    ids = np.full(hb * wb, -1, dtype=np.int64)
    used = np.flatnonzero(np.bincount(blk, minlength=hb * wb))
    ids[used] = np.arange(len(used))
    inverse = ids[blk]
    ref = _means(take_rows(p, in_layer), inverse[in_layer], len(used))
    away = np.flatnonzero(~in_layer)
    if len(away):
        inverse[away] = _nearest_block(take_rows(p, away), blk[away], ids.reshape(hb, wb),
                                       ref, wb)
    counts = np.bincount(inverse, minlength=len(used))
    wp = _means(p, inverse, len(used))
    offsets = stencil_offsets(params.normal_neighbors)
    nb, sq = _stencil_links(wp, ids.reshape(hb, wb), used, offsets)
    # A link spans a depth jump when it is longer than a jump per block of its offset (a
    # slanted surface stretches the long offsets' links too: a fixed bound would cut them).
    reach = jump * np.maximum(np.sqrt((offsets * offsets).sum(axis=1)), 1.0)
    keep = sq <= (reach * reach)[None, :]
    nb, sq = _without_links(nb, sq, keep)
    normals, variation = _stencil_normals(wp, nb, keep)
    return GridCloud(wp, inverse, counts, normals, variation, nb, sq, b)


def _block_medians(values: NDArray[np.float64], row: NDArray[np.int64], col: NDArray[np.int64],
                   grid: tuple[int, int, int]) -> NDArray[np.float64]:
    """Lower median of ``values`` (F,) at pixels (``row``, ``col``) per b x b block.

    ``grid`` is (Hb, Wb, b); returns (Hb * Wb,) medians, NaN for blocks without a pixel.
    The pixels are laid out block by block ((Hb * Wb, b * b), empty slots inf) and each
    block's row sorted: b * b values per block, cheaper than one sort of all pixels.
    """
    hb, wb, b = grid
    table = np.full((hb, b, wb, b), np.inf)
    # Laid out as the image padded to (Hb * b, Wb * b): pixel (row, col) is one flat index.
    table.reshape(-1)[row * (wb * b) + col] = values
    table = table.transpose(0, 2, 1, 3).reshape(hb * wb, b * b)
    table.sort(axis=1)
    sizes = np.count_nonzero(np.isfinite(table), axis=1)
    med = table[np.arange(hb * wb), (np.maximum(sizes, 1) - 1) // 2]
    med[sizes == 0] = np.nan
    return med


def _means(p: NDArray[np.float64], group: NDArray[np.int64], n: int) -> NDArray[np.float64]:
    """Mean of the rows of ``p`` (F, 3) per ``group`` (F,) of ``n`` (empty groups: NaN)."""
    counts = np.bincount(group, minlength=n).astype(np.float64)
    out = np.empty((n, 3))
    for axis in range(3):
        out[:, axis] = np.bincount(group, weights=p[:, axis], minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        out /= counts[:, None]
    return out


def _nearest_block(p: NDArray[np.float64], blk: NDArray[np.int64], grid_ids: NDArray[np.int64],
                   ref: NDArray[np.float64], wb: int) -> NDArray[np.int64]:
    """Working point nearest to each pixel ``p`` (A, 3) among the 3 x 3 blocks around it.

    ``blk`` (A,) are the pixels' own blocks, ``grid_ids`` (Hb, Wb) the working point of
    every block (-1 for none), ``ref`` (M, 3) the working points' layer means [m] (NaN for
    a block without one).
    """
    padded = np.pad(grid_ids, 1, constant_values=-1)
    br, bc = blk // wb + 1, blk % wb + 1
    cand = np.stack([padded[br + dr, bc + dc] for dr in (-1, 0, 1) for dc in (-1, 0, 1)],
                    axis=1)
    pos = ref[np.maximum(cand, 0)]
    d2 = np.einsum("akj,akj->ak", pos - p[:, None, :], pos - p[:, None, :])
    d2[(cand < 0) | ~np.isfinite(d2)] = np.inf
    return cand[np.arange(len(p)), np.argmin(d2, axis=1)]


def _stencil_links(wp: NDArray[np.float64], grid_ids: NDArray[np.int64],
                   used: NDArray[np.int64], offsets: NDArray[np.int64]
                   ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Neighbours (M, K) of every working point over the block ``offsets`` (K, 2).

    ``grid_ids`` (Hb, Wb) hold the working point of every block (-1: none) and ``used``
    (M,) the flat block of every working point. Missing neighbours are -1; the squared
    distances [m^2] of the links are ``inf`` for them. One gather of the padded block grid
    per link, over the working points only (not over every block of the image).
    """
    hb, wb = grid_ids.shape
    pad = int(np.abs(offsets).max())
    ids = np.pad(grid_ids, pad, constant_values=-1).ravel()
    wide = wb + 2 * pad
    # Flat index of every working point's block in the padded grid, and of every offset.
    home = (used // wb + pad) * wide + (used % wb + pad)
    shift = offsets[:, 0] * wide + offsets[:, 1]
    nb = ids[home[:, None] + shift[None, :]]
    sq = np.zeros(nb.shape)
    for axis in range(3):
        col = np.ascontiguousarray(wp[:, axis])
        diff = col[nb] - col[:, None]        # a missing neighbour (-1) is set to inf below
        sq += diff * diff
    sq[nb < 0] = np.inf
    return nb, sq


def _without_links(nb: NDArray[np.int64], sq: NDArray[np.float64], keep: NDArray[np.bool_]
                   ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """``nb``, ``sq`` (M, K) with the links not in ``keep`` set to the point itself and inf."""
    self_idx = np.broadcast_to(np.arange(len(nb))[:, None], nb.shape)
    return np.where(keep, nb, self_idx), np.where(keep, sq, np.inf)


def _stencil_normals(points: NDArray[np.float64], nb: NDArray[np.int64],
                     keep: NDArray[np.bool_]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """PCA normals (M, 3) and surface variation (M,) over each point's kept links.

    ``nb`` (M, K) are the neighbours and ``keep`` (M, K) the links to use (the point
    itself is always among them); normals point towards the origin.
    """
    m = len(points)
    rows = keep.sum(axis=1)
    indptr = np.zeros(m + 1, dtype=np.int64)
    np.cumsum(rows, out=indptr[1:])
    weights = np.repeat(1.0 / np.maximum(rows, 1), rows)
    incidence = csr_matrix((weights, nb[keep], indptr), shape=(m, m))
    q = points - centroid(points)
    x, y, z = q[:, 0], q[:, 1], q[:, 2]
    s = incidence @ np.column_stack([x, y, z, x * x, x * y, x * z, y * y, y * z, z * z])
    mx, my, mz = s[:, 0], s[:, 1], s[:, 2]
    xx, xy, xz = s[:, 3] - mx * mx, s[:, 4] - mx * my, s[:, 5] - mx * mz
    yy, yz, zz = s[:, 6] - my * my, s[:, 7] - my * mz, s[:, 8] - mz * mz
    lam, normals = smallest_eigenpairs_sym(xx, xy, xz, yy, yz, zz)
    total = xx + yy + zz
    variation = np.divide(lam, total, out=np.zeros(m), where=total > 0)
    normals[np.einsum("ij,ij->i", normals, points) > 0] *= -1
    return normals, variation
