"""Per-frame sensor noise and point spacing, and the tolerances they imply.

Depth sensors displace each point along its viewing ray by a noise whose standard
deviation grows with the range: sigma(z) = a + b z^2 describes structured-light and stereo
cameras (Khoshelham and Elberink 2012: sigma grows with the square of the depth) and, with
b ~ 0, laser scanners. :func:`estimate_noise` measures it from the cloud itself: on a random
sample of a few thousand local neighbourhoods, the residual of the least-squares plane (the
smallest eigenvalue of the neighbourhood's covariance) is the noise along the normal; divided
by the cosine between normal and ray it is the noise along the ray. Most neighbourhoods of an
indoor scene lie on smooth surfaces, so the median in each depth bin is the noise there
(edges and small curved objects are the minority). The same sample gives the point spacing,
proportional to the range for a camera or a scanner with a fixed angular step.

With ``noise_model = auto`` the tolerances that stand for the noise and the sampling are
derived from the estimate (:func:`resolve_params`), each with a floor at its given value,
so a noise-free cloud keeps every threshold as given:

* noise amplitude t of eq. 6: ``K_AMPLITUDE * sigma`` (t is the noise amplitude itself);
* RANSAC inlier threshold: ``K_INLIER * sigma`` (real noise has heavier tails than a
  Gaussian); support-plane band: ``K_SUPPORT * sigma * cos`` along the plane's normal,
  at the range and incidence of the frame's dominant plane (:func:`support_band`);
* angle tolerance of the model graph: widened by the angle the inlier band subtends over
  the object's extent (added in quadrature);
* working voxel of an object: ``K_VOXEL * sigma`` (normals from voxels much finer than the
  noise point anywhere) and ``VOXEL_SPACINGS`` point spacings (a voxel finer than the
  sampling holds one point);
* segmentation voxel: ``SEG_VOXEL_SPACINGS`` point spacings (its neighbour links must reach
  the next sample);
* reconstruction spacing: the point spacing (finer samples add no detail).

sigma and the spacing are taken at the median range of the points the parameters are for:
the whole frame for the segmentation, each object for its own modeling.

With ``noise_model = auto``, :func:`is_fragment` also decides which ``unknown`` segments are
too small to be objects for a planner.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import nnls

from geomodel_ros.core.fastmath import knn, rows_finite, take_rows
from geomodel_ros.core.input import in_range
from geomodel_ros.core.params import ModelingParams

__all__ = ["NoiseEstimate", "disparity_step", "estimate_noise", "frame_noise", "resolve_params",
           "object_params", "is_fragment", "K_AMPLITUDE", "K_INLIER", "K_SUPPORT", "K_VOXEL",
           "VOXEL_SPACINGS", "SEG_VOXEL_SPACINGS", "FRAGMENT_VOXELS"]

#: Points the neighbourhoods are drawn from (a random subset of the cloud): building a
#: KD-tree on 20k points takes a few milliseconds, and the subset spacing of a 300k-point
#: frame (about 4 pixels) makes neighbourhoods wide compared with the noise, which the
#: plane residual needs (it measures sigma only where the neighbourhood's extent along
#: the surface is well above sigma).
NOISE_SUBSET = 20000
#: Neighbourhoods measured per frame: the median of a few hundred per depth bin has a
#: relative standard error of a few per cent.
NOISE_QUERIES = 2000
#: Points per neighbourhood (a plane has 3 degrees of freedom: 17 are left for the residual).
NOISE_NEIGHBORS = 20
#: Depth bins (equal counts) of the sigma(z) fit.
NOISE_BINS = 6
#: Fewest valid points and usable neighbourhoods for an estimate (fewer: no estimate).
MIN_NOISE_POINTS = 200
MIN_NOISE_SAMPLES = 30
#: A neighbourhood samples a surface when its residual variance is below this share of its
#: smaller in-plane variance (noise sigma below half the in-plane spread: on the desk
#: scenes' neighbourhoods, about 3 mm in radius, sigma is at most a third of it); a cloud
#: of which fewer than MIN_SURFACE_SHARE do is no sampled surface (a random blob) and gets
#: no estimate.
SURFACE_RATIO = 0.25
MIN_SURFACE_SHARE = 0.5
#: Neighbourhoods seen at more than acos(MIN_INCIDENCE_COS) (about 70 degrees) from their
#: normal are not used: the division by the cosine would magnify their errors.
MIN_INCIDENCE_COS = 0.35
#: A neighbourhood's residual variance w0 is sigma_n^2 chi2(nu) / nu with nu = k - 3; the
#: median of chi2(nu) / nu is about (1 - 2 / (9 nu))^3 (Wilson-Hilferty), so the median of
#: the residual is divided by its square root to estimate sigma_n.
_NU = NOISE_NEIGHBORS - 3
MEDIAN_CHI_FACTOR = math.sqrt((1.0 - 2.0 / (9.0 * _NU)) ** 3)
#: Guard against division by a zero length [m].
_TINY = 1e-12

#: Second entropy word of the estimate's random stream (the first is ``params.seed``): any
#: fixed value will do; it keeps the stream apart from the modeling's.
NOISE_STREAM = 14
#: The dominant plane of :func:`_plane_scale`: the best of this many neighbourhood planes,
#: taking the points within PLANE_BAND_SIGMAS local sigmas (wide: the slow errors it
#: measures are a few local sigmas) or PLANE_BAND_SPACINGS point spacings of it; it must
#: hold at least PLANE_MIN_SHARE of the sample (a desk, floor or wall, not a box face).
PLANE_HYPOTHESES = 32
PLANE_SAMPLE = 5000
PLANE_BAND_SIGMAS = 10.0
PLANE_BAND_SPACINGS = 2.0
PLANE_MIN_SHARE = 0.1
#: Refits of the dominant plane to its points within PLANE_TRIM robust sigmas (3: the
#: Gaussian's points, not the objects standing on it).
PLANE_ITERATIONS = 3
PLANE_TRIM = 3.0
#: 1.4826 MAD is the standard deviation of a Gaussian.
MAD_TO_SIGMA = 1.4826
#: t of eq. 6 = this many sigma (t is the noise amplitude).
K_AMPLITUDE = 1.0
#: Inlier bands (RANSAC, support planes) = this many sigma. A Gaussian holds 99.7 % of its
#: points within 3 sigma; real depth noise has heavier tails (flying pixels, stereo
#: mismatches): on the table of the PCL mug scene and of osd_learn frames 3 robust sigmas
#: hold 97-98 % of the points, 4 hold 98-99 %, and the mug's cylinder verifies only from
#: about 3.5 sigma. A wider band lets flat models verify on small round objects (at 4 sigma
#: a 60 mm cone under Kinect-class noise verified as a cuboid). 3.5 serves both.
K_INLIER = 3.5
#: Support-plane band = this many sigma along the plane's normal: a desk or floor must keep
#: nearly all its points (4 sigma: 98-99 % on the real tables above), or the rest joins the
#: objects standing on it as a rim.
K_SUPPORT = 4.0
#: Object working voxel >= this many sigma. Normals come from ``normal_neighbors`` (16)
#: voxels, spread about 1.6 voxels around their centre: a plane fit over them tilts by
#: about sigma / (4.5 voxels). Region growing joins neighbours whose normals differ by less
#: than ``face_angle_threshold`` (0.2 rad); with the difference of two such normals at 3
#: standard deviations (3 sqrt(2) sigma / (4.5 voxels)) below it, voxel >= 4.7 sigma.
K_VOXEL = 5.0
#: ... but at most the object's extent across over this many voxels: a small object (a
#: cone 60 mm across) keeps enough voxels to show its shape.
MIN_VOXELS_ACROSS = 10.0
#: Object voxel >= this many point spacings: a finer voxel holds one sample and only costs
#: time. One spacing leaves the desk scenes' 3 mm voxel as given (spacings below 3 mm).
VOXEL_SPACINGS = 1.0
#: Segmentation voxel >= this many point spacings: its neighbour links (at most
#: ``seg_max_edge_factor`` voxels) must reach the next sample also where a surface is seen
#: at grazing incidence (a far floor: sampled several times sparser along the ray than the
#: median spacing). Twice the spacing leaves the desk scenes' 4 mm as given (spacings up
#: to 2 mm).
SEG_VOXEL_SPACINGS = 2.0
#: An ``unknown`` segment is a fragment, not an object for a planner, when its observed
#: area is below that of a square this many segmentation voxels across (4.8 cm at the
#: desk's 4 mm voxel, about 12 cm for a Kinect at 2 m): the segmentation cuts the scene at
#: that resolution, and smaller pieces it cannot type are shreds of larger surfaces (edges,
#: flying pixels, carpet, the rim of a hole). Typed objects are never fragments.
FRAGMENT_VOXELS = 12.0


@dataclass(frozen=True)
class NoiseEstimate:
    """Depth noise and point spacing of one frame.

    Attributes
    ----------
    a : float [m]
        Range-independent noise sigma.
    b : float [1/m]
        Quadratic term: sigma(z) = a + b z^2 at range z [m] along the ray.
    spacing_per_m : float
        Point spacing per metre of range: spacing(z) = spacing_per_m * z [m].
    spacing : float [m]
        Median point spacing of the frame.
    depth : float [m]
        Median range of the sampled points.
    samples : int
        Neighbourhoods used (0: no estimate, every value 0).
    scale : float
        Factor (>= 1) by which the residual of the frame's dominant plane exceeded the
        local noise; ``a`` and ``b`` include it (:func:`_plane_scale`).
    plane_cos : float
        Median cosine of the angle between the dominant plane's normal and the rays to its
        points (1 when there is none): its noise along the normal is sigma * plane_cos.
    plane_depth : float [m]
        Median range of the dominant plane's points (0 when there is none).
    """

    a: float = 0.0
    b: float = 0.0
    spacing_per_m: float = 0.0
    spacing: float = 0.0
    depth: float = 0.0
    samples: int = 0
    scale: float = 1.0
    plane_cos: float = 1.0
    plane_depth: float = 0.0

    def sigma(self, z: float | NDArray[np.float64]) -> float | NDArray[np.float64]:
        """Noise sigma [m] along the ray at range ``z`` [m] (a float or an array of ranges)."""
        return self.a + self.b * z * z

    def spacing_at(self, z: float) -> float:
        """Point spacing [m] at range ``z`` [m]."""
        return self.spacing_per_m * z

    def to_dict(self) -> dict:
        """JSON-ready dictionary (the CLI's ``noise``)."""
        return {"a": float(self.a), "b": float(self.b), "sigma_at_1m": float(self.sigma(1.0)),
                "spacing_per_m": float(self.spacing_per_m), "spacing": float(self.spacing),
                "depth": float(self.depth), "samples": int(self.samples),
                "scale": float(self.scale), "plane_cos": float(self.plane_cos),
                "plane_depth": float(self.plane_depth)}


def _sample(points: NDArray[np.float64], rng: np.random.Generator, max_range: float
            ) -> tuple[NDArray[np.float64], float]:
    """Draw a random subset of about NOISE_SUBSET usable rows of ``points`` (N, 3) [m].

    Usable: finite and within ``max_range`` [m] of the origin. Each usable row is kept
    independently (Bernoulli), so the subset samples every surface like a random sample of
    the full cloud's density times the kept fraction, and neither depends on the unusable
    rows (a driver's garbage changes nothing). The subset is returned in random order.

    Returns
    -------
    sub : (M, 3) float64 array [m]
    fraction : float
        Kept fraction of the usable rows (1 when every row was kept).
    """
    rows = np.flatnonzero(in_range(points, max_range))
    fraction = min(1.0, NOISE_SUBSET / max(len(rows), 1))
    if fraction < 1.0:
        rows = rows[rng.random(len(rows)) < fraction]
    # Random order: the first NOISE_QUERIES rows are the neighbourhoods' centres.
    return take_rows(points, rows[rng.permutation(len(rows))]), fraction


def _neighbourhoods(sub: NDArray[np.float64], fraction: float
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                               NDArray[np.float64]]:
    """Noise along the ray, range and spacing of a sample of local neighbourhoods.

    Parameters
    ----------
    sub : (M, 3) float64 array [m], finite, in random order, M >= MIN_NOISE_POINTS
        The subset of the cloud the neighbourhoods are taken from.
    fraction : float
        Share of the cloud's points in ``sub``.

    Returns
    -------
    sigma_ray, range, spacing : (Q,) float64 arrays [m]
        Plane residual divided by the incidence cosine, range of the neighbourhood's
        centre, and the point spacing of the full cloud there.
    planes : (Q, 4) float64 array
        The neighbourhoods' planes (unit normal, offset d: n . x + d = 0).

    When fewer than MIN_SURFACE_SHARE of the neighbourhoods are surface-like (residual
    variance below SURFACE_RATIO times the smaller in-plane variance), the points sample
    no surface (a random blob) and every array is empty. Otherwise all count: the median
    is robust to the edges and corners among them, and leaving out the noisiest
    neighbourhoods would bias it low.
    """
    k = min(NOISE_NEIGHBORS, len(sub))
    nb, sqdist = knn(sub, k, return_sqdist=True, queries=sub[:NOISE_QUERIES])
    dist = np.sqrt(sqdist)
    hood = np.take(sub, nb, axis=0)                            # (Q, k, 3)
    centre = hood.mean(axis=1)
    d = hood - centre[:, None, :]
    w, v = np.linalg.eigh(np.matmul(d.transpose(0, 2, 1), d) / k)
    z = np.linalg.norm(centre, axis=1)
    cos = np.abs(np.einsum("qi,qi->q", v[:, :, 0], centre)) / np.maximum(z, _TINY)
    resid = np.sqrt(np.maximum(w[:, 0], 0.0) * k / max(k - 3, 1))
    # The k points within the distance r_k of the k-th (the centre included) cover about
    # pi r_k^2 = (k - 1/2) spacing_sub^2 of the surface, on a grid as on a random sample;
    # the full cloud is 1 / fraction times denser.
    nn = dist[:, -1] * np.sqrt(math.pi * fraction / (k - 0.5))
    surface = w[:, 0] < SURFACE_RATIO * w[:, 1]
    if np.count_nonzero(surface) < MIN_SURFACE_SHARE * len(w):
        return (np.zeros(0),) * 3 + (np.zeros((0, 4)),)   # not a sampled surface
    ok = cos >= MIN_INCIDENCE_COS
    normal = v[ok, :, 0]
    planes = np.column_stack([normal, -np.einsum("qi,qi->q", normal, centre[ok])])
    return resid[ok] / cos[ok] / MEDIAN_CHI_FACTOR, z[ok], nn[ok], planes


def estimate_noise(points: NDArray[np.float64], rng: np.random.Generator | int | None = None,
                   max_range: float = math.inf) -> NoiseEstimate:
    """Estimate sigma(z) = a + b z^2 and the point spacing of a cloud in the sensor frame.

    Parameters
    ----------
    points : (N, 3) float array [m]
        Cloud with the sensor at the origin; non-finite rows are ignored.
    rng : Generator, seed or None
        Randomness of the neighbourhood sample.
    max_range : float [m]
        Rows farther from the origin are ignored (see ``ModelingParams.max_range``).

    Returns
    -------
    NoiseEstimate
        ``samples == 0`` (every value 0) when the cloud is too small to measure.
    """
    rng = np.random.default_rng(rng)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    sub, fraction = _sample(pts, rng, max_range)
    if len(sub) < MIN_NOISE_POINTS:
        return NoiseEstimate()
    s, z, spacing, planes = _neighbourhoods(sub, fraction)
    if len(s) < MIN_NOISE_SAMPLES:
        return NoiseEstimate()
    a, b = _fit_quadratic(s, z)
    per_m = float(np.median(spacing / np.maximum(z, _TINY)))
    scale, plane_cos, plane_depth = _plane_scale(sub, planes, a, b, per_m, rng)
    return NoiseEstimate(a * scale, b * scale, per_m, float(np.median(spacing)),
                         float(np.median(z)), len(s), scale, plane_cos, plane_depth)


def _plane_scale(sub: NDArray[np.float64], planes: NDArray[np.float64], a: float, b: float,
                 spacing_per_m: float, rng: np.random.Generator
                 ) -> tuple[float, float, float]:
    """Ratio (>= 1) of the noise across the frame's dominant plane to the local noise.

    The local residuals see only the noise within a few centimetres; real sensors add
    errors that vary slowly across the image (depth distortion, stereo smoothing), which
    a model fitted to a whole object meets as well. Among PLANE_HYPOTHESES of the
    neighbourhoods' ``planes`` (Q, 4), the one with the most of the first PLANE_SAMPLE
    points of ``sub`` (M, 3) [m] within ``PLANE_BAND_SIGMAS`` local sigmas (or
    ``PLANE_BAND_SPACINGS`` spacings) is refitted to them, then PLANE_ITERATIONS times to
    the points within ``PLANE_TRIM`` robust sigmas (1.4826 MAD) of it; the robust sigma of
    the residuals along the ray, over the median local sigma a + b z^2 of the same points,
    is the ratio. 1 when no plane holds ``PLANE_MIN_SHARE`` of the points or the local
    noise is ~0.

    Returns
    -------
    scale : float
        The ratio.
    cos : float
        Median cosine between the dominant plane's normal and its points' rays (1 when
        there is no dominant plane).
    depth : float [m]
        Median range of the dominant plane's points (0 when there is none).
    """
    pts = sub[:PLANE_SAMPLE]
    z = np.sqrt(np.einsum("ij,ij->i", pts, pts))
    local = a + b * z * z
    band = np.maximum(PLANE_BAND_SIGMAS * local, PLANE_BAND_SPACINGS * spacing_per_m * z)
    pick = planes[rng.permutation(len(planes))[:PLANE_HYPOTHESES]]
    near = np.abs(pts @ pick[:, :3].T + pick[:, 3]) <= band[:, None]   # (M, H)
    inl = near[:, int(np.argmax(near.sum(axis=0)))]
    if np.count_nonzero(inl) < PLANE_MIN_SHARE * len(pts):
        return 1.0, 1.0, 0.0
    base = float(np.median(local[inl]))
    if base <= _TINY:
        return 1.0, 1.0, 0.0
    robust = 0.0
    for _ in range(PLANE_ITERATIONS):
        q = pts[inl]
        c = q.mean(axis=0)
        normal = np.linalg.eigh((q - c).T @ (q - c))[1][:, 0]
        dist = (pts - c) @ normal
        robust_n = MAD_TO_SIGMA * float(np.median(np.abs(dist[inl])))
        inl = inl & (np.abs(dist) <= PLANE_TRIM * robust_n)
        if np.count_nonzero(inl) < MIN_NOISE_SAMPLES:
            return 1.0, 1.0, 0.0
        cos = np.maximum(np.abs(pts[inl] @ normal) / z[inl], MIN_INCIDENCE_COS)
        robust = MAD_TO_SIGMA * float(np.median(np.abs(dist[inl] / cos)))
    return max(1.0, robust / base), float(np.median(cos)), float(np.median(z[inl]))


def _fit_quadratic(s: NDArray[np.float64], z: NDArray[np.float64]) -> tuple[float, float]:
    """Fit sigma = a + b z^2 (a, b >= 0) to the medians of ``s`` in equal-count depth bins."""
    order = np.argsort(z)
    bins = np.array_split(order, min(NOISE_BINS, max(1, len(z) // MIN_NOISE_SAMPLES)))
    zm = np.array([np.median(z[i]) for i in bins])
    sm = np.array([np.median(s[i]) for i in bins])
    if zm[-1] - zm[0] <= 1e-9 * max(zm[-1], 1.0) or len(bins) < 2:
        return float(np.median(s)), 0.0
    # Scale the columns so that the least squares is well conditioned at any range.
    zs = float(zm.max())
    (a, b), _ = nnls(np.stack([np.ones_like(zm), (zm / zs) ** 2], axis=1), sm)
    return float(a), float(b / (zs * zs))


def _median_range(points: NDArray[np.float64]) -> float:
    """Median distance [m] of the finite rows of ``points`` (N, 3) from the origin."""
    step = max(1, len(points) // NOISE_SUBSET)
    sub = points[::step]
    sub = sub[rows_finite(sub)]
    return float(np.median(np.linalg.norm(sub, axis=1))) if len(sub) else 0.0


def object_params(params: ModelingParams, noise: NoiseEstimate, depth: float,
                  extent: float = math.inf) -> ModelingParams:
    """``params`` with the noise- and spacing-dependent tolerances at range ``depth`` [m].

    Every derived value is at least the one given (its floor), so the result equals
    ``params`` for a noise-free, densely sampled cloud. ``noise_model = fixed`` or an
    empty estimate return ``params`` itself.

    Parameters
    ----------
    params : ModelingParams
    noise : NoiseEstimate
    depth : float [m]
        Range of the object (or frame) along the ray.
    extent : float [m]
        Size of the object across: its faces' normals tilt by up to the angle the inlier
        band subtends over it (``angle_tolerance`` grows by atan(band / extent), added in
        quadrature), and its working voxel is at most ``extent / MIN_VOXELS_ACROSS``
        (infinite: neither).
    """
    if params.noise_model != "auto" or noise.samples == 0:
        return params
    sigma, spacing = noise.sigma(depth), noise.spacing_at(depth)
    tilt = math.atan(K_INLIER * sigma / extent) if extent > 0.0 else 0.0
    values = {
        "angle_tolerance": math.hypot(params.angle_tolerance, tilt),
        "noise_amplitude": max(params.noise_amplitude, K_AMPLITUDE * sigma),
        "ransac_threshold": max(params.ransac_threshold, K_INLIER * sigma),
        "voxel_size": max(params.voxel_size, min(max(K_VOXEL * sigma, VOXEL_SPACINGS * spacing),
                                                 extent / MIN_VOXELS_ACROSS)),
        "seg_voxel_size": max(params.seg_voxel_size, SEG_VOXEL_SPACINGS * spacing),
        "seg_plane_threshold": max(params.seg_plane_threshold, support_band(noise, depth)),
        "reconstruction_spacing": max(params.reconstruction_spacing, spacing),
    }
    if all(values[k] == getattr(params, k) for k in values):
        return params
    return dataclasses.replace(params, **_clipped(values))


def support_band(noise: NoiseEstimate, depth: float) -> float:
    """Inlier band [m] of the support planes: K_SUPPORT sigma along their normal.

    Distances to a plane are measured along its normal, where the noise along the ray is
    reduced by the cosine of the incidence; both are those of the frame's dominant plane
    (its median range and incidence), or ``depth`` [m] and 1 when there is none.
    """
    at = noise.plane_depth if noise.plane_depth > 0.0 else depth
    return K_SUPPORT * noise.sigma(at) * noise.plane_cos


def _clipped(values: dict[str, float]) -> dict[str, float]:
    """``values`` clipped to their parameters' allowed ranges."""
    from geomodel_ros.core.params import PARAMETERS

    highs = {p.name: p.high for p in PARAMETERS}
    return {k: min(v, highs[k]) if highs[k] is not None else v for k, v in values.items()}


def frame_noise(points: NDArray[np.float64], params: ModelingParams) -> NoiseEstimate:
    """Noise estimate of a frame ``points`` (N, 3) [m] from its own random stream.

    The stream is seeded with ``(params.seed, NOISE_STREAM)``: reproducible, and
    independent of the segmentation's and the modeling's, so that estimating the noise
    changes none of their random draws.
    """
    return estimate_noise(points, np.random.default_rng([params.seed, NOISE_STREAM]),
                          params.max_range)


def resolve_params(points: NDArray[np.float64], params: ModelingParams,
                   noise: NoiseEstimate | None = None
                   ) -> tuple[ModelingParams, NoiseEstimate | None]:
    """Concrete parameters for ``points`` (a frame or one object) and the noise estimate.

    Parameters
    ----------
    points : (N, 3) float array [m]
        The frame (or object) in the sensor frame; non-finite rows are ignored.
    params : ModelingParams
        With ``noise_model = fixed`` they are returned unchanged and nothing is estimated.
    noise : NoiseEstimate, optional
        The frame's estimate, when known (e.g. for one of its objects); otherwise
        :func:`frame_noise` of ``points``.

    Returns
    -------
    params : ModelingParams
        :func:`object_params` at the median range of ``points``.
    noise : NoiseEstimate or None
        None with ``noise_model = fixed``.
    """
    if params.noise_model != "auto":
        return params, None
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if noise is None:
        noise = frame_noise(pts, params)
    return object_params(params, noise, _median_range(pts)), noise


def is_fragment(point_count: int, depth: float, noise: NoiseEstimate | None,
                params: ModelingParams) -> bool:
    """Tell whether an ``unknown`` segment of ``point_count`` points at ``depth`` is a fragment.

    Its observed area, ``point_count * spacing(depth)^2`` [m^2], is compared with a square
    of ``FRAGMENT_VOXELS`` segmentation voxels (``seg_voxel_size`` as resolved for the
    frame's spacing). Never with ``noise_model = fixed`` or without an estimate.
    """
    if params.noise_model != "auto" or noise is None or noise.samples == 0:
        return False
    spacing = noise.spacing_at(depth)
    side = FRAGMENT_VOXELS * max(params.seg_voxel_size, SEG_VOXEL_SPACINGS * spacing)
    return point_count * spacing * spacing < side * side


#: 1/z [1/m] is rounded to this many decimals before its distinct values are taken (as in
#: ``tools.noise_calibration``): far finer than a disparity step (Kinect v1: 2.85e-3 1/m),
#: coarser than the float32 storage of real frames (about 1e-7 at 1 m).
DISPARITY_DECIMALS = 6
#: The step is measured on at most this many points, taken at a fixed stride: a quantised
#: frame has a few hundred levels (the office scene 317 over 0.8-3.8 m), each held by many
#: points, so a sample this size still meets nearly all of them.
DISPARITY_SAMPLE = 20000
#: A frame is quantised in disparity when its sample takes at most this share of distinct
#: 1/z values (on average two or more points per level); an unquantised frame's values are
#: all distinct, and the median gap between them is only the sample's density, no step.
DISPARITY_MAX_DISTINCT_SHARE = 0.5
#: Levels blurred by a small depth jitter (depths averaged, filtered, transformed or stored
#: with float noise) are found as the runs of sorted 1/z split by gaps wider than a
#: resolution tau; tau is scanned in this many geometric steps per octave, from the median
#: gap (no finer tau holds at most DISPARITY_MAX_DISTINCT_SHARE levels) up to the widest.
DISPARITY_SCAN_PER_OCTAVE = 4
#: The runs are the frame's levels where they are stable: doubling tau merges at most this
#: share of them (empty gaps between levels, much wider than the gaps inside one). Runs of
#: an unquantised sample are not: its gaps are near exponential, and doubling any tau that
#: leaves at most half as many runs as points merges half of them or more. The same share
#: bounds the neighbouring levels found closer than half a step (next constant).
DISPARITY_STABLE_SHARE = 0.05
#: Neighbouring levels lie at least this many steps apart: the camera's levels are one
#: step apart, or several where levels are empty; the rounding of the stored depths moves
#: them by less than half a step (osd_learn, office, milk carton and mug frames: no gap
#: between distinct 1/z below 0.497 of their median). Clumps of continuous depths (a few
#: objects at separate ranges) are spaced at random: about 3 in 10 of their gaps are
#: shorter than half the median gap.
DISPARITY_MIN_LEVEL_GAP = 0.5
#: Stable runs count as a period only over at least this many levels: clumps that happen
#: to keep every gap within the bound above are 1 in 200 at this count (0.707 ** 15).
DISPARITY_MIN_LEVELS = 16
#: Two nested depth ranges of one frame see one lattice: the step of a range is taken only
#: when its farther half gives the same within this share (the share of levels either may
#: have merged or missed, :data:`DISPARITY_STABLE_SHARE`). Office, milk carton, mug and two
#: osd_learn frames with 0.05-2 mm of z jitter: 182 nested pairs, within 3.6 % (median
#: 0.1 %). Clumps of continuous depths that pass the tests above in one range rarely do in
#: its half, and not with the same gap (600 clouds of 40-1000 random clumps: 2 such pairs,
#: 13-16 % apart).
DISPARITY_RANGE_AGREEMENT = DISPARITY_STABLE_SHARE


def disparity_step(points: NDArray[np.float64]) -> float | None:
    """Disparity quantisation step of a frame: the median gap between its levels of 1/z.

    The levels are the distinct values of 1/z when they are few (at most
    :data:`DISPARITY_MAX_DISTINCT_SHARE` of the sampled points); otherwise, where a jitter
    of the depths has made every value distinct, the stable runs of the sorted 1/z
    (:func:`_blurred_levels`) in the largest far range of the frame where they are resolved
    (:func:`_far_range_step`).

    Parameters
    ----------
    points : (N, 3) float array [m]
        The frame in the sensor frame, optical axis along +z or -z; non-finite rows and
        points at z = 0 (or at a z so small that 1/z overflows once scaled for rounding)
        are ignored.

    Returns
    -------
    float or None
        The step in 1/z [1/m] (a depth step of ``step * z**2`` [m] at depth z), or None for
        a frame whose depths are not quantised, whose levels are blurred into a continuum,
        or with too few points.
    """
    z = np.asarray(points, dtype=np.float64).reshape(-1, 3)[:, 2]
    z = np.abs(z[::max(1, len(z) // DISPARITY_SAMPLE)])
    # A depth so small that 1/z, scaled for the rounding to DISPARITY_DECIMALS, overflows
    # (a subnormal or 1e-305 m from a malformed message) has no level: its gaps would be
    # inf - inf.
    z = z[np.isfinite(z) & (z >= 10.0 ** DISPARITY_DECIMALS / np.finfo(np.float64).max)]
    if len(z) < 2:
        return None
    ordered = np.sort(1.0 / z)
    rounded = np.round(ordered, DISPARITY_DECIMALS)  # sorted too: rounding keeps the order
    new = np.concatenate(([True], rounded[1:] != rounded[:-1]))
    inv = rounded[new]
    if len(inv) < 2:
        return None
    if len(inv) <= DISPARITY_MAX_DISTINCT_SHARE * len(z):
        return float(np.median(np.diff(inv)))
    exact = np.concatenate(([True], ordered[1:] != ordered[:-1]))
    return _far_range_step(ordered, np.cumsum(exact))


def _far_range_step(inv: NDArray[np.float64], distinct: NDArray[np.int64]) -> float | None:
    """Step of levels blurred by a jitter of the depths, found where they are resolved.

    The step is one constant in 1/z, but a jitter of sd ``s`` in depth is ``s / z**2`` in
    1/z: the near levels blur first (0.5 mm at 0.84 m is 0.24 of a Kinect step, at 3 m
    0.02). So the frame's sorted 1/z are taken in nested ranges from the far end, the whole
    sample, its farther half, the farther half of that, and so on; a range's step
    (:func:`_blurred_levels`, :func:`_level_step`) is the frame's when the range's farther
    half gives the same (:data:`DISPARITY_RANGE_AGREEMENT`), the largest such range first.
    A range whose values repeat exactly (at most :data:`DISPARITY_MAX_DISTINCT_SHARE` of
    them distinct, not rounded) ends the search: a jitter leaves no two depths equal, so that
    range is not jittered levels and the nearer depths it left are continuous (in a
    noise-free render, 1/z of a plane is affine in the pixel row: each row of a far desk is
    one exact value, a lattice of rows).

    Parameters
    ----------
    inv : (n,) float64 array [1/m]
        Sorted inverse depths of the sample, n >= 2 (the far end first).
    distinct : (n,) int64 array
        Distinct values (exactly, not rounded) among ``inv[:i + 1]``.

    Returns
    -------
    float or None
        The step [1/m], or None when no two nested ranges of at least
        ``2 * DISPARITY_MIN_LEVELS`` points agree on one.
    """
    m = len(inv)
    found = None
    while m >= 2 * DISPARITY_MIN_LEVELS and distinct[m - 1] > DISPARITY_MAX_DISTINCT_SHARE * m:
        centres = _blurred_levels(inv[:m])
        step = None if centres is None else _level_step(centres)
        if step is not None and found is not None \
                and abs(step - found) <= DISPARITY_RANGE_AGREEMENT * found:
            return found
        found = step
        m //= 2
    return None


def _blurred_levels(inv: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """Split sorted 1/z into levels at the finest gap resolution where the split is stable.

    Parameters
    ----------
    inv : (n,) float64 array [1/m]
        Sorted inverse depths, n >= 2.

    Returns
    -------
    (L,) float64 array [1/m] or None
        The levels' mean 1/z, ascending, or None when no resolution gives at least
        :data:`DISPARITY_MIN_LEVELS` levels, at most :data:`DISPARITY_MAX_DISTINCT_SHARE`
        of the points, that doubling the resolution leaves nearly unmerged
        (:data:`DISPARITY_STABLE_SHARE`). The levels are taken at the coarser resolution of
        the finest stable pair.
    """
    n = len(inv)
    gaps = np.diff(inv)
    finest = max(float(np.partition(gaps, len(gaps) // 2)[len(gaps) // 2]),
                 10.0 ** -DISPARITY_DECIMALS)
    # Gaps per scan interval (tau_k, tau_k+1]: runs(tau_k) = n - gaps no wider than tau_k.
    grade = np.ceil(np.log2(np.maximum(gaps, finest) / finest) * DISPARITY_SCAN_PER_OCTAVE)
    count = np.cumsum(np.bincount(grade.astype(np.int64)))
    taus = finest * 2.0 ** (np.arange(len(count)) / DISPARITY_SCAN_PER_OCTAVE)
    runs = n - count
    merged = n - np.append(count[DISPARITY_SCAN_PER_OCTAVE:],
                           np.full(min(DISPARITY_SCAN_PER_OCTAVE, len(count)), n - 1))
    stable = ((runs - merged <= DISPARITY_STABLE_SHARE * runs)
              & (runs <= DISPARITY_MAX_DISTINCT_SHARE * n) & (merged >= DISPARITY_MIN_LEVELS))
    if not stable.any():
        return None
    starts = np.concatenate(([0], np.flatnonzero(gaps > 2.0 * taus[np.argmax(stable)]) + 1))
    return np.add.reduceat(inv, starts) / np.diff(np.append(starts, n))


def _level_step(centres: NDArray[np.float64]) -> float | None:
    """Step of levels found in blurred 1/z: the median gap between their centres.

    Parameters
    ----------
    centres : (L,) float64 array [1/m]
        Mean 1/z of each level, ascending.

    Returns
    -------
    float or None
        The step [1/m], or None when the levels are no lattice: more than
        :data:`DISPARITY_STABLE_SHARE` of the neighbouring levels closer than
        :data:`DISPARITY_MIN_LEVEL_GAP` steps. (Their width needs no test of its own: the
        runs are split at gaps wider than any inside them, stable under a doubling.)
    """
    gaps = np.diff(centres)
    step = float(np.median(gaps))
    close = np.count_nonzero(gaps < DISPARITY_MIN_LEVEL_GAP * step)
    return None if close > DISPARITY_STABLE_SHARE * len(gaps) else step
