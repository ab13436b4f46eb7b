"""How much a frame's slow sensor errors bend a flat surface: the null of the bend test.

Real depth cameras add to their pixel-to-pixel noise a range error that varies slowly
across the image (``NoiseEstimate.scale`` 1.6-2.5 on every real frame measured: the noise
across the frame's dominant plane over the local noise). Such an error bends a flat face
by an amount that does not shrink with the face's number of points, so an F-test whose
null hypothesis is independent noise calls flat faces curved
(:func:`~geomodel_ros.core.surface_type.face_bend`). Here the null hypothesis is "a plane
plus this frame's errors", measured on the frame itself: patches of its largest support
plane (desk, table, floor: flat, and seen by the same sensor) as large in the image as the
face under test, each sampled to as many points as the face's region has (the bend that
independent noise leaves in a quadric grows as the points get fewer, and a face's points
are voxel centroids, quieter than the support's raw points: the patches' bends are then
at least the face's share of it). The bend each patch shows (the quadric's RMS height
over the plane, and the turn of its normal) is what the frame's errors alone produce
there; it is scaled to the face's range by the ratio of the depth noise sigma(z) there
and at the patch. A face bends beyond the errors when its bend height exceeds every
patch's (a Monte-Carlo test at level 1 / (patches + 1)) and its turn exceeds ``min_arc``
after the patches' median turn (:func:`bends_beyond`).

The correlation length of the errors is fixed in pixels (the sensor's), so a patch of the
same angular size (radius over range) meets the same part of the error field whatever its
range; the errors' amplitude grows with range as the depth noise does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray
from geomodel_ros.core.noise import NoiseEstimate
from geomodel_ros.core.surface_type import FaceBend, patch_bends

__all__ = ["NULL_PATCHES", "NULL_SAMPLE", "MIN_NULL_PATCHES", "SlowBend", "SlowBendNull",
           "slow_bend_null", "bends_beyond"]

#: Patches of the support measured per bound: a face beyond all of them bends beyond the
#: frame's errors at a level of 1 / (NULL_PATCHES + 1) (2.4 %; the face's turn must
#: exceed ``min_arc`` as well, see :func:`bends_beyond`).
NULL_PATCHES = 40
#: Fewer usable patches than this (a small support, seen in few pixels) say nothing about
#: the errors: no bound (infinite), and no face is found bent by this test.
MIN_NULL_PATCHES = 10
#: The support is sampled to about this many points (every k-th): patches of a few
#: hundred points down to a tenth of a 640 x 480 image's width keep 20 points or more.
NULL_SAMPLE = 20000
#: A patch needs this many points for its quadric (six terms) to say anything.
MIN_PATCH_POINTS = 20
#: A patch whose points spread about their centroid by less than this share of a full
#: disc's RMS radius (r / sqrt 2) is cut by the support's border and left out: a disc cut
#: by a chord half a radius from its centre (80 % of it left) keeps 0.93 of the spread, a
#: half disc 0.80, a patch larger than the whole support less.
MIN_PATCH_SPREAD = 0.9
#: Fixed seed of the patch centres: the null of a frame does not depend on the order in
#: which objects are modeled, nor on their random streams.
NULL_SEED = 20261202


@dataclass(frozen=True)
class SlowBend:
    """The bend the frame's errors give a flat patch of a given size and range.

    Attributes
    ----------
    height : float [m]
        Largest RMS bend height over the patches (inf: too few patches).
    turn : float [rad]
        Median turn of the patches' normals.
    patches : int
        Patches measured.
    """

    height: float
    turn: float
    patches: int


@dataclass(frozen=True)
class SlowBendNull:
    """Patches of a frame's support plane, for the bounds of :meth:`bound`.

    Attributes
    ----------
    points : (P, 3) float64 [m]
        A sample of the support's points (sensor at the origin).
    normal : (3,) float64, unit
        The support plane's normal.
    noise : NoiseEstimate
        The frame's noise (``sigma(z)`` scales the bends from range to range).
    """

    points: NDArray[np.float64]
    normal: NDArray[np.float64]
    noise: NoiseEstimate

    @cached_property
    def _centres(self) -> NDArray[np.float64]:
        rng = np.random.default_rng(NULL_SEED)
        pick = rng.choice(len(self.points), size=min(NULL_PATCHES, len(self.points)),
                          replace=False)
        return self.points[np.sort(pick)]

    @cached_property
    def _squared_distances(self) -> NDArray[np.float64]:
        """(C, P) squared distances [m^2] from the patch centres to the sample's points."""
        c, p = self._centres, self.points
        d2 = np.einsum("ij,ij->i", c, c)[:, None] + np.einsum("ij,ij->i", p, p)[None, :] \
            - 2.0 * (c @ p.T)
        return np.maximum(d2, 0.0)

    def bound(self, radius: float, depth: float, count: int) -> SlowBend:
        """Bend of flat patches as large in the image as a disc of ``radius`` at ``depth``.

        Parameters
        ----------
        radius : float [m]
            Radius of the face's region whose bend is tested.
        depth : float [m]
            Its range from the sensor.
        count : int
            Points of the face's region: each patch is sampled to as many (evenly over
            its points); patches with fewer are left out, and a region of fewer than
            MIN_PATCH_POINTS gets no bound (infinite: too few points to judge).

        Returns
        -------
        SlowBend
            Heights scaled to ``depth`` by sigma(depth) / sigma(patch range).
        """
        if radius <= 0.0 or depth <= 0.0 or count < MIN_PATCH_POINTS:
            return SlowBend(math.inf, 0.0, 0)
        at = np.linalg.norm(self._centres, axis=1)
        r = radius * at / depth
        inside = self._squared_distances <= (r * r)[:, None]
        keep = np.flatnonzero(inside.sum(axis=1) >= count)
        patches = np.array([self.points[np.flatnonzero(inside[i])[
            np.linspace(0, np.count_nonzero(inside[i]) - 1, count).astype(np.int64)]]
            for i in keep]).reshape(len(keep), count, 3)
        # Patches cut by the support's border spread less than a full disc.
        q = patches - patches.mean(axis=1, keepdims=True)
        spread = np.sqrt(np.mean(np.einsum("pki,pki->pk", q, q), axis=1))
        full = spread >= MIN_PATCH_SPREAD * r[keep] / math.sqrt(2.0)
        if np.count_nonzero(full) < MIN_NULL_PATCHES:
            return SlowBend(math.inf, 0.0, int(np.count_nonzero(full)))
        height, turn = patch_bends(patches[full], self.normal)
        sigma_at = np.maximum(self.noise.sigma(at[keep][full]),
                              np.finfo(float).tiny)
        height = height * self.noise.sigma(depth) / sigma_at
        return SlowBend(float(height.max()), float(np.median(turn)), len(height))


def slow_bend_null(points: NDArray[np.float64], labels: NDArray[np.int64],
                   supports: dict[int, tuple[NDArray[np.float64], float]] | None,
                   noise: NoiseEstimate | None) -> SlowBendNull | None:
    """Return the null of the frame's largest support plane, or None without one.

    Parameters
    ----------
    points : (N, 3) float64 [m]
        The frame's points, sensor at the origin.
    labels : (N,) int64
        Object id per point; the supports' ids label their points.
    supports : dict id -> (normal (3,), d)
        Support planes n . x + d = 0.
    noise : NoiseEstimate or None
        The frame's noise; None (or an empty estimate) gives no null.
    """
    if not supports or noise is None or noise.samples == 0:
        return None
    counts = {k: int(np.count_nonzero(labels == k)) for k in supports}
    best = max(counts, key=lambda k: counts[k])
    rows = np.flatnonzero(labels == best)
    if len(rows) < MIN_PATCH_POINTS * MIN_NULL_PATCHES:
        return None
    rows = rows[:: max(1, len(rows) // NULL_SAMPLE)]
    pts = points[rows]
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    normal = np.asarray(supports[best][0], dtype=np.float64)
    return SlowBendNull(pts, normal / np.linalg.norm(normal), noise)


def bends_beyond(bend: FaceBend, null: SlowBend, min_arc: float) -> bool:
    """Whether a face's ``bend`` goes beyond the frame's errors (``null``) and ``min_arc``.

    Its height must exceed every flat patch's, and its turn ``min_arc`` [rad] plus the
    patches' median turn: the errors turn a patch of that size by about as much, and
    where they turn the face the same way as its shape does, they add to its turn; a
    turn that exceeds ``min_arc`` (the least arc a round side must span to be verified as
    one) only by the errors' share may be a flat face's. (Taking the two as independent,
    squares adding, called the handle of the PCL mug and box faces at 1.5 m curved.)
    """
    return bend.height > null.height and bend.turn > min_arc + null.turn
