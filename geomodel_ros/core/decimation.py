"""Decimation of organized clouds: model every d-th pixel, label every pixel.

With ``decimation`` d > 1 an organized cloud (H x W pixels) is modeled from its samples,
the pixels ``(off + d i, off + d j)`` with ``off = d // 2`` (the centre of each d x d block):
a camera's decimation filter without averaging, so every sample keeps its own depth, noise
and disparity level and the frame's noise estimate still describes it. The segmentation and
the modeling then see about 1 / d^2 of the points.

Every pixel of the full image then gets a label (:func:`spread_labels`): the label of its
block's sample when it lies within a segmentation link of that sample
(``seg_max_edge_factor`` times the larger of ``seg_voxel_size`` and the sample's spacing to
its nearest sample neighbour). A pixel across a depth edge from its block's sample, or in a
block whose sample has no return, takes the label of the nearest sample of the blocks
around it within whose link it lies, and is left unlabelled (-1) where there is none rather
than given the wrong object.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.fastmath import rows_finite

__all__ = ["Decimated", "decimate", "spread_labels"]


class Decimated(NamedTuple):
    """The samples of an organized cloud.

    ``points`` (h * w, 3) are the sampled pixels row-major, ``shape`` (h, w) their image
    shape, ``rows`` and ``cols`` the sampled pixel rows (h,) and columns (w,) of the full
    image, ``step`` the decimation (a block's edge in pixels).
    """

    points: NDArray[np.float64]
    shape: tuple[int, int]
    rows: NDArray[np.int64]
    cols: NDArray[np.int64]
    step: int


def decimate(points: NDArray[np.float64], shape: tuple[int, int], step: int) -> Decimated:
    """Take every ``step``-th pixel of every ``step``-th row of ``points`` (H * W, 3).

    The samples are the centres of the ``step`` x ``step`` blocks (offset ``step // 2``); an
    image with fewer than ``step // 2 + 1`` rows or columns keeps its first row or column.
    Samples with a non-finite coordinate become all NaN (no return, as the core reads them).
    """
    h, w = shape
    off = step // 2
    rows = np.arange(min(off, h - 1), h, step, dtype=np.int64)
    cols = np.arange(min(off, w - 1), w, step, dtype=np.int64)
    image = points.reshape(h, w, 3)
    small = np.ascontiguousarray(image[rows[:, None], cols[None, :]]).reshape(-1, 3)
    # A sample without a return is NaN in all three coordinates (an infinite one would
    # make the distances of spread_labels inf - inf).
    small[~rows_finite(small)] = np.nan
    return Decimated(small, (len(rows), len(cols)), rows, cols, step)


def _block_counts(pixels: int, samples: int, step: int) -> NDArray[np.int64]:
    """Pixels (samples,) of each block along one image axis (the last takes the rest)."""
    return np.bincount(np.minimum(np.arange(pixels) // step, samples - 1), minlength=samples)


def _over_blocks(a: NDArray, rows: NDArray[np.int64], cols: NDArray[np.int64]) -> NDArray:
    """Spread a per-sample array (h, w) over the pixels of the samples' blocks (H, W)."""
    return np.repeat(np.repeat(a, rows, axis=0), cols, axis=1)


def _sample_spacing(samples: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance [m] (h, w) from each sample to its nearest 4-neighbour sample (inf if none)."""
    spacing = np.full(samples.shape[:2], np.inf)
    for axis in (0, 1):
        d = np.linalg.norm(np.diff(samples, axis=axis), axis=2)
        d = np.where(np.isfinite(d), d, np.inf)
        lead = [slice(None)] * 2
        trail = [slice(None)] * 2
        lead[axis] = slice(None, -1)
        trail[axis] = slice(1, None)
        spacing[tuple(lead)] = np.minimum(spacing[tuple(lead)], d)
        spacing[tuple(trail)] = np.minimum(spacing[tuple(trail)], d)
    return spacing


def spread_labels(points: NDArray[np.float64], shape: tuple[int, int], dec: Decimated,
                  sample_labels: NDArray[np.int64], voxel: float, edge_factor: float
                  ) -> NDArray[np.int64]:
    """Label every pixel of ``points`` (H * W, 3) from the labels (h * w,) of the samples.

    Each pixel takes the label of its block's sample when it lies within ``edge_factor``
    times the larger of ``voxel`` [m] and that sample's spacing to its nearest sample
    neighbour (its reach). A finite pixel out of that reach (across a depth edge from it,
    or in a block whose sample has no return) takes the label of the nearest of the
    samples of the eight blocks around its own whose reach it lies within; with none, -1
    (as every non-finite pixel).
    """
    h, w = shape
    rows = _block_counts(h, len(dec.rows), dec.step)
    cols = _block_counts(w, len(dec.cols), dec.step)
    image = points.reshape(h, w, 3)
    samples = dec.points.reshape(*dec.shape, 3)
    sq = np.zeros((h, w))
    for axis in range(3):
        diff = image[..., axis] - _over_blocks(samples[..., axis], rows, cols)
        sq += diff * diff
    reach = edge_factor * np.maximum(voxel, _sample_spacing(samples))
    reach_sq = _over_blocks(reach * reach, rows, cols)
    lab = np.asarray(sample_labels, dtype=np.int64).reshape(dec.shape)
    near = sq <= reach_sq
    out = np.where(near, _over_blocks(lab, rows, cols), -1).ravel()
    miss = np.flatnonzero(~near.ravel() & rows_finite(points))
    if len(miss):
        out[miss] = _from_blocks_around(points[miss], miss // w, miss % w, dec, lab, reach)
    return out


def _from_blocks_around(p: NDArray[np.float64], r: NDArray[np.int64], c: NDArray[np.int64],
                        dec: Decimated, lab: NDArray[np.int64], reach: NDArray[np.float64]
                        ) -> NDArray[np.int64]:
    """Label pixels ``p`` (Q, 3) at rows ``r``, columns ``c`` from the blocks around theirs.

    Each takes the label (from ``lab``, h x w) of the nearest sample of the eight blocks
    around its own whose ``reach`` (h, w) [m] holds it; with none, -1.
    """
    h, w = dec.shape
    br = np.minimum(r // dec.step, h - 1)
    bc = np.minimum(c // dec.step, w - 1)
    samples = dec.points.reshape(h, w, 3)
    best = np.full(len(p), np.inf)
    out = np.full(len(p), -1, dtype=np.int64)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr == dc == 0:
                continue
            nr, nc = br + dr, bc + dc
            inside = (nr >= 0) & (nr < h) & (nc >= 0) & (nc < w)
            nr, nc = np.clip(nr, 0, h - 1), np.clip(nc, 0, w - 1)
            sq = np.square(p - samples[nr, nc]).sum(axis=1)
            better = inside & (sq <= np.square(reach[nr, nc])) & (sq < best)
            best = np.where(better, sq, best)
            out = np.where(better, lab[nr, nc], out)
    return out
