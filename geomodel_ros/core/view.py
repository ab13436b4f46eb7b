"""The scene as the sensor saw it: its returns along viewing rays, for free-space tests.

A depth sensor at the origin of the cloud's frame records, along every ray, the nearest
surface. Where a hypothesised surface (e.g. the hidden lower part of a box) would lie,
the returns along the rays towards it say whether that space was seen free (a return
behind it: the sensor looked through), hidden (a return in front of it: an occluder) or
unknown (no return). :class:`SceneView` answers that for any set of target points without
assuming an organized image: the returns are binned on a small angular grid around the
targets' directions (a gnomonic projection centred on them, uniform near its centre).

A ray without a return is unknown only inside the sensor's field of view. A camera (cloud
in its optical frame: z forward) sees a rectangle of image coordinates (x / z, y / z); the
smallest such rectangle holding every return is the part of the field of view the scene
shows, and a ray outside it was never looked along (:meth:`SceneView.beyond_image`): what
lies there is hidden from the sensor, not free.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from threading import Lock

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import ConvexHull, QhullError

from geomodel_ros.core.geometry import frame_with_z, perpendicular_basis, unit3
from geomodel_ros.core.noise import MAD_TO_SIGMA
from geomodel_ros.core.obb import hull_candidates
from geomodel_ros.core.ransac import fit_plane_svd, refine

__all__ = ["SceneView", "RayReturns", "PlaneSegment", "MAX_HALF_ANGLE", "LABEL_SAMPLE"]

#: Largest half angle [rad] of the cone of directions a query looks at: the gnomonic
#: projection stays near-uniform well inside it (cell areas grow with 1 / cos^3).
MAX_HALF_ANGLE = math.radians(45.0)
#: The cone of a query reaches this many cells beyond its outermost target, so that the
#: cells of the outermost targets are complete.
CONE_MARGIN_CELLS = 2.0
#: The points of a label are summarised (e.g. to fit its plane) on about this many of them,
#: every k-th in the cloud's order: a plane of 1000 points is known to a fraction of its
#: noise, and the planes of a frame's labels cost a few milliseconds.
LABEL_SAMPLE = 1000
#: ... taken from a first every-k-th cut of the whole cloud to about this many points
#: (16 labels' worth): only labels of thousands of points (large planes) are summarised
#: for a use, and sorting a whole frame by label would cost more than the rest.
SAMPLE_ROWS = 16 * LABEL_SAMPLE
#: Labels with fewer sampled points get no plane (too few to say anything of one).
MIN_PLANE_SAMPLES = 50
#: A label's plane is refined on its points within this many robust standard deviations
#: (1.4826 median absolute distances) of the least-squares plane: a plane's own noise
#: stays in, another surface of the segment (a box's second face) mostly out.
RESIDUAL_SIGMAS = 3.0


@dataclass(frozen=True)
class PlaneSegment:
    """The plane of one label's points.

    Attributes
    ----------
    label : int
    normal : (3,) float64, unit, towards the sensor (the origin)
    d : float [m], the plane is normal . x + d = 0
    residuals : (s,) float64 [m], distances of the label's sampled points, ascending
    area : float [m^2], area of the convex hull of those points in the plane
    """

    label: int
    normal: NDArray[np.float64]
    d: float
    residuals: NDArray[np.float64]
    area: float

    def share(self, band: float) -> float:
        """Share of the sampled points within ``band`` [m] of the plane."""
        return float(np.searchsorted(self.residuals, band, side="right")) / len(self.residuals)


@dataclass(frozen=True)
class RayReturns:
    """The scene's returns near a set of targets.

    Attributes
    ----------
    nearest : (m,) float64 [m]
        Range of the nearest return in each target's angular cell; NaN where there is none.
    nearest_label : (m,) int64
        Label of that return (-1 also where there is none).
    ranges : (m,) float64 [m]
        Range of each target from the sensor.
    points : (k, 3) float64 [m]
        The scene's returns within the query's cone of directions (for occupancy tests).
    labels : (k,) int64
        Their labels (-1 = none).
    """

    nearest: NDArray[np.float64]
    nearest_label: NDArray[np.int64]
    ranges: NDArray[np.float64]
    points: NDArray[np.float64]
    labels: NDArray[np.int64]


@dataclass(frozen=True)
class SceneView:
    """Every return of a scene, the sensor at the origin.

    Attributes
    ----------
    points : (N, 3) float64 [m]
        The scene's points; non-finite rows are ignored.
    labels : (N,) int64
        Object id per point (-1 = none), as given to the modeling.
    max_range : float [m]
        Points farther from the origin are ignored (as everywhere in the modeling).
    """

    points: NDArray[np.float64]
    labels: NDArray[np.int64]
    max_range: float
    _plane_lock: Lock = field(init=False, repr=False, compare=False, default_factory=Lock)
    _planes: dict[int, PlaneSegment] = field(init=False, repr=False, compare=False,
                                              default_factory=dict)

    def __post_init__(self) -> None:
        """Check that points and labels align."""
        if self.points.ndim != 2 or self.points.shape[1] != 3 or \
                self.labels.shape != (len(self.points),):
            raise ValueError("SceneView needs (N, 3) points and (N,) labels, got "
                             f"{self.points.shape} and {self.labels.shape}")

    @cached_property
    def _columns(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Coordinates by row (3, N) [m] and ranges (N,) [m] of every point, computed once.

        Stored by coordinate (contiguous rows): a query's cone test is then four
        multiply-adds over contiguous arrays, several times faster than a product of the
        (N, 3) cloud with a vector. Non-finite rows and rows beyond ``max_range`` get a
        NaN range, which no test accepts.
        """
        cols = np.ascontiguousarray(self.points.T)
        # Huge finite rows (a driver's garbage, 1e300 m) overflow to an infinite range.
        with np.errstate(over="ignore", invalid="ignore"):
            r = np.sqrt(cols[0] * cols[0] + cols[1] * cols[1] + cols[2] * cols[2])
            r[r > self.max_range] = np.nan
        return cols, r

    @cached_property
    def image_bounds(self) -> NDArray[np.float64] | None:
        """Extent of the returns in image coordinates: (4,) min and max of x / z, y / z.

        None when a return lies at z <= 0 (the cloud is not in a camera's optical frame,
        e.g. a scanner that sees all round): no field of view is known then.
        """
        cols, r = self._columns
        ok = np.isfinite(r)
        x, y, z = cols[0][ok], cols[1][ok], cols[2][ok]
        if z.size == 0 or float(z.min()) <= 0.0:
            return None
        u, v = x / z, y / z
        return np.array([u.min(), u.max(), v.min(), v.max()])

    def beyond_image(self, targets: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Whether the rays to ``targets`` (m, 3) [m] lie outside the field of view (m,).

        Outside: behind the camera (z <= 0) or beyond :attr:`image_bounds`. All False
        when no field of view is known.
        """
        bounds = self.image_bounds
        if bounds is None:
            return np.zeros(len(targets), dtype=bool)
        z = targets[:, 2]
        ahead = z > 0.0
        zs = np.where(ahead, z, 1.0)
        u, v = targets[:, 0] / zs, targets[:, 1] / zs
        inside = ahead & (u >= bounds[0]) & (u <= bounds[1]) & (v >= bounds[2]) & \
            (v <= bounds[3])
        return ~inside

    @cached_property
    def label_samples(self) -> dict[int, NDArray[np.float64]]:
        """Every k-th usable point of each label >= 0: label -> (s, 3) [m], s <~ 2 LABEL_SAMPLE.

        Taken from every k-th point of the cloud (about SAMPLE_ROWS), the usable ones
        (finite, within ``max_range``).
        """
        rows = np.arange(0, len(self.points), max(1, len(self.points) // SAMPLE_ROWS))
        pts = self.points[rows]
        with np.errstate(invalid="ignore"):
            usable = np.sqrt(np.einsum("ij,ij->i", pts, pts)) <= self.max_range
        rows = rows[usable & (self.labels[rows] >= 0)]
        if rows.size == 0:
            return {}
        order = rows[np.argsort(self.labels[rows], kind="stable")]
        ids, starts, counts = np.unique(self.labels[order], return_index=True,
                                        return_counts=True)
        out = {}
        for lab, s0, c in zip(ids.tolist(), starts.tolist(), counts.tolist()):
            step = max(1, c // LABEL_SAMPLE)
            out[lab] = self.points[order[s0:s0 + c:step]]
        return out

    def plane_segments(self, min_area: float = 0.0) -> list[PlaneSegment]:
        """Return the plane of each label's sample that may cover ``min_area`` [m^2].

        Labels of fewer than MIN_PLANE_SAMPLES samples get none, nor labels too small for
        ``min_area``: a plane figure of diameter D has at most the area pi D^2 / 4 of a
        disc (isodiametric inequality), and D is at most the diagonal of the sample's
        bounding box. A least-squares plane, refined on RESIDUAL_SIGMAS times the robust
        scatter of its points about it; computed once per label and view (under a lock:
        the modeling's objects ask from several threads) and shared by every caller.
        """
        out = []
        for lab, pts in self.label_samples.items():
            if len(pts) < MIN_PLANE_SAMPLES:
                continue
            diag2 = float(np.sum(np.ptp(pts, axis=0) ** 2))
            if math.pi / 4.0 * diag2 < min_area:
                continue
            with self._plane_lock:
                seg = self._planes.get(lab)
                if seg is None:
                    seg = self._planes[lab] = _plane_segment(lab, pts)
            out.append(seg)
        return out

    def returns(self, targets: NDArray[np.float64], cell: float,
                band: tuple[float, float] = (0.0, math.inf)) -> RayReturns:
        """Find the scene's nearest return along the ray to each of ``targets`` (m, 3) [m].

        Returns are binned in angular cells of ``cell`` [rad] (tangent-plane units of a
        gnomonic projection centred on the targets' mean direction); a target's return is
        the nearest one in its cell. Targets beyond MAX_HALF_ANGLE of that direction get
        none. The returned ``points`` are those in the cone of the targets whose range
        lies in ``band`` [m].
        """
        r_t = np.sqrt(np.einsum("ij,ij->i", targets, targets))
        dirs = targets / np.maximum(r_t, np.finfo(float).tiny)[:, None]
        e3 = unit3(dirs.sum(axis=0))
        e1, e2 = perpendicular_basis(e3)
        spread = math.acos(min(1.0, max(-1.0, float((dirs @ e3).min()))))
        half = min(spread + CONE_MARGIN_CELLS * cell, MAX_HALF_ANGLE)
        cols, all_r = self._columns
        with np.errstate(invalid="ignore"):  # returns of huge magnitude: inf - inf
            along = cols[0] * e3[0] + cols[1] * e3[1] + cols[2] * e3[2]
            sel = np.flatnonzero(along > math.cos(half) * all_r)
        p_sel, a_sel = cols[:, sel], along[sel]
        keys = _cell_keys((e1 @ p_sel) / a_sel, (e2 @ p_sel) / a_sel, cell, half)
        tkeys = _cell_keys(dirs @ e1 / (dirs @ e3), dirs @ e2 / (dirs @ e3), cell, half)
        tkeys[dirs @ e3 <= math.cos(half)] = -1
        # Only the targets' cells matter: sorted by cell, nearest first; a sentinel cell
        # (key -2, range NaN, label -1) in front keeps the look-up free of empty cases.
        hit = np.flatnonzero(np.isin(keys, tkeys))
        keys = np.r_[-2, keys[hit]]
        ranges = np.r_[np.nan, all_r[sel[hit]]]
        order = np.lexsort((ranges, keys))
        cells, first = np.unique(keys[order], return_index=True)
        head = order[first]
        at = np.minimum(np.searchsorted(cells, tkeys), len(cells) - 1)
        found = (cells[at] == tkeys) & (tkeys >= 0)
        nearest = np.where(found, ranges[head][at], np.nan)
        nearest_label = np.where(found, np.r_[-1, self.labels[sel[hit]]][head][at], -1)
        r_sel = all_r[sel]
        near = sel[(r_sel >= band[0]) & (r_sel <= band[1])]
        return RayReturns(nearest, nearest_label, r_t, self.points[near], self.labels[near])


def _plane_segment(label: int, pts: NDArray[np.float64]) -> PlaneSegment:
    """Plane of one label's sampled points ``pts`` (s, 3) [m] (see SceneView.plane_segments)."""
    model = fit_plane_svd(pts)
    scatter = MAD_TO_SIGMA * float(np.median(np.abs(pts @ model.normal + model.d)))
    if scatter > 0.0:
        model = refine(model, pts, RESIDUAL_SIGMAS * scatter)
    toward = float(model.normal @ pts.mean(axis=0)) < 0.0
    n, d = (model.normal, model.d) if toward else (-model.normal, -model.d)
    return PlaneSegment(label, n, float(d), np.sort(np.abs(pts @ n + d)), _plane_area(pts, n))


def _plane_area(pts: NDArray[np.float64], normal: NDArray[np.float64]) -> float:
    """Area [m^2] of the convex hull of ``pts`` (k, 3) [m] in the plane of ``normal``."""
    xy = pts @ frame_with_z(normal)[:, :2]
    try:
        return float(ConvexHull(hull_candidates(xy)).volume)
    except (QhullError, ValueError):
        return 0.0


def _cell_keys(u: NDArray[np.float64], v: NDArray[np.float64], cell: float,
               half: float) -> NDArray[np.int64]:
    """Angular cell index (n,) of directions with gnomonic coordinates ``u``, ``v`` (n,).

    The cone of half angle ``half`` [rad] is covered by (2k + 1)^2 cells of ``cell``.
    """
    k = int(math.ceil(math.tan(half) / cell)) + 1
    iu = np.clip(np.floor(u / cell), -k, k).astype(np.int64) + k
    iv = np.clip(np.floor(v / cell), -k, k).astype(np.int64) + k
    return iu * (2 * k + 1) + iv
