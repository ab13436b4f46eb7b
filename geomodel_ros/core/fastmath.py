"""Fast forms of a few numpy reductions over point arrays.

numpy reduces an (N, 3) C-ordered array along axis 0 (``mean``, ``min``) or along its
short axis 1 (``linalg.norm``) several times slower than a BLAS product or a reduction
over contiguous rows. Clouds here have hundreds of thousands of rows and are reduced
many times per frame, so the hot paths use these equivalents.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import threading
from contextlib import contextmanager
from typing import Iterator

import numpy as np
from numpy.typing import NDArray

__all__ = ["row_norms", "centroid", "rows_finite", "take_rows", "robust_sigma", "knn", "knn_among",
           "link_components", "pair_components", "group_by_label", "MAX_INT16_LABEL",
           "retain_freed_memory", "single_threaded_blas", "blas_libraries"]

#: :func:`link_components` first joins each point to its nearest this many neighbours
#: (besides itself): on voxel grids those few links already hold nearly all of a surface
#: together (osd_learn supports: 50,000 points in 4-9 pieces, 34-43 of the other links
#: joining two of them), so the other links are only checked, not built into the graph.
FIRST_LINKS = 4
#: Labels up to this are grouped by counting and a 16-bit radix sort (:func:`group_by_label`).
MAX_INT16_LABEL = int(np.iinfo(np.int16).max)


def row_norms(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Euclidean norm of every row of ``v`` (N, 3)."""
    return np.sqrt(np.einsum("ij,ij->i", v, v))


def centroid(p: NDArray[np.float64]) -> NDArray[np.float64]:
    """Mean of the rows of ``p`` (N, 3); zeros for an empty array."""
    n = len(p)
    return np.ones(n) @ p / n if n else np.zeros(p.shape[1] if p.ndim == 2 else 3)


def rows_finite(p: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Mark the rows of ``p`` (N, D) whose entries are all finite: (N,) bool."""
    ok = np.isfinite(p[:, 0])
    for i in range(1, p.shape[1]):
        ok &= np.isfinite(p[:, i])
    return ok


def robust_sigma(d: NDArray[np.float64]) -> float:
    """Estimate a standard deviation from the median absolute deviation (outlier-proof)."""
    return float(1.4826 * np.median(np.abs(d - np.median(d)))) if d.size else 0.0


def knn_among(points: NDArray[np.float64], sel: NDArray[np.int64], neighbors: NDArray[np.int64],
              sqdist: NDArray[np.float64], k: int
              ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Find the ``k`` nearest neighbours of the points ``sel`` among themselves.

    Parameters
    ----------
    points : (N, 3) float64 array [m]
    sel : (M,) int64 array
        Rows of ``points``, without repeats.
    neighbors, sqdist : (N, K) arrays
        Nearest neighbours of every point of ``points`` among all of them, nearest first,
        and their squared distances [m^2] (:func:`knn`).
    k : int
        Neighbours wanted (at most K are taken from ``neighbors``).

    Returns
    -------
    neighbors, sqdist : (M, k') arrays, k' = min(k, M)
        Indices into ``sel`` (not ``points``) and squared distances [m^2], nearest first.

    Notes
    -----
    Where at least k' of a point's K neighbours are in ``sel``, the first k' of them are its
    k' nearest in ``sel`` (a nearer point of ``sel`` would be among the K): they are kept,
    and only the other points are searched again, among ``sel`` alone. Equal distances
    may come in another order than a new search over ``sel`` would give.
    """
    m = len(sel)
    k = int(min(k, m))
    local = np.full(len(points), -1, dtype=np.int64)
    local[sel] = np.arange(m)
    nb = local[take_rows(neighbors, sel)]
    sq = take_rows(sqdist, sel)
    inside = nb >= 0
    kept = np.flatnonzero(inside.sum(axis=1) >= k) if k <= nb.shape[1] else \
        np.zeros(0, dtype=np.int64)
    out = np.empty((m, k), dtype=np.int64)
    out_sq = np.empty((m, k))
    if k == nb.shape[1]:
        out[kept], out_sq[kept] = nb[kept], sq[kept]
    else:
        # The first k neighbours in ``sel`` of each kept row, in their order (a stable
        # sort moves the others behind them).
        first = np.argsort(~inside[kept], axis=1, kind="stable")[:, :k]
        out[kept] = np.take_along_axis(nb[kept], first, axis=1)
        out_sq[kept] = np.take_along_axis(sq[kept], first, axis=1)
    again = np.ones(m, dtype=bool)
    again[kept] = False
    if again.any():
        sub = take_rows(points, sel)
        out[again], out_sq[again] = knn(sub, k, return_sqdist=True, queries=sub[again])
    return out, out_sq


def link_components(neighbors: NDArray[np.int64], keep: NDArray[np.bool_]
                    ) -> tuple[int, NDArray[np.int32]]:
    """Label the connected components of the links ``i -> neighbors[i, j]`` kept.

    Parameters
    ----------
    neighbors : (M, k) int array
        Neighbours of every point, indices 0 .. M-1 (nearest first, e.g. from :func:`knn`);
        entries that are not kept may hold any index from -M to M-1 (e.g. -1 for none).
    keep : (M, k) bool array
        The links of the graph, where ``keep[i, j]`` (undirected: a link joins its two
        ends either way).

    Returns
    -------
    n, labels : int, (M,) int32 array
        As :func:`scipy.sparse.csgraph.connected_components` (``directed=False``) gives
        them for the whole graph: components numbered in the order of their first point.

    Notes
    -----
    The components of columns 1 .. :data:`FIRST_LINKS` (column 0 of a kNN list is the point
    itself) are found first; a link of the other columns then matters only where it joins
    two of them, and those few links are
    joined on the graph of the components. Each step numbers its components by their
    first member (scipy's traversal starts at every point not yet labelled, in order), so
    the numbering is the whole graph's.
    """
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    m, k = neighbors.shape
    # Column 0 is the point itself in a kNN list: the first links are columns 1 .. f.
    f = min(FIRST_LINKS, k - 1)
    # Every row holds f entries: a link not kept becomes a loop on its own point, which
    # joins nothing (no masked gather, no row counts).
    if f > 0:
        first = np.where(keep[:, 1:f + 1], neighbors[:, 1:f + 1], np.arange(m)[:, None])
        graph = csr_matrix((np.ones(m * f), first.ravel(), np.arange(0, m * f + 1, f)),
                           shape=(m, m))
        n, labels = connected_components(graph, directed=False)
    else:  # one column (k = 1): no first links, every point its own component
        n, labels = m, np.arange(m, dtype=np.int32)
    # The links that join two components, over all columns at once (a kept link of
    # columns 1 .. f never does; one gather costs less than two of column slices).
    other = np.take(labels, neighbors)
    cross = np.flatnonzero(keep & (other != labels[:, None]))
    if not len(cross):
        return n, labels
    a, b = labels[cross // k], other.ravel()[cross]
    n, merged = connected_components(csr_matrix((np.ones(len(a)), (a, b)), shape=(n, n)),
                                     directed=False)
    return n, merged[labels]


def pair_components(n: int, pairs: NDArray[np.int64]) -> NDArray[np.int64]:
    """Label (n,) the connected components of ``n`` nodes linked by ``pairs`` (L, 2)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def group_by_label(idx: NDArray[np.int64], lab: NDArray[np.int64]
                   ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64],
                              NDArray[np.int64]]:
    """Group ``idx`` by their labels ``lab`` (>= 0): (order, ids, starts, ends).

    ``order[starts[k]:ends[k]]`` are the indices labelled ``ids[k]``, in input order;
    ``ids`` ascending. ``idx`` and ``lab`` are (n,) int arrays, n >= 1.
    """
    top = int(lab.max())
    if top <= MAX_INT16_LABEL:
        # Few small labels (the usual case): counting, and numpy's radix sort for int16.
        counts = np.bincount(lab, minlength=top + 1)
        ids = np.flatnonzero(counts)
        ends = np.cumsum(counts)[ids]
        starts = ends - counts[ids]
        order = idx[np.argsort(lab.astype(np.int16), kind="stable")]
    else:
        srt = np.argsort(lab, kind="stable")
        order = idx[srt]
        ids, starts = np.unique(lab[srt], return_index=True)
        ends = np.r_[starts[1:], len(order)]
    return order, ids, starts, ends


def take_rows(a: NDArray, which: NDArray) -> NDArray:
    """``a[which]`` for an (N, D) array and an index array or boolean mask of rows.

    numpy's ``take`` and ``compress`` copy whole rows; fancy and boolean indexing of a
    2-D array go element by element and are 2-5x slower on clouds of 10^5 points.
    """
    which = np.asarray(which)
    if which.dtype == bool:
        return np.compress(which, a, axis=0)
    return np.take(a, which, axis=0)


def knn(points: NDArray[np.float64], k: int, return_sqdist: bool = False,
        queries: NDArray[np.float64] | None = None):
    """Find the ``k`` nearest neighbours of every point of ``points`` (M, 3) among themselves.

    Returns their indices (M, k), nearest first (the point itself, distance 0, among them);
    with ``return_sqdist`` also their squared distances (M, k) [m^2]. With ``queries``
    (Q, 3) the neighbours among ``points`` of those points instead ((Q, k) arrays).

    pykdtree's k-d tree (OpenMP over the queries). Measured on osd_learn working clouds
    (55k points, k = 16, 2 cores): 41 ms against 58 ms for open3d's multithreaded search and
    66-72 ms for :class:`scipy.spatial.cKDTree` with two workers (BENCHMARKS.md section
    21). Neighbours at exactly equal distances (voxel centroids of a
    depth-quantised frame) come in the tree's order. In a process forked after this one
    searched (GNU OpenMP's threads do not survive fork), scipy's tree on one thread.
    """
    k = int(min(k, len(points)))
    m = len(points) if queries is None else len(queries)
    if m == 0 or k == 0:
        empty = np.zeros((m, k), dtype=np.int64)
        return (empty, np.zeros((m, k))) if return_sqdist else empty
    data = np.ascontiguousarray(points, dtype=np.float64)
    q = data if queries is None else np.ascontiguousarray(queries, dtype=np.float64)
    if _openmp_inherited:
        # A child forked after this process's OpenMP team started: GNU OpenMP's team does
        # not survive fork (the child would wait for threads that do not exist).
        from scipy.spatial import cKDTree
        dist, idx = cKDTree(data).query(q, k=k, workers=1)
        sqdist = np.square(dist).reshape(m, k)
    else:
        from pykdtree.kdtree import KDTree  # imported on first use: the module stays cheap
        _openmp_started.set()
        sqdist, idx = KDTree(data, leafsize=KNN_LEAF_SIZE).query(q, k=k, sqr_dists=True)
        sqdist = sqdist.reshape(m, k)
    idx = idx.astype(np.int64, copy=False).reshape(m, k)
    return (idx, sqdist) if return_sqdist else idx


#: Set once this process has searched with pykdtree (its OpenMP team may be running).
_openmp_started = threading.Event()
#: True in a process forked after that (:func:`knn` then searches without OpenMP).
_openmp_inherited = False


def _after_fork_in_child() -> None:
    global _openmp_inherited
    _openmp_inherited = _openmp_inherited or _openmp_started.is_set()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


#: Points per leaf of the k-d tree of :func:`knn` (pykdtree's default).
KNN_LEAF_SIZE = 16


#: glibc's mallopt() parameter numbers (malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3


def retain_freed_memory(mmap_threshold: int = 32 * 2**20, trim_threshold: int = 2**30) -> bool:
    """Let this process reuse the memory of freed arrays instead of returning it to the OS.

    glibc only; process-wide, so it is called by the ``geomodel`` CLI and the node's
    ``main``, never on import.

    glibc serves large blocks (numpy's temporaries over a cloud) with fresh pages that
    the kernel must map and zero on first touch, and gives them back when freed; every
    frame then pays those page faults again (about 4,000 per paper scene in
    ``model_objects``, 7,000-10,000 per Kinect frame in ``model_scene``, about 5 us each
    on a virtual machine). Blocks up to ``mmap_threshold`` bytes (glibc's maximum,
    32 MiB) come from the heap instead, and up to ``trim_threshold`` bytes of free heap
    are kept. Peak memory is unchanged; resident memory stays at the peak between frames.

    Returns False (and changes nothing) where the C library has no ``mallopt``.
    """
    try:
        mallopt = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    return bool(mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold))) and \
        bool(mallopt(_M_TRIM_THRESHOLD, int(trim_threshold)))


_blas_lock = threading.Lock()
_blas_users = 0
_blas_limiter = None
_blas_libraries = None


def blas_libraries():
    """Return the threadpoolctl controller of the BLAS libraries this process has loaded.

    numpy's and scipy's (each wheel ships its own OpenBLAS; scipy's is loaded here first),
    or whatever BLAS they were built with; found once and cached, so a BLAS library loaded
    later is not controlled.
    """
    global _blas_libraries
    if _blas_libraries is None:
        import scipy.linalg  # noqa: F401  (loads scipy's own BLAS, used by its fitting)
        from threadpoolctl import ThreadpoolController

        _blas_libraries = ThreadpoolController().select(user_api="blas")
    return _blas_libraries


@contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Run the block with BLAS on one thread; restore its thread count afterwards.

    For code that is parallel at a coarser grain (the modeling's one worker thread per
    object on all cores): there OpenBLAS's own threads for a product over a large object
    (an (n, 3) cloud times a 3-vector) only wait for a core the workers hold, 1-10 ms per
    call on a loaded machine. Products whose sums run over a few coordinates give the
    same bits with any thread count (OpenBLAS splits their output); a sum over the rows
    of a large cloud (:func:`centroid` of more than about 150,000 points) is split into
    one partial sum per thread, so there the last bit depends on the thread count (that
    is, on the machine's cores without this). Process-wide (OpenBLAS has no per-thread
    count in every build); nested and concurrent uses count, the last one out restores.
    Every BLAS library loaded (:func:`blas_libraries`, through threadpoolctl: OpenBLAS,
    MKL, BLIS, FlexiBLAS) is limited; a no-op where none is found.
    """
    global _blas_users, _blas_limiter
    with _blas_lock:
        if _blas_users == 0:
            _release_blas_control()
            _blas_limiter = blas_libraries().limit(limits=1)
        _blas_users += 1
    try:
        yield
    finally:
        with _blas_lock:
            _blas_users -= 1
            if _blas_users == 0:
                _release_blas_control()
                _blas_limiter.restore_original_limits()
                _blas_limiter = None
                _release_blas_control()


def _release_blas_control() -> None:
    """Let any thread set OpenBLAS's process-wide thread count next.

    threadpoolctl lets only the first thread that set it set it again (later threads are
    silently ignored) until that thread's ``with`` blocks are done; here the count is set
    and restored under :data:`_blas_lock`, possibly by different threads (the last one
    out restores), so the control is released around each change. (Older threadpoolctl
    releases, e.g. Debian's 3.1, have no such control: nothing to release.)
    """
    import threadpoolctl

    release = getattr(getattr(threadpoolctl, "OpenBLASController", None),
                      "clear_controlling_thread", None)
    if release is not None:
        release(force=True)
