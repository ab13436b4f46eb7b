"""Mixed pixels of an organized cloud: returns between two surfaces at a depth edge.

A pixel whose footprint straddles a silhouette returns a range between the foreground's and
the background's (time-of-flight cameras' "flying pixels"; depth images resampled to another
camera's pixels). Such a point lies on no surface, and between two objects it is a bridge
that links them. It is told apart on the pixel grid: along a row or a column, a run of one or
two pixels lies strictly between two surfaces that are each continuous up to the run (their
own neighbours beyond are within :data:`SIDE_SHARE` of the jump) while the jump between them
exceeds what the frame's noise and quantisation make of one surface. A surface seen at a
slant rises steadily (its sides are not flat next to the run) and stays; a silhouette pixel
that belongs to one side (within :data:`SIDE_SHARE` of the jump from it) stays.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.fastmath import row_norms, take_rows
from geomodel_ros.core.noise import NoiseEstimate
from geomodel_ros.core.params import ModelingParams

__all__ = ["SIDE_SHARE", "MAX_RUN", "JUMP_SIGMAS", "mixed_pixels", "mixed_rows"]

#: Each side of an edge is flat next to it when its next pixel is within this share of the
#: jump; a pixel in the run lies between the sides by more than this share from both.
SIDE_SHARE = 0.25
#: Runs of up to this many pixels between two surfaces are mixed (a footprint straddles an
#: edge over one pixel; resampling spreads it over two).
MAX_RUN = 2
#: Two surfaces are apart at a pixel when their ranges differ by more than this many sigma
#: of the frame's depth noise there, plus two disparity steps (a surface quantised in
#: terraces steps by up to two of them over the run's width), and at least a segmentation
#: link. Measured (BENCHMARKS.md section 27): at 8 sigma the rendered Kinect-class clutter
#: without mixed pixels still gave 1,700 hits per frame (curved sides near their silhouette),
#: at 11 sigma 400, most of them on rims seen edge-on.
JUMP_SIGMAS = 11.0


def mixed_pixels(ranges: NDArray[np.float64], jump: NDArray[np.float64]
                 ) -> tuple[NDArray[np.bool_], int, int]:
    """Mixed pixels of a range image, and how many of its edges hold them.

    Parameters
    ----------
    ranges : (H, W) float64 array [m]
        Distance of each pixel's point from the sensor; NaN where there is no return.
    jump : (H, W) float64 array [m]
        Least range difference between two surfaces at each pixel for an edge (beyond the
        frame's noise and quantisation there).

    Returns
    -------
    mixed : (H, W) bool array
        True for the pixels of runs of 1 .. :data:`MAX_RUN` along a row or a column that lie
        between two flat sides differing by more than ``jump``.
    runs, edges : int
        Windows (of 1 .. :data:`MAX_RUN` pixels between flat sides, along rows and columns)
        that hold a mixed run, and that straddle an edge at all: ``runs / edges`` is the
        share of the frame's edges whose pixels see both surfaces.
    """
    r = np.asarray(ranges, dtype=np.float64)
    j = np.asarray(jump, dtype=np.float64)
    out = np.zeros(r.shape, dtype=bool)
    runs = edges = 0
    for transpose in (False, True):
        rr, jj, hit = (r.T, j.T, out.T) if transpose else (r, j, out)
        n_runs, n_edges = _mark_runs(rr, jj, hit)
        runs, edges = runs + n_runs, edges + n_edges
    return out, runs, edges


def _mark_runs(r: NDArray[np.float64], j: NDArray[np.float64], hit: NDArray[np.bool_]
               ) -> tuple[int, int]:
    """Mark (in ``hit``) the mixed runs along the rows of ``r``; count runs and edges.

    The jump test runs on the whole image; the rest only where it holds (a few per cent of
    the windows: edges are lines in the image).
    """
    width = r.shape[1]
    flat_r = r.ravel()
    runs = edges = 0
    for run in range(1, MAX_RUN + 1):
        span = run + 4  # outer, side, run pixels, side, outer
        if width < span:
            continue
        n = width - span + 1
        with np.errstate(invalid="ignore"):
            jumps = np.abs(r[:, run + 2:run + 2 + n] - r[:, 1:1 + n]) > j[:, 2:2 + n]
        rows, start = np.nonzero(jumps)
        first = rows * width + start  # flat index of each window's outer pixel
        outer_a, a, b, outer_b = (flat_r[first + k] for k in (0, 1, run + 2, run + 3))
        step = np.abs(b - a)
        margin = SIDE_SHARE * step
        edge = (np.abs(outer_a - a) < margin) & (np.abs(outer_b - b) < margin)
        edges += int(np.count_nonzero(edge))
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        for k in range(run):
            m = flat_r[first + 2 + k]
            edge &= (m > lo + margin) & (m < hi - margin)
        runs += int(np.count_nonzero(edge))
        for k in range(run):
            hit[rows[edge], start[edge] + 2 + k] = True
    return runs, edges


def mixed_rows(points: NDArray[np.float64], shape: tuple[int, int], finite: NDArray[np.int64],
               params: ModelingParams, noise: NoiseEstimate | None, step: float | None
               ) -> NDArray[np.bool_]:
    """Which of the rows ``finite`` of an organized cloud are mixed pixels.

    Parameters
    ----------
    points : (H * W, 3) float64 array [m]
        The cloud's pixels, row-major, sensor at the origin.
    shape : (H, W)
    finite : (F,) int64 array
        Rows with a return.
    params : ModelingParams
        ``seg_voxel_size`` and ``seg_max_edge_factor`` (a segmentation link: the least jump).
    noise : NoiseEstimate or None
        The frame's depth noise (None: none known, the least jump only).
    step : float or None
        The frame's disparity step in 1/z [1/m] (:func:`~geomodel_ros.core.noise.
        disparity_step`), None when the depths are not quantised.

    Returns
    -------
    (F,) bool array
    """
    rng = row_norms(take_rows(points, finite))
    ranges = np.full(shape[0] * shape[1], np.nan)
    ranges[finite] = rng
    jump = np.full(len(ranges), np.inf)
    sigma = noise.sigma(rng) if noise is not None else 0.0
    quantum = 2.0 * (step or 0.0) * rng * rng
    jump[finite] = np.maximum(params.seg_max_edge_factor * params.seg_voxel_size,
                              JUMP_SIGMAS * sigma + quantum)
    mixed, _, _ = mixed_pixels(ranges.reshape(shape), jump.reshape(shape))
    return mixed.ravel()[finite]
