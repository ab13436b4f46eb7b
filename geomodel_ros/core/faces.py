"""Working cloud and smooth faces of one object.

An object's points are reduced to a voxel grid (the *working cloud*) on which normals,
surface variation and neighbourhoods are computed once. Faces are the connected
components of the neighbourhood graph restricted to smooth, non-edge links (region
growing done as a graph problem with :mod:`scipy.sparse.csgraph`); edge points and
slivers join the face of their nearest face point. Face adjacency comes from the same
neighbourhood graph.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

from geomodel_ros.core.errors import InputError
from geomodel_ros.core.fastmath import centroid, knn, link_components, robust_sigma, take_rows
from geomodel_ros.core.ransac import PlaneModel, fit_plane_svd, refine

__all__ = ["WorkingCloud", "FaceSet", "voxelize", "count_voxels", "estimate_normals",
           "build_working_cloud",
           "smallest_eigenpairs", "smallest_eigenpairs_sym", "neighborhood_moments",
           "split_faces", "face_labels", "faces_from_labels", "pca_normals", "working_voxel_size",
           "split_plane_unions", "face_plane", "link_folds"]


#: Voxel boxes of up to this many cells, or of up to DENSE_CELLS_PER_POINT cells per
#: point, are counted in a dense table (sorting is used for sparser boxes).
DENSE_CELLS = 1 << 22
DENSE_CELLS_PER_POINT = 8
#: Keys in which at most this share of the neighbouring pairs descend are sorted with a
#: stable sort (timsort, linear on its long ascending runs): a sensor's cloud comes in scan
#: order, whose consecutive points mostly share or follow their voxel (a Kinect frame's
#: 194k keys: 3.7 ms against quicksort's 11.1 ms); keys in random order take quicksort
#: (11.3 ms against the stable sort's 14.0 ms on the same keys shuffled). A quarter: far
#: from both (a scan-order frame has a few per cent descents, random keys a half).
PRESORTED_DESCENTS = 0.25
#: At least this many keys below 2**(2 * RADIX_DIGIT_BITS) are sorted by their two
#: RADIX_DIGIT_BITS-bit digits instead, low digit first, each with numpy's stable sort
#: (a radix sort, linear in the keys, for 16-bit integers): the same order as one stable
#: sort of the keys. Measured (CPU, keys of a Kinect frame at the 4 mm grid, up to 1.1e7):
#: 194k keys in scan order 3.0 ms against the stable sort's 3.3 ms, shuffled 2.9 against
#: quicksort's 11.1 ms; 60k keys 0.62 / 0.92 and 0.57 / 2.8 ms; below about 30k keys in
#: scan order the two passes over the digits' 65,536 buckets cost more than they save
#: (10k: 0.10 / 0.06 ms).
RADIX_MIN_KEYS = 20000
RADIX_DIGIT_BITS = 16
#: Largest number of voxel keys (cells of the occupied box times groups) and largest cell
#: index [voxels] :func:`voxelize` accepts: keys are int64, and 2**62 leaves room for the
#: products and sums that build them (larger boxes raise InputError instead of overflowing).
MAX_GRID_KEYS = float(2 ** 62)
#: Eigenvectors from cross products of rows of A - lambda I (scaled to entries <= 1) whose
#: norm is below this are ill-determined (a repeated smallest eigenvalue): those matrices
#: go to :func:`numpy.linalg.eigh` instead.
_MIN_CROSS_NORM = 1e-8
#: Floor of the scale that normalises a matrix's entries (all-zero matrices stay finite).
_TINY_SCALE = 1e-300
#: Faces touch when at least this many neighbour links join them (one stray link between
#: two faces is noise).
MIN_ADJACENCY_LINKS = 2
#: The nearest-face search of :func:`_relabel_small` runs on all cores only from this many
#: queries on: starting the threads costs more than they save below it (2 cores, one
#: nearest point in a tree of 8,000: 1,000 queries 0.52 ms on one thread, 0.59 ms on
#: both; 3,000 1.76 / 1.99 ms; 10,000 5.8 / 3.2 ms). Segments and objects have a few
#: hundred to a few thousand points off their large faces. Each query is answered on its
#: own, so the thread count changes no result.
THREADED_QUERIES = 5000
#: :func:`pca_normals` computes clouds of at least this many points in two halves, the
#: second on a thread of its own (scipy's sparse product and numpy's loops over the rows
#: release the GIL). Every row's normal is computed from its own neighbourhood alone, so
#: the halves give the same bits. Measured (2 cores, load average about 3.5; a Kinect
#: frame's 55-65k working points, 16 neighbours): 11.8-14.1 ms on one thread, 8.1-9.6 on
#: two; 5,000 points 1.1 / 1.8 ms, 10,000-20,000 points 0.5-0.8 ms saved (load 3-7).
#: When the other core is busy the halves take as long as one thread.
THREADED_NORMALS = 20000
#: An object whose voxelization fills more than this many times ``max_points`` voxels is
#: voxelized once more, coarser (the estimate of :func:`working_voxel_size` missed).
REVOXELIZE_FACTOR = 1.5
#: :func:`working_voxel_size` voxelizes a regular subset of about this many times
#: ``max_points`` points.
SUBSET_POINTS_FACTOR = 4
#: The Poisson occupancy estimate is iterated until it changes by less than this share
#: (or at most _OCCUPANCY_ITERATIONS times; it converges in a few).
_OCCUPANCY_TOLERANCE = 1e-3
_OCCUPANCY_ITERATIONS = 50
#: A face whose plane spread (robust sigma) is at most this share of the RANSAC threshold
#: is flat whatever its CF.
FLAT_SPREAD_SHARE = 0.5
#: A face taken apart into planes must hold at least two (and, like a box's visible
#: sides, at most three) mutually perpendicular planes.
MIN_UNION_PLANES = 2
MAX_UNION_PLANES = 3
#: Point normals of a face whose mean is shorter than this cancel out (no direction to
#: fall back on).
_MIN_MEAN_NORMAL = 1e-9


def _grid_spans(low: NDArray[np.float64], high: NDArray[np.float64], voxel_size: float,
                groups: NDArray[np.int64] | None) -> list[int]:
    """Cells per axis of the voxel box from its lowest and highest cell indices (3,).

    The indices are floats (the floor of coordinate / voxel_size); they are checked in
    floats, before any integer arithmetic, so that a box whose cell keys (one per cell and
    group) do not fit in int64 raises :class:`InputError` instead of overflowing.
    """
    spans = high - low + 1.0
    keys = float(np.prod(spans))
    if groups is not None:
        keys *= float(groups.max()) - float(groups.min()) + 1.0
    extreme = float(max(np.max(np.abs(low)), np.max(np.abs(high))))
    if not (math.isfinite(keys) and keys <= MAX_GRID_KEYS and extreme <= MAX_GRID_KEYS):
        extent = (high - low) * voxel_size
        raise InputError(
            f"points too large for a voxel grid: they span {np.array2string(extent, precision=3)}"
            f" m (up to {extreme * voxel_size:.3g} m from the origin); at a voxel of "
            f"{voxel_size:g} m that needs {keys:.3g} cells, at most {MAX_GRID_KEYS:.3g} are "
            f"allowed: lower max_range or raise voxel_size / seg_voxel_size")
    return [int(v) for v in spans]


def _cell_keys(pt: NDArray[np.float64], voxel_size: float,
               groups: NDArray[np.int64] | None) -> NDArray[np.int64]:
    """One int64 key per point of ``pt`` (3, N) [m]: its voxel (and group), from 0.

    Integer cell coordinates shifted to start at 0, flattened row-major over the occupied
    box (then over the groups); the box is checked in floats first (:func:`_grid_spans`).
    """
    scaled = pt * (1.0 / voxel_size)
    np.floor(scaled, out=scaled)
    g = None if groups is None else np.asarray(groups, dtype=np.int64)
    low = scaled.min(axis=1, keepdims=True)
    span = _grid_spans(low.ravel(), scaled.max(axis=1), voxel_size, g)
    cols = scaled.astype(np.int64)
    del scaled
    cols -= low.astype(np.int64)
    flat = cols[0] * (span[1] * span[2])
    flat += cols[1] * span[2]
    flat += cols[2]
    del cols
    if g is not None:
        g = g - g.min()
        flat += (span[0] * span[1] * span[2]) * g
    return flat


def count_voxels(points: NDArray[np.float64], voxel_size: float) -> int:
    """Count the voxels of edge ``voxel_size`` [m] that ``points`` (N, 3) [m] occupy.

    The count of :func:`voxelize` without its centroids and inverse (a plain sort instead
    of a sort with inverse on sparse boxes: several times faster on millions of points).
    """
    if len(points) == 0:
        return 0
    flat = _cell_keys(np.ascontiguousarray(points.T), voxel_size, None)
    cells = int(flat.max()) + 1
    if cells <= max(DENSE_CELLS, DENSE_CELLS_PER_POINT * len(flat)):
        occupied = np.zeros(cells, dtype=bool)
        occupied[flat] = True
        return int(np.count_nonzero(occupied))
    flat.sort()
    return int(np.count_nonzero(flat[1:] != flat[:-1])) + 1


def voxelize(points: NDArray[np.float64], voxel_size: float,
             groups: NDArray[np.int64] | None = None
             ) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """Average points per voxel.

    Parameters
    ----------
    points : (N, 3) float64 array [m]
    voxel_size : float [m]
    groups : (N,) int array, optional
        Points of different groups never share a voxel (e.g. face labels).

    Returns
    -------
    centroids : (M, 3) float64 array [m]
    inverse : (N,) int64 array
        Voxel index of every input point.
    counts : (M,) int64 array
        Points per voxel.
    """
    if len(points) == 0:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    # Keys on the transposed (3, N) points: numpy is slow along the short last axis of (N, 3).
    pt = np.ascontiguousarray(points.T)
    flat = _cell_keys(pt, voxel_size, groups)
    cells = int(flat.max()) + 1
    if cells <= max(DENSE_CELLS, DENSE_CELLS_PER_POINT * len(flat)):
        # A dense table over the occupied box instead of sorting (same result as
        # np.unique, voxels in ascending key order, in linear time); small dtypes keep
        # the table's memory, which is touched sparsely, low.
        occupied_mask = np.zeros(cells, dtype=bool)
        occupied_mask[flat] = True
        occupied = np.flatnonzero(occupied_mask)
        lookup = np.empty(cells, dtype=np.int32 if occupied.size < 2 ** 31 else np.int64)
        lookup[occupied] = np.arange(occupied.size, dtype=lookup.dtype)
        inverse = lookup[flat].astype(np.int64)
        counts = np.bincount(inverse, minlength=occupied.size)
    else:
        inverse, counts = _sorted_groups(flat, cells - 1)
    m = counts.size
    centroids = np.empty((m, 3))
    for axis in range(3):
        centroids[:, axis] = np.bincount(inverse, weights=pt[axis], minlength=m)
    centroids /= counts[:, None]
    return centroids, inverse, counts


def _sorted_groups(keys: NDArray[np.int64], top: int | None = None
                   ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Group equal ``keys`` (N,): the group of every key and the group sizes.

    The groups are numbered in ascending key order: the inverse and counts of
    :func:`numpy.unique`, whatever sort is used (see :data:`PRESORTED_DESCENTS` and
    :data:`RADIX_MIN_KEYS`). ``keys`` are >= 0; ``top`` is their largest when known.
    """
    n = len(keys)
    order = _key_order(keys, int(keys.max()) if top is None else top)
    ordered = keys[order]
    first = np.empty(n, dtype=bool)
    first[0] = True
    np.not_equal(ordered[1:], ordered[:-1], out=first[1:])
    inverse = np.empty(n, dtype=np.int64)
    inverse[order] = np.cumsum(first) - 1
    return inverse, np.diff(np.append(np.flatnonzero(first), n))


def _key_order(keys: NDArray[np.int64], top: int) -> NDArray[np.int64]:
    """Return an order (N,) that sorts ``keys`` (N,) >= 0, the largest ``top``.

    Two radix passes (:data:`RADIX_MIN_KEYS`) give the stable sort's order; otherwise
    the stable sort or quicksort by how sorted the keys come (:data:`PRESORTED_DESCENTS`).
    """
    n = len(keys)
    if n >= RADIX_MIN_KEYS and top < 1 << (2 * RADIX_DIGIT_BITS):
        digit = (1 << RADIX_DIGIT_BITS) - 1
        low = np.argsort((keys & digit).astype(np.uint16), kind="stable")
        high = (keys[low] >> RADIX_DIGIT_BITS).astype(np.uint16)
        return low[np.argsort(high, kind="stable")]
    descents = np.count_nonzero(keys[1:] < keys[:-1])
    return np.argsort(keys, kind="stable" if descents <= PRESORTED_DESCENTS * n else None)


def smallest_eigenpairs(cov: NDArray[np.float64]
                        ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Smallest eigenvalue and its unit eigenvector of many symmetric 3x3 matrices.

    Parameters
    ----------
    cov : (M, 3, 3) float64 array, symmetric positive semi-definite

    Returns
    -------
    lam : (M,) float64, smallest eigenvalue
    vec : (M, 3) float64, unit eigenvectors
    """
    return smallest_eigenpairs_sym(cov[:, 0, 0], cov[:, 0, 1], cov[:, 0, 2], cov[:, 1, 1],
                                   cov[:, 1, 2], cov[:, 2, 2])


def smallest_eigenpairs_sym(xx: NDArray, xy: NDArray, xz: NDArray, yy: NDArray, yz: NDArray,
                            zz: NDArray) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Return :func:`smallest_eigenpairs` of matrices given by their six distinct entries.

    The matrices are [[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]], each entry an (M,) array.

    Closed form (trigonometric solution of the characteristic cubic, eigenvector from the
    largest cross product of two rows of A - lambda I), on flat arrays only; falls back to
    :func:`numpy.linalg.eigh` for the rare near-degenerate matrices.
    """
    scale = np.abs(xx)
    for v in (xy, xz, yy, yz, zz):
        scale = np.maximum(scale, np.abs(v))
    scale = np.maximum(scale, _TINY_SCALE)
    a, b, c, d, e, f = (v / scale for v in (xx, xy, xz, yy, yz, zz))
    q = (a + d + f) / 3.0
    a0, d0, f0 = a - q, d - q, f - q
    off = b * b + c * c + e * e
    p = np.sqrt((a0 * a0 + d0 * d0 + f0 * f0 + 2.0 * off) / 6.0)
    inv_p = 1.0 / np.where(p > 0, p, 1.0)
    ba, bb, bc, bd, be, bf = a0 * inv_p, b * inv_p, c * inv_p, d0 * inv_p, e * inv_p, f0 * inv_p
    det = ba * (bd * bf - be * be) - bb * (bb * bf - be * bc) + bc * (bb * be - bd * bc)
    phi = np.arccos(np.clip(det / 2.0, -1.0, 1.0)) / 3.0
    lam = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)   # smallest root
    # Rows of A - lam I: r0 = (a', b, c), r1 = (b, d', e), r2 = (c, e, f').
    al, dl, fl = a - lam, d - lam, f - lam
    c01 = np.stack([b * e - c * dl, c * b - al * e, al * dl - b * b])
    c02 = np.stack([b * fl - c * e, c * c - al * fl, al * e - b * c])
    c12 = np.stack([dl * fl - e * e, e * c - b * fl, b * e - dl * c])
    n01, n02, n12 = (np.einsum("ij,ij->j", v, v) for v in (c01, c02, c12))
    vec = np.where(n01 >= n02, c01, c02)
    nrm = np.maximum(n01, n02)
    vec = np.where(n12 > nrm, c12, vec)
    nrm = np.sqrt(np.maximum(nrm, n12))
    bad = nrm < _MIN_CROSS_NORM
    # Divided straight into the (M, 3) layout (a transposed copy afterwards takes longer).
    out = np.empty((len(nrm), 3))
    np.divide(vec, np.where(bad, 1.0, nrm), out=out.T)
    vec = out
    if bad.any():
        sel = np.flatnonzero(bad)
        cov = np.empty((len(sel), 3, 3))
        for (i, j), v in zip(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)),
                             (xx, xy, xz, yy, yz, zz)):
            cov[:, i, j] = cov[:, j, i] = v[sel]
        w, vv = np.linalg.eigh(cov)
        vec[sel] = vv[:, :, 0]
        lam[sel] = w[:, 0] / scale[sel]
    return np.maximum(lam, 0.0) * scale, vec


def neighborhood_moments(points: NDArray[np.float64], neighbors: NDArray[np.int64]
                         ) -> tuple[NDArray[np.float64], ...]:
    """Return the covariance entries of every point's neighbourhood.

    The entries (xx, xy, xz, yy, yz, zz), each (M,), are those of the covariance of
    ``points[neighbors[i]]`` (neighbors (M, k) int).

    Sums over the neighbourhoods are one sparse-matrix product of the neighbour
    incidence matrix with per-point monomials (coordinates taken relative to the cloud's
    centroid, which keeps the moment differences well conditioned).
    """
    return _moments(_monomials(points), neighbors)


def estimate_normals(points: NDArray[np.float64], k: int,
                     viewpoint: NDArray[np.float64] | None = None,
                     return_sqdist: bool = False,
                     neighbours: tuple[NDArray[np.int64], NDArray[np.float64]] | None = None
                     ) -> tuple[NDArray, ...]:
    """PCA normals over the ``k`` nearest neighbours, oriented towards ``viewpoint``.

    ``neighbours`` (the (M, k') nearest neighbours and their squared distances [m^2],
    nearest first) are used instead of a search when given.

    Returns
    -------
    normals : (M, 3) float64 array, unit length
    variation : (M,) float64 array
        Surface variation lambda_min / (lambda_1 + lambda_2 + lambda_3) in [0, 1/3].
    neighbors : (M, k) int64 array
        Neighbour indices, nearest first (the point itself among them).
    sqdist : (M, k) float64 array, only with ``return_sqdist``
        Squared distances [m^2] to the neighbours.
    """
    m = len(points)
    k = int(min(k, m))
    if k == 0:
        empty = (np.zeros((m, 3)), np.zeros(m), np.zeros((m, 0), dtype=np.int64))
        return (*empty, np.zeros((m, 0))) if return_sqdist else empty
    neighbors, sqdist = knn(points, k, return_sqdist=True) if neighbours is None \
        else neighbours
    normals, variation, _ = pca_normals(points, neighbors, viewpoint)
    if return_sqdist:
        return normals, variation, neighbors, sqdist
    return normals, variation, neighbors


def pca_normals(points: NDArray[np.float64], neighbors: NDArray[np.int64],
                viewpoint: NDArray[np.float64] | None = None
                ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """PCA normals of ``points`` (M, 3) [m] over their ``neighbors`` (M, k), k >= 1.

    The normals of :func:`estimate_normals` from given neighbour lists, with the smallest
    eigenvalue of every neighbourhood's covariance, which callers that test how far a
    neighbourhood lies off its plane reuse instead of computing it again.

    Returns
    -------
    normals : (M, 3) float64 array
        Unit normals oriented towards ``viewpoint`` (default the origin).
    variation : (M,) float64 array
        Surface variation lambda_min / (lambda_1 + lambda_2 + lambda_3) in [0, 1/3].
    lam : (M,) float64 array [m^2]
        Smallest eigenvalue lambda_min (the mean squared distance from the plane).

    Notes
    -----
    The covariances are those of :func:`neighborhood_moments`. From
    :data:`THREADED_NORMALS` points on, the second half of the rows is computed on a
    second thread (the same bits: no row's result depends on another's).
    """
    m = len(points)
    vp = None if viewpoint is None else np.asarray(viewpoint, dtype=np.float64)
    mono = _monomials(points)
    normals, variation, lam = np.empty((m, 3)), np.empty(m), np.empty(m)

    def rows(lo: int, hi: int) -> None:
        xx, xy, xz, yy, yz, zz = _moments(mono, neighbors[lo:hi])
        lam[lo:hi], normals[lo:hi] = smallest_eigenpairs_sym(xx, xy, xz, yy, yz, zz)
        total = xx + yy + zz
        variation[lo:hi] = 0.0
        np.divide(lam[lo:hi], total, out=variation[lo:hi], where=total > 0)
        # Towards the viewpoint: the normal's sign flipped where it points away.
        ray = points[lo:hi] if vp is None else points[lo:hi] - vp
        flip = np.einsum("mi,mi->m", normals[lo:hi], ray) > 0
        np.multiply(normals[lo:hi], -1, out=normals[lo:hi], where=flip[:, None])

    if m >= THREADED_NORMALS:
        half = m // 2
        failed: list[BaseException] = []

        def second_half() -> None:
            try:
                rows(half, m)
            except BaseException as error:  # re-raised below, on the caller's thread
                failed.append(error)

        second = threading.Thread(target=second_half)
        second.start()
        try:
            rows(0, half)
        finally:
            second.join()
        if failed:
            raise failed[0]
    else:
        rows(0, m)
    return normals, variation, lam


def _monomials(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per-point monomials of :func:`neighborhood_moments`: (M, 9) float64 array.

    Columns x, y, z, xx, xy, xz, yy, yz, zz of ``points`` (M, 3) [m] taken relative to
    their centroid.
    """
    mono = np.empty((len(points), 9))
    np.subtract(points, centroid(points), out=mono[:, :3])
    x, y, z = mono[:, 0], mono[:, 1], mono[:, 2]
    for col, (a, b) in enumerate(((x, x), (x, y), (x, z), (y, y), (y, z), (z, z)), start=3):
        np.multiply(a, b, out=mono[:, col])
    return mono


def _moments(mono: NDArray[np.float64], neighbors: NDArray[np.int64]
             ) -> tuple[NDArray[np.float64], ...]:
    """Covariance entries (xx, xy, xz, yy, yz, zz), each (R,), of R neighbourhoods.

    ``mono`` (M, 9) are the cloud's :func:`_monomials`, ``neighbors`` (R, k) rows of
    indices into it. The sums are one sparse-matrix product (as in
    :func:`neighborhood_moments`), the differences are taken on its transposed copy,
    whose rows are contiguous.
    """
    r, k = neighbors.shape
    incidence = csr_matrix((np.full(r * k, 1.0 / k), neighbors.ravel(),
                            np.arange(0, r * k + 1, k)), shape=(r, len(mono)))
    s = np.ascontiguousarray((incidence @ mono).T)
    mx, my, mz = s[0], s[1], s[2]
    square = np.empty(r)
    for row, (a, b) in enumerate(((mx, mx), (mx, my), (mx, mz), (my, my), (my, mz), (mz, mz)),
                                 start=3):
        np.multiply(a, b, out=square)
        np.subtract(s[row], square, out=s[row])
    return tuple(s[3:])


@dataclass
class WorkingCloud:
    """Voxel-reduced cloud of one object with normals and neighbourhoods.

    Attributes
    ----------
    points : (M, 3) float64 [m]
    normals : (M, 3) float64, oriented towards the sensor
    variation : (M,) float64, surface variation
    neighbors : (M, k) int64
    counts : (M,) int64, input points per working point
    point_to_working : (N,) int64, working point of each input point
    sqdist : (M, k) float64 or None, squared distances to the neighbours [m^2]
    """

    points: NDArray[np.float64]
    normals: NDArray[np.float64]
    variation: NDArray[np.float64]
    neighbors: NDArray[np.int64]
    counts: NDArray[np.int64]
    point_to_working: NDArray[np.int64]
    sqdist: NDArray[np.float64] | None = None


#: Objects with more than this many times ``max_points`` points get their working voxel
#: from a subset (:func:`working_voxel_size`); smaller ones are voxelized at the given
#: size first and only again if they fill too many voxels.
SUBSET_ESTIMATE_FACTOR = 8


def working_voxel_size(points: NDArray[np.float64], voxel_size: float, max_points: int) -> float:
    """Return the voxel edge [m] at which ``points`` fill about ``max_points`` voxels.

    ``points`` (N, 3) [m] sample a surface; the result is ``voxel_size`` or, for large
    objects, coarser.

    The occupied voxels of a regular subset estimate the count; on a surface it falls
    with the square of the voxel edge.
    """
    n = len(points)
    if n <= max_points:
        return voxel_size
    sub = points[:: max(1, n // (SUBSET_POINTS_FACTOR * max_points))]
    occupied = len(voxelize(sub, voxel_size)[2])
    # A subset misses sparsely hit voxels: with points spread evenly (Poisson), s points
    # in V voxels occupy V (1 - exp(-s / V)) of them; solve for V (it cannot exceed n).
    s, total = len(sub), float(occupied)
    for _ in range(_OCCUPANCY_ITERATIONS):
        hit = -math.expm1(-s / total)
        nxt = min(occupied / max(hit, 1e-12), float(n))
        if nxt - total <= _OCCUPANCY_TOLERANCE * total:
            total = nxt
            break
        total = nxt
    if total <= max_points:
        return voxel_size
    return voxel_size * math.sqrt(total / max_points)


def build_working_cloud(points: NDArray[np.float64], voxel_size: float, k: int,
                        groups: NDArray[np.int64] | None = None,
                        max_points: int | None = None) -> WorkingCloud:
    """Voxelize ``points`` (N, 3) [m] and estimate normals on the result.

    With ``max_points`` the voxels grow for large objects (:func:`working_voxel_size`).
    """
    if max_points is not None and len(points) > SUBSET_ESTIMATE_FACTOR * max_points:
        # Large object: choose the voxel from a subset, voxelize once.
        voxel_size = working_voxel_size(points, voxel_size, max_points)
    centroids, inverse, counts = voxelize(points, voxel_size, groups)
    if max_points is not None and len(counts) > REVOXELIZE_FACTOR * max_points:
        # An object that fills far more voxels than expected: once more, coarser.
        voxel_size *= math.sqrt(len(counts) / max_points)
        centroids, inverse, counts = voxelize(points, voxel_size, groups)
    normals, variation, neighbors = estimate_normals(centroids, k)
    return WorkingCloud(centroids, normals, variation, neighbors, counts, inverse)


@dataclass
class FaceSet:
    """Faces of one object on its working cloud.

    Attributes
    ----------
    labels : (M,) int64
        Face index of every working point (0..F-1).
    adjacency : (F, F) bool
        True where two faces touch.
    """

    labels: NDArray[np.int64]
    adjacency: NDArray[np.bool_]

    @property
    def count(self) -> int:
        return int(self.adjacency.shape[0])


def _pair_dot(v: NDArray[np.float64], neighbors: NDArray[np.int64]) -> NDArray[np.float64]:
    """Return (M, k) dot products of every row of ``v`` (M, 3) with its neighbours' rows.

    Column by column: one gather per coordinate instead of two (M*k, 3) gathers.
    """
    out = np.zeros(neighbors.shape)
    for a in range(v.shape[1]):
        col = np.ascontiguousarray(v[:, a])
        out += col[neighbors] * col[:, None]
    return out


def _pair_sqdist(p: NDArray[np.float64], neighbors: NDArray[np.int64]) -> NDArray[np.float64]:
    """Return (M, k) squared distances of every point of ``p`` (M, 3) to its neighbours."""
    out = np.zeros(neighbors.shape)
    for a in range(p.shape[1]):
        col = np.ascontiguousarray(p[:, a])
        d = col[neighbors] - col[:, None]
        out += d * d
    return out


def _adjacency(labels: NDArray[np.int64], neighbors: NDArray[np.int64], n_faces: int,
               min_links: int = MIN_ADJACENCY_LINKS) -> NDArray[np.bool_]:
    a = np.repeat(labels, neighbors.shape[1])
    b = labels[neighbors.ravel()]
    cross = a != b
    links = np.zeros((n_faces, n_faces), dtype=np.int64)
    np.add.at(links, (a[cross], b[cross]), 1)
    links = links + links.T
    return links >= min_links


def _relabel_small(labels: NDArray[np.int64], points: NDArray[np.float64], min_size: int
                   ) -> NDArray[np.int64]:
    """Give points of faces smaller than ``min_size`` (and label -1) their nearest big face.

    ``labels`` (M,) are -1 or face ids 0, 1, ...; the big faces are renumbered 0, 1, ... in
    the order of their ids (``np.unique``'s), counted instead of sorted.
    """
    sizes = np.bincount(labels + 1)
    # Indexed by label + 1, so that -1 (no face) is never big.
    big = (sizes >= max(min_size, 1)) & (np.arange(len(sizes)) > 0)
    if not big.any():
        return np.zeros(len(labels), dtype=np.int64)
    keep = big[labels + 1]
    out = labels.copy()
    if not keep.all():
        tree = cKDTree(points[keep])
        queries = points[~keep]
        _, j = tree.query(queries, k=1, workers=-1 if len(queries) >= THREADED_QUERIES else 1)
        out[~keep] = labels[keep][j]
    rank = np.cumsum(big) - 1
    return rank[out + 1].astype(np.int64)


def split_faces(cloud: WorkingCloud, angle_threshold: float, edge_variation: float,
                min_face_points: int, max_edge: float | None = None,
                crease_length: float | None = None) -> FaceSet:
    """Split the working cloud into smooth faces: :func:`face_labels` and which faces touch."""
    labels = face_labels(cloud, angle_threshold, edge_variation, min_face_points, max_edge,
                         crease_length)
    n_faces = int(labels.max()) + 1 if labels.size else 0
    return FaceSet(labels, _adjacency(labels, cloud.neighbors, n_faces))


def face_labels(cloud: WorkingCloud, angle_threshold: float, edge_variation: float,
                min_face_points: int, max_edge: float | None = None,
                crease_length: float | None = None,
                planar: NDArray[np.bool_] | None = None) -> NDArray[np.int64]:
    """Label the smooth faces of the working cloud: (M,) int64, faces 0 .. F-1.

    Neighbouring non-edge points whose normals differ by less than ``angle_threshold``
    [rad] are linked; faces are the connected components with at least
    ``min_face_points`` points. Edge points (surface variation above ``edge_variation``)
    and smaller components are assigned to the face of their nearest face point. With
    ``max_edge`` [m], neighbours farther apart (across a depth jump) are never linked.

    With ``crease_length`` [m], a link shorter than it may turn the normals by only its
    share of ``angle_threshold`` (length / ``crease_length``): the threshold is then a
    turn per ``crease_length`` of surface, whatever the spacing of the working points.
    Without it the test is per link, and its tolerance to curvature grows as the points
    get denser: a crease that the normals round over about a centimetre is crossed in
    several small turns by links much shorter than ``crease_length``
    (:func:`_link_angle_limits`).

    With ``planar`` (M,) bool, the points it marks are never edge points: their
    neighbourhoods lie on a plane within the noise, which alone raised their variation.
    """
    m, k = cloud.neighbors.shape
    if m == 0:
        return np.zeros(0, dtype=np.int64)
    smooth = cloud.variation <= edge_variation
    if planar is not None:
        smooth |= planar
    nb = cloud.neighbors
    cos = _pair_dot(cloud.normals, nb)
    np.abs(cos, out=cos)
    d2 = None
    if max_edge is not None or crease_length is not None:
        d2 = cloud.sqdist if cloud.sqdist is not None else _pair_sqdist(cloud.points, nb)
    limit = np.cos(angle_threshold) if crease_length is None else \
        _link_angle_limits(d2, angle_threshold, crease_length)
    keep = (cos >= limit) & smooth[nb] & smooth[:, None] & (nb != np.arange(m)[:, None])
    if max_edge is not None:
        keep &= d2 <= max_edge * max_edge
    _, comp = link_components(nb, keep)
    comp = np.where(smooth, comp, -1).astype(np.int64)
    return _relabel_small(comp, cloud.points, min_face_points)


def _link_angle_limits(sqdist: NDArray[np.float64], angle_threshold: float,
                       crease_length: float) -> NDArray[np.float64]:
    """Return the cosine (M, k) of the largest normal turn allowed on each link.

    A link of squared length ``sqdist`` [m^2] (``inf`` for a removed link) shorter than
    ``crease_length`` [m] may turn by ``angle_threshold`` [rad] times length /
    ``crease_length``; longer links by ``angle_threshold``. Links of length 0 (the point
    itself) allow no turn.
    """
    share = np.sqrt(sqdist, where=np.isfinite(sqdist), out=np.full(sqdist.shape, np.inf))
    share *= 1.0 / crease_length
    np.minimum(share, 1.0, out=share)
    share *= angle_threshold
    return np.cos(share)


#: Normals within this angle [rad] of a plane's normal count as lying on it when a
#: non-planar face is taken apart into planes (:func:`split_plane_unions`).
UNION_NORMAL_ANGLE = math.radians(15.0)
#: Share of a face's points the planes must hold between them to replace it.
UNION_COVERAGE = 0.75
#: Candidate plane directions tried per face (a regular subset of its normals).
UNION_CANDIDATES = 64


def _plane_parts(points: NDArray[np.float64], normals: NDArray[np.float64], threshold: float,
                 perpendicular_tolerance: float, min_points: int
                 ) -> list[NDArray[np.int64]] | None:
    """Return indices of two or three perpendicular planes that hold most of a face.

    None when there are no such planes.

    The plane of each step is the direction most normals agree with (within
    UNION_NORMAL_ANGLE), refitted to those points; its members are the points within
    ``threshold`` [m] of it whose normals agree. A round surface (cylinder, cone,
    sphere) has no two perpendicular planes that hold UNION_COVERAGE of it: its normals
    turn steadily, so each direction holds only a narrow strip.
    """
    m = len(points)
    cos_n = math.cos(UNION_NORMAL_ANGLE)
    rest = np.arange(m)
    parts: list[NDArray[np.int64]] = []
    axes: list[NDArray[np.float64]] = []
    for _ in range(MAX_UNION_PLANES):
        if len(rest) < min_points:
            break
        nr = normals[rest]
        cand = nr[:: max(1, len(rest) // UNION_CANDIDATES)]
        agree = np.abs(cand @ nr.T) >= cos_n
        best = int(np.argmax(agree.sum(axis=1)))
        sel = rest[agree[best]]
        if len(sel) < min_points:
            break
        plane = fit_plane_svd(points[sel])
        on = (np.abs(points[rest] @ plane.normal + plane.d) <= threshold) \
            & (np.abs(nr @ plane.normal) >= cos_n)
        if on.sum() < min_points:
            break
        if any(abs(float(plane.normal @ a)) > math.sin(perpendicular_tolerance) for a in axes):
            break
        parts.append(rest[on])
        axes.append(plane.normal)
        rest = rest[~on]
    if len(parts) < MIN_UNION_PLANES or sum(len(p) for p in parts) < UNION_COVERAGE * m:
        return None
    return parts


def face_plane(points: NDArray[np.float64], normals: NDArray[np.float64], threshold: float
                ) -> tuple[PlaneModel, float]:
    """Return the plane of a face's working points (M, 3) and its robust spread [m].

    The spread is MAD-based, so that a few flying pixels do not make a flat face curved.

    Least squares first; when its spread exceeds half of ``threshold`` [m] (strays far
    off the face, e.g. flying pixels behind a small box, can tilt the least-squares
    plane by tens of degrees), the plane through the median along the points' mean
    normal, refined on its inliers, is taken if it fits tighter.
    """
    if len(points) < 3:
        return PlaneModel(np.array([0, 0, 1.0]), 0.0), 0.0
    plane = fit_plane_svd(points)
    spread = robust_sigma(plane.distance(points))
    if spread <= threshold * FLAT_SPREAD_SHARE:
        return plane, spread
    mean = centroid(normals)
    norm = float(np.linalg.norm(mean))
    if norm <= _MIN_MEAN_NORMAL:
        return plane, spread
    mean /= norm
    alt = refine(PlaneModel(mean, -float(np.median(points @ mean))), points, threshold)
    alt_spread = robust_sigma(alt.distance(points))
    return (alt, alt_spread) if alt_spread < spread else (plane, spread)


def split_plane_unions(cloud: WorkingCloud, faces: FaceSet, threshold: float,
                       perpendicular_tolerance: float, min_face_points: int,
                       planes: dict[int, tuple[PlaneModel, float]] | None = None) -> FaceSet:
    """Take apart faces that are two or three perpendicular planes grown together.

    On real sensor data the normals turn gradually across a box's edge (depth noise,
    the normal neighbourhood straddles the edge), so region growing can run round it
    and join two or three sides of a box into one face that no plane fits. Every face
    no plane fits to within half of ``threshold`` [m] (:func:`face_plane`) is tried: when two or
    three mutually perpendicular planes (within ``perpendicular_tolerance`` [rad] of
    90 degrees) hold most of its points, each becomes a face of its own and the rest of
    its points (the rounded edge) join the nearest one.

    ``planes``, when given, receives face id -> :func:`face_plane` of every face whose
    plane was fitted here and that is left whole (its working points, in ascending
    order, are those of the face of that id in the result), for callers that need the
    same plane again.
    """
    labels = faces.labels.copy()
    top = faces.count
    changed = False
    for f in range(faces.count):
        w = np.flatnonzero(labels == f)
        if len(w) < MIN_UNION_PLANES * min_face_points:
            continue
        pts = cloud.points[w]
        fitted = face_plane(pts, cloud.normals[w], threshold)
        if planes is not None:
            planes[f] = fitted
        if fitted[1] <= threshold * FLAT_SPREAD_SHARE:
            continue  # the spread that makes a face planar whatever its CF
        parts = _plane_parts(pts, cloud.normals[w], threshold, perpendicular_tolerance,
                             min_face_points)
        if parts is None:
            continue
        if planes is not None:
            del planes[f]
        local = np.full(len(w), -1, dtype=np.int64)
        for i, part in enumerate(parts):
            local[part] = i
        loose = local < 0
        if loose.any():
            # The points between the planes (the rounded edge) join the nearest plane.
            _, j = cKDTree(pts[~loose]).query(pts[loose], k=1)
            local[loose] = local[~loose][j]
        labels[w] = np.where(local == 0, f, top + local - 1)
        top += len(parts) - 1
        changed = True
    if not changed:
        return faces
    return FaceSet(labels, _adjacency(labels, cloud.neighbors, top))


def faces_from_labels(cloud: WorkingCloud, point_face_labels: NDArray[np.int64]) -> FaceSet:
    """Faces given per input point (the working cloud must be built with them as groups)."""
    wl = np.zeros(len(cloud.points), dtype=np.int64)
    wl[cloud.point_to_working] = point_face_labels
    _, compact = np.unique(wl, return_inverse=True)
    compact = compact.ravel().astype(np.int64)
    n_faces = int(compact.max()) + 1 if compact.size else 0
    return FaceSet(compact, _adjacency(compact, cloud.neighbors, n_faces))


def link_folds(points: NDArray[np.float64], normals: NDArray[np.float64],
               i: NDArray[np.int64], j: NDArray[np.int64]) -> NDArray[np.float64]:
    """Fold [m] (L,) of the links i -> j (L,) between ``points`` (M, 3) [m].

    (below_i + below_j) / 2, each point's height below the other's tangent plane along
    its unit normal (``normals`` (M, 3), oriented towards the sensor): about l^2 / (2 r)
    on a surface of radius r bent away from the sensor (seen from outside), 0 on a plane,
    negative on a surface bent towards it (seen from inside).
    """
    d = take_rows(points, i) - take_rows(points, j)
    return 0.5 * (np.einsum("ij,ij->i", take_rows(normals, i), d)
                  - np.einsum("ij,ij->i", take_rows(normals, j), d))
