"""Whether one model explains an object's points better than another beyond the noise.

Two models fitted to the same object are compared point by point on the same points:
each point's truncated residual (MSAC cost at the noise band) under one minus under the
other. Depth errors of a real sensor are correlated over neighbouring pixels, so the
points' differences are not independent: their mean is judged against the
cluster-robust standard error over blocks of neighbouring points (:data:`BLOCK_GRID`
squared cells of the object's extent), with a one-sided Student test at
:data:`LOWER_LEVEL` and one degree of freedom fewer than the blocks holding points.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import stats

__all__ = ["BLOCK_GRID", "LOWER_LEVEL", "MIN_BLOCKS", "spread_blocks", "lower_beyond_noise"]

#: Blocks per side of the grid over the object's two widest directions: 16 blocks, each
#: of about 125 of the 2000 compared points (RIVAL_SAMPLE) and a few centimetres wide on
#: a cup-sized object, about the length over which a structured-light sensor's slow
#: depth errors stay correlated; 15 degrees of freedom for the test.
BLOCK_GRID = 4
#: One-sided significance level of "lower" (the conventional 5 % two-sided).
LOWER_LEVEL = 0.025
#: Fewest blocks holding points for a judgement (below, nothing is significantly lower).
MIN_BLOCKS = 4


def spread_blocks(points: NDArray[np.float64], grid: int = BLOCK_GRID) -> NDArray[np.int64]:
    """Return a block index (n,) per point: equal-count cells along the two widest directions.

    Parameters
    ----------
    points : (n, 3) float64 array [m]
    grid : int, cells per direction (``grid`` squared blocks)

    Returns
    -------
    (n,) int64 array in [0, grid^2)
    """
    n = len(points)
    if n < 2:
        return np.zeros(n, dtype=np.int64)
    centred = points - points.mean(axis=0)
    _, vecs = np.linalg.eigh(centred.T @ centred)
    cells = []
    for k in (2, 1):  # the widest two principal directions (eigh: ascending)
        rank = np.argsort(np.argsort(centred @ vecs[:, k], kind="stable"), kind="stable")
        cells.append(np.minimum(rank * grid // n, grid - 1))
    return (cells[0] * grid + cells[1]).astype(np.int64)


def lower_beyond_noise(cost_lower: NDArray[np.float64], cost_other: NDArray[np.float64],
                       blocks: NDArray[np.int64]) -> tuple[bool, float]:
    """Whether the mean of ``cost_lower`` (n,) is below that of ``cost_other`` (n,) significantly.

    The per-point differences' mean over its cluster-robust standard error over
    ``blocks`` (n,) (:func:`spread_blocks`) must exceed the Student quantile at
    :data:`LOWER_LEVEL` with (blocks - 1) degrees of freedom.

    Returns
    -------
    (bool, float): the verdict and the statistic (0 when it cannot be judged)
    """
    d = np.asarray(cost_other, dtype=np.float64) - np.asarray(cost_lower, dtype=np.float64)
    n = len(d)
    if n == 0:
        return False, 0.0
    counts = np.bincount(blocks, minlength=1)
    sums = np.bincount(blocks, weights=d, minlength=1)
    g = int(np.count_nonzero(counts))
    mean = float(d.mean())
    se = float(np.sqrt(np.sum((sums - counts * mean) ** 2))) / n
    if g < MIN_BLOCKS:
        return False, 0.0
    if se <= 0.0:  # every block's differences alike: any positive mean is beyond them
        return mean > 0.0, (float("inf") if mean > 0.0 else 0.0)
    stat = mean / se
    return stat > float(stats.t.ppf(1.0 - LOWER_LEVEL, g - 1)), stat
