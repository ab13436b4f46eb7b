"""Fast forms of a few numpy reductions over point arrays.

numpy reduces an (N, 3) C-ordered array along axis 0 (``mean``, ``min``) or along its
short axis 1 (``linalg.norm``) several times slower than a BLAS product or a reduction
over contiguous rows. Clouds here have hundreds of thousands of rows and are reduced
many times per frame, so the hot paths use these equivalents.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["row_norms", "centroid", "rows_finite", "knn"]


def row_norms(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Euclidean norm of every row of ``v`` (N, 3)."""
    return np.sqrt(np.einsum("ij,ij->i", v, v))


def centroid(p: NDArray[np.float64]) -> NDArray[np.float64]:
    """Mean of the rows of ``p`` (N, 3); zeros for an empty array."""
    n = len(p)
    return np.ones(n) @ p / n if n else np.zeros(p.shape[1] if p.ndim == 2 else 3)


def rows_finite(p: NDArray[np.float64]) -> NDArray[np.bool_]:
    """True for rows of ``p`` (N, D) whose entries are all finite."""
    ok = np.isfinite(p[:, 0])
    for i in range(1, p.shape[1]):
        ok &= np.isfinite(p[:, i])
    return ok


def knn(points: NDArray[np.float64], k: int, return_sqdist: bool = False):
    """Indices (M, k) of the ``k`` nearest neighbours of every point of ``points`` (M, 3)
    among themselves, nearest first (the point itself, distance 0, among them); with
    ``return_sqdist`` also their squared distances (M, k) [m^2].

    open3d's multithreaded nearest-neighbour search (faster than building and querying
    a :class:`scipy.spatial.cKDTree` on working clouds of 10^4-10^5 points).
    """
    import open3d as o3d  # imported on first use: the module stays cheap to import

    m = len(points)
    k = int(min(k, m))
    if m == 0 or k == 0:
        empty = np.zeros((m, k), dtype=np.int64)
        return (empty, np.zeros((m, k))) if return_sqdist else empty
    data = o3d.core.Tensor(np.ascontiguousarray(points, dtype=np.float64))
    search = o3d.core.nns.NearestNeighborSearch(data)
    if not search.knn_index():
        raise RuntimeError("open3d could not build a nearest-neighbour index")
    idx, sqdist = search.knn_search(data, k)
    idx = idx.numpy().astype(np.int64, copy=False).reshape(m, k)
    if return_sqdist:
        return idx, sqdist.numpy().astype(np.float64, copy=False).reshape(m, k)
    return idx
