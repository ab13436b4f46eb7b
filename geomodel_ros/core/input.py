"""Preparation of a scene cloud before any grid arithmetic: range gate and size bound.

Every entry of the core that voxelizes a scene (:func:`~geomodel_ros.core.modeling.model_scene`,
:func:`~geomodel_ros.core.modeling.model_objects`,
:func:`~geomodel_ros.core.segmentation.segment_scene`) first drops the points farther than
``max_range`` from the sensor origin exactly like invalid (non-finite) points: they get label
-1 and the rows stay in place, so organized clouds keep their shape. A driver's garbage returns
(coordinates around 1e9 m) therefore never reach the voxel grids, and neither do the rows at
the origin (0, 0, 0) that some drivers write for a pixel without a return.

A scene with more than ``max_points`` valid points is averaged on a voxel grid first
(:func:`downsample`): the smallest voxel of the sequence ``seg_voxel_size * GROWTH**k`` that
leaves at most ``max_points`` voxels. Memory then grows with ``max_points``, not with the
input, apart from a few copies of the input array itself. The segmentation then works at
that voxel (:func:`working_params`: its neighbour links and plane areas are measured in
voxels), and counts (``seg_min_cluster_points``, ``min_object_points``, an object's
``point_count``) are counts of voxels.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.errors import InputError
from geomodel_ros.core.faces import count_voxels, voxelize
from geomodel_ros.core.fastmath import rows_finite, take_rows
from geomodel_ros.core.params import PARAMETERS, ModelingParams

__all__ = ["DOWNSAMPLE_GROWTH", "Downsampled", "downsample", "in_range", "origin_rows",
           "without_far_points", "working_params"]

#: Ratio of successive voxel edges tried by :func:`downsample`: the voxel used is at most
#: this factor coarser than the smallest one that would do, and a 5M-point floor needs
#: five voxelizations from the segmentation voxel (4 mm -> 12 mm).
DOWNSAMPLE_GROWTH = 1.25
#: Most voxel edges :func:`downsample` tries (1.25**200 is about 1e19: no cloud needs as many).
MAX_DOWNSAMPLE_STEPS = 200
#: Largest allowed ``seg_voxel_size`` [m]: the segmentation of a downsampled scene works at
#: the downsampling voxel, up to this.
_SEG_VOXEL_MAX = float(next(p.high for p in PARAMETERS if p.name == "seg_voxel_size"))


def _inside_box(points: NDArray[np.float64], max_range: float) -> bool:
    """Tell whether every finite row of ``points`` (N, 3) [m] is within ``max_range`` [m].

    True when all finite coordinates lie in the cube of half-edge ``max_range / sqrt(3)``
    (then every finite row does); False means "not sure". Two NaN-ignoring reductions,
    several times faster than the squared norms of the rows: the usual cloud passes this
    test and needs nothing else. Infinite or all-NaN coordinates give False.
    """
    if points.size == 0:
        return True
    top = float(np.fmax.reduce(points, axis=None))
    bottom = float(np.fmin.reduce(points, axis=None))
    if not (math.isfinite(top) and math.isfinite(bottom)):
        return False
    return max(abs(top), abs(bottom)) * math.sqrt(3.0) <= max_range


def origin_rows(points: NDArray[np.float64]) -> NDArray[np.int64]:
    """Return the rows of ``points`` (N, 3) that are exactly (0, 0, 0).

    Some drivers write the origin for a pixel without a return instead of NaN; no
    measurement is exactly there (a sensor sees nothing at zero range, and a measured point
    of a cloud in another frame lands on three exact zeros with no real chance), so such
    a row is invalid like a NaN row. Looked for on the z column first (one strided pass).
    """
    idx = np.flatnonzero(points[:, 2] == 0.0)
    return idx[(points[idx, 0] == 0.0) & (points[idx, 1] == 0.0)]


def in_range(points: NDArray[np.float64], max_range: float) -> NDArray[np.bool_]:
    """Mark the rows of ``points`` (N, 3) [m] that are finite and within ``max_range`` [m].

    A NaN or infinite row has a NaN or infinite squared norm, which fails the comparison;
    huge finite values overflow to inf in the square (silenced) and fail too. A row at the
    origin is no return (:func:`origin_rows`) and is not marked either.
    """
    if _inside_box(points, max_range):
        ok = rows_finite(points)
    else:
        with np.errstate(over="ignore", invalid="ignore"):
            sq = np.einsum("ij,ij->i", points, points)
        ok = sq <= max_range * max_range
    ok[origin_rows(points)] = False
    return ok


def without_far_points(points: NDArray[np.float64], params: ModelingParams
                       ) -> NDArray[np.float64]:
    """``points`` (N, 3) [m] with the finite rows beyond ``params.max_range`` set to NaN.

    Rows at the origin (:func:`origin_rows`: a driver's "no return") are set to NaN too.
    Returns ``points`` itself (no copy) when there is no such row; otherwise a copy, so
    that the caller's array is never modified. Non-finite rows are left as they are (they
    are invalid already).
    """
    far = origin_rows(points)
    if not _inside_box(points, params.max_range):
        with np.errstate(over="ignore", invalid="ignore"):
            sq = np.einsum("ij,ij->i", points, points)
        # NaN rows fail the comparison; rows with an inf pass it but are not finite.
        beyond = np.flatnonzero(sq > params.max_range * params.max_range)
        far = np.concatenate([far, beyond[rows_finite(points[beyond])]])
    if far.size == 0:
        return points
    out = points.copy()
    out[far] = np.nan
    return out


class Downsampled(NamedTuple):
    """A cloud averaged on a voxel grid.

    Attributes
    ----------
    points : (M, 3) float64 array [m]
        Voxel centroids (M <= max_points).
    rows : (K,) int64 array
        Input rows that were used (finite, within max_range).
    inverse : (K,) int64 array
        Voxel of each used row: ``points[inverse[j]]`` stands for input row ``rows[j]``.
    voxel_size : float [m]
        Edge of the voxels.
    """

    points: NDArray[np.float64]
    rows: NDArray[np.int64]
    inverse: NDArray[np.int64]
    voxel_size: float


def downsample(points: NDArray[np.float64], rows: NDArray[np.int64], params: ModelingParams
               ) -> Downsampled:
    """Average ``points[rows]`` on the smallest voxel grid with at most ``max_points`` voxels.

    Parameters
    ----------
    points : (N, 3) float64 array [m]
    rows : (K,) int64 array
        The usable rows (finite, within ``max_range``), K > ``params.max_points``.
    params : ModelingParams
        ``max_points`` and ``seg_voxel_size`` (the first voxel edge tried) are used.

    Returns
    -------
    Downsampled

    Raises
    ------
    InputError
        If the points cannot be voxelized (see :func:`~geomodel_ros.core.faces.voxelize`).
    """
    used = points if len(rows) == len(points) else take_rows(points, rows)
    size = params.seg_voxel_size
    for _ in range(MAX_DOWNSAMPLE_STEPS):
        if count_voxels(used, size) <= params.max_points:
            centroids, inverse, _ = voxelize(used, size)
            return Downsampled(centroids, rows, inverse, size)
        size *= DOWNSAMPLE_GROWTH
    raise InputError(f"no voxel up to {size:.3g} m leaves at most max_points = "
                     f"{params.max_points} points")


def working_params(params: ModelingParams, voxel_size: float) -> ModelingParams:
    """``params`` for a scene downsampled at ``voxel_size`` [m].

    The segmentation voxel becomes ``voxel_size`` (at most the largest allowed
    ``seg_voxel_size``): at its own, finer voxel every voxel centroid would be isolated
    (neighbour links are limited to ``seg_max_edge_factor`` segmentation voxels).
    """
    return dataclasses.replace(params, seg_voxel_size=min(voxel_size, _SEG_VOXEL_MAX))
