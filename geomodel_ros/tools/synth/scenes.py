"""Synthetic desk scenes of the paper, rendered with the ray-casting camera.

All scenes share one desk: a 400 x 400 mm rectangle centred at
(-9.030, -43.117, 518.281) mm with unit normal along (0, -0.766, -0.643), i.e.
tilted 40 degrees and facing the camera.  Objects rest on the desk (their
lowest point lies exactly on the desk plane, computed from the analytic
support function), except stacked ones, whose bottom lies exactly on the top of the
object below.  Labels: desk = 0, objects 1..K in the documented order.

The segmentation scenes (:data:`SEGMENTATION_SCENE_NAMES`, rendered with
:data:`SEGMENTATION_CAMERA`) have objects in contact: ``touching`` (two boxes face to
face, a cylinder against a box), ``stacked`` (box on box, cylinder on box),
``occluded`` (a tall box hiding half of a cylinder) and ``apart`` (box, cylinder,
sphere well apart).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.ndimage import gaussian_filter1d

from .camera import PinholeCamera
from .shapes import Box, Cone, Cylinder, Rectangle, Shape, Sphere, Torus

__all__ = [
    "GroundTruthObject",
    "GROUND_TRUTH_TYPES",
    "NoiseModel",
    "SENSOR_NOISE",
    "KINECT_CLASS_NOISE",
    "KINECT_REAL_NOISE",
    "MIXED_EDGE_NOISE",
    "KINECT_INV_DEPTH_STEP",
    "MIXED_EDGE_MIN_JUMP",
    "mixed_pixel_share",
    "correlated_field",
    "quantize_disparity",
    "Scene",
    "SCENE_NAMES",
    "PAPER_SCENE_NAMES",
    "PAPER_CAMERA",
    "TINY_CAMERA",
    "SEGMENTATION_CAMERA",
    "SEGMENTATION_SCENE_NAMES",
    "DESK_CENTER",
    "DESK_NORMAL",
    "DESK_SIZE",
    "desk_frame",
    "scene_geometry",
    "render_scene",
    "apply_noise",
]

# --------------------------------------------------------------------------- ground truth
#: dimension keys required by each ground-truth type
GROUND_TRUTH_TYPES: dict[str, tuple[str, ...]] = {
    "plane": ("length", "width"),
    "cuboid": ("length", "width", "height"),
    "cylinder": ("radius", "height"),
    "cone": ("radius", "height"),
    "sphere": ("radius",),
    "frustum": ("radius", "top_radius", "height"),
    "torus": ("major_radius", "minor_radius"),
}


@dataclass(frozen=True, eq=False)
class GroundTruthObject:
    """Analytic ground truth of one scene object, in the modeling's conventions.

    Parameters
    ----------
    id : int
        Label value used in :attr:`Scene.labels` / :attr:`Scene.label_image`.
    type : str
        One of ``"plane"``, ``"cuboid"``, ``"cylinder"``, ``"cone"``,
        ``"sphere"``, ``"frustum"``, ``"torus"``.
    center : (3,) float64 array [m]
        Box centre (plane, cuboid), midpoint of the axis segment (cylinder,
        cone), centre (sphere, torus).
    rotation : (3, 3) float64 array
        Columns are the object's x, y, z axes in the camera frame.  Plane:
        z = normal facing the camera (``normal . center < 0``); cylinder: z =
        axis; cone: z = axis, base -> apex; torus: z = symmetry axis.
    dimensions : dict[str, float]
        All in [m]. plane: length, width (along x, y); cuboid: length, width,
        height (extents along x, y, z); cylinder, cone: radius, height;
        sphere: radius; torus: major_radius, minor_radius.
    """

    id: int
    type: str
    center: np.ndarray
    rotation: np.ndarray
    dimensions: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.type not in GROUND_TRUTH_TYPES:
            raise ValueError(f"type must be one of {tuple(GROUND_TRUTH_TYPES)}, got {self.type!r}")
        center = np.array(self.center, dtype=np.float64).reshape(-1)
        rotation = np.array(self.rotation, dtype=np.float64)
        if center.shape != (3,) or rotation.shape != (3, 3):
            raise ValueError("center must be (3,) and rotation (3, 3)")
        keys = GROUND_TRUTH_TYPES[self.type]
        if set(self.dimensions) != set(keys):
            raise ValueError(f"dimensions of a {self.type!r} must have exactly the keys {keys}")
        center.setflags(write=False)
        rotation.setflags(write=False)
        object.__setattr__(self, "id", int(self.id))
        object.__setattr__(self, "center", center)
        object.__setattr__(self, "rotation", rotation)
        object.__setattr__(self, "dimensions", {k: float(self.dimensions[k]) for k in keys})

    def to_dict(self) -> dict:
        """JSON-ready dictionary (lists and floats only)."""
        return {
            "id": int(self.id),
            "type": self.type,
            "center": [float(v) for v in self.center],
            "rotation": [[float(v) for v in row] for row in self.rotation],
            "dimensions": {k: float(v) for k, v in self.dimensions.items()},
        }


# --------------------------------------------------------------------------- noise
@dataclass(frozen=True)
class NoiseModel:
    """Depth-sensor degradations applied to an organized cloud.

    Parameters
    ----------
    sigma_at_0_5m : float
        Standard deviation [m] of the Gaussian range noise at 0.5 m depth, in
        [0, inf).  A point at depth z [m] is displaced along its viewing ray by
        ``N(0, sigma)`` with ``sigma = sigma_offset + sigma_at_0_5m * (z / 0.5) ** 2``.
    dropout : float
        Fraction of the valid pixels removed at random, in [0, 1)
        (``round(dropout * n_valid)`` pixels exactly).
    holes : int
        Number of random elliptical holes (pixels set to NaN / label -1), in
        [0, inf).  Centres uniform over the image, semi-axes uniform in
        [0.02, 0.08] x min(width, height) pixels, random orientation.
    sigma_offset : float
        Depth-independent part of sigma [m], in [0, inf) (default 0: sigma grows with the
        square of the depth only).
    corr_ratio : float
        Standard deviation of a spatially correlated range error, as a multiple of
        ``sigma(z)``, in [0, inf) (default 0: none).  Real depth cameras add errors that vary
        slowly across the image (depth distortion, the correlation window of the disparity
        search) to the pixel-independent noise: a point at depth z is displaced along its
        ray by ``corr_ratio * sigma(z) * F(u, v)``, F a stationary Gaussian random field
        over the image with unit variance (:func:`correlated_field`).
    corr_length_px : float
        Correlation length [px] of F, in (0, inf): its correlation at a lag of r pixels is
        ``exp(-r**2 / (2 * corr_length_px**2))`` (default 8, used only with
        ``corr_ratio > 0``).
    inv_depth_step : float
        Quantisation step of the inverse depth 1/z [1/m], in [0, inf) (default 0: none).
        Structured-light and stereo cameras measure a disparity ``d = f b / z`` [px] in
        sub-pixel steps q, so 1/z comes in steps ``q / (f b)`` and the depth in terraces
        ``q z**2 / (f b)`` apart (:func:`quantize_disparity`; Kinect v1:
        :data:`KINECT_INV_DEPTH_STEP`).
    mixed_edges : float
        Share of the pixels along a depth edge that see both surfaces, in [0, 1] (default
        0: none). A pixel whose footprint straddles a silhouette returns a depth between
        the two surfaces (a "flying" or mixed pixel: time-of-flight cameras, and depth
        images resampled to another camera's pixels). Every pixel with a 4-neighbour of
        another label more than :data:`MIXED_EDGE_MIN_JUMP` away in depth is a candidate;
        that share of them is moved along its ray to a depth uniform between its own and
        the neighbour's, and labelled -1 (the point lies on no object). Measured on real
        frames by :func:`mixed_pixel_share`.
    """

    sigma_at_0_5m: float = 0.0
    dropout: float = 0.0
    holes: int = 0
    sigma_offset: float = 0.0
    corr_ratio: float = 0.0
    corr_length_px: float = 8.0
    inv_depth_step: float = 0.0
    mixed_edges: float = 0.0

    def __post_init__(self) -> None:
        s = float(self.sigma_at_0_5m)
        if not np.isfinite(s) or s < 0.0:
            raise ValueError(f"sigma_at_0_5m must be in [0, inf) [m], got {self.sigma_at_0_5m!r}")
        d = float(self.dropout)
        if not (0.0 <= d < 1.0):
            raise ValueError(f"dropout must be a fraction in [0, 1), got {self.dropout!r}")
        h = self.holes
        if isinstance(h, bool) or int(h) != h or int(h) < 0:
            raise ValueError(f"holes must be an integer in [0, inf), got {self.holes!r}")
        object.__setattr__(self, "sigma_at_0_5m", s)
        object.__setattr__(self, "dropout", d)
        object.__setattr__(self, "holes", int(h))
        o = float(self.sigma_offset)
        if not np.isfinite(o) or o < 0.0:
            raise ValueError(f"sigma_offset must be in [0, inf) [m], got {self.sigma_offset!r}")
        object.__setattr__(self, "sigma_offset", o)
        for name, low_open in (("corr_ratio", False), ("corr_length_px", True),
                               ("inv_depth_step", False)):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v < 0.0 or (low_open and v == 0.0):
                bounds = "(0, inf)" if low_open else "[0, inf)"
                raise ValueError(f"{name} must be in {bounds}, got {getattr(self, name)!r}")
            object.__setattr__(self, name, v)
        m = float(self.mixed_edges)
        if not (0.0 <= m <= 1.0):
            raise ValueError(f"mixed_edges must be a share in [0, 1], got {self.mixed_edges!r}")
        object.__setattr__(self, "mixed_edges", m)

    def sigma(self, depth) -> np.ndarray:
        """Noise sigma [m] at depth ``depth`` [m] (array or scalar)."""
        return self.sigma_offset + self.sigma_at_0_5m * (np.asarray(depth) / 0.5) ** 2


#: Step of the inverse depth [1/m] of a Kinect v1 (structured light, 1/8-pixel disparity):
#: Khoshelham and Elberink (2012), "Accuracy and Resolution of Kinect Depth Data for Indoor
#: Mapping Applications", Sensors 12(2), 1437-1454: 1/Z is linear in the normalised
#: disparity d' (1/8-pixel units), with m/fb = -2.85e-3 per unit from their calibration, so
#: one unit of d' is a depth step of 2.85e-3 Z^2 (2.85 mm at 1 m, 7 cm at 5 m). Measured on
#: the 45 osd_learn frames (Kinect): the median gap between the distinct 1/z values on the
#: table is 2.82e-3 to 2.88e-3 1/m (``python -m geomodel_ros.tools.noise_calibration``).
KINECT_INV_DEPTH_STEP = 2.85e-3
#: A typical close-range structured-light / stereo sensor.
SENSOR_NOISE = NoiseModel(sigma_at_0_5m=0.001, dropout=0.02, holes=0)
#: A Kinect-class RGB-D camera: sigma = 1.2 mm + 0.8 mm * z^2 (1.4 mm at 0.5 m, 2.0 mm at
#: 1 m, 3.0 mm at 1.5 m), 5 % dropout and three holes.
KINECT_CLASS_NOISE = NoiseModel(sigma_at_0_5m=0.0002, dropout=0.05, holes=3, sigma_offset=0.0012)
#: A Kinect v1 as measured on real frames: KINECT_CLASS_NOISE as the pixel-independent part,
#: plus a correlated range error (1.75 sigma(z), correlation length 16 px) and the Kinect's
#: disparity quantisation (KINECT_INV_DEPTH_STEP). Calibrated by measurement of the sensor
#: (``estimate_noise(...).scale``: noise across the dominant plane over the local noise), not
#: by the method's results: on the 45 osd_learn frames the scale is 1.62-2.45 (median 1.86)
#: and the table's residual correlation along rows/columns falls from 0.79 at 1 px to 0.53
#: at 4, 0.39 at 16 and 0.23 at 48 px (medians); on the suite's 9 tabletop renders at 0.5,
#: 1.0, 1.5 m (2 seeds) this preset gives scale 1.64-2.29 (median 2.00; Kinect-class alone
#: 1.00-1.11), local sigma 0.96-1.13 sigma(z) (Kinect-like), and desk correlation 0.71 at
#: 1 px, 0.68 at 4, 0.38 at 16 px: of correlation lengths 8, 12, 16, 24, 32 px and shares
#: 1-2 it is the closest to the real correlation with every scale in the real range
#: (``python -m geomodel_ros.tools.noise_calibration``; BENCHMARKS.md, "Synthetic scenes
#: with realistic sensor noise"). The real Kinect's local noise is 0.62-0.83 of the
#: Kinect-class sigma(z): this preset is about 1.4x noisier overall than osd_learn.
KINECT_REAL_NOISE = NoiseModel(sigma_at_0_5m=0.0002, dropout=0.05, holes=3, sigma_offset=0.0012,
                               corr_ratio=1.75, corr_length_px=16.0,
                               inv_depth_step=KINECT_INV_DEPTH_STEP)

#: Kinect-class noise with mixed pixels at the depth edges: each pixel beside a silhouette
#: sees both surfaces with probability 0.5 (about one of the two pixels at every edge), as a
#: time-of-flight camera's "flying pixels" without its driver's filter. Not calibrated on
#: real frames: the Kinect v1 frames here have none to speak of (``mixed_pixel_share``: 4 of
#: 65,673 edge windows on the 45 osd_learn frames, 16 of 2,179 in the milk scene, 0 of 921
#: in the mug scene; the office scene's 581 of 8,386 are its far disparity terraces), a
#: structured-light camera's property; rendered clutter with this preset 8-14 %.
MIXED_EDGE_NOISE = NoiseModel(sigma_at_0_5m=0.0002, dropout=0.05, holes=3, sigma_offset=0.0012,
                              mixed_edges=0.5)

#: Extent of the Gaussian kernel, in kernel standard deviations (scipy's default).
_FIELD_TRUNCATE = 4.0


def correlated_field(shape: tuple[int, int], length_px: float, rng=None) -> np.ndarray:
    """Draw a stationary Gaussian random field over an image, unit variance, zero mean.

    White noise on a grid padded by the kernel's radius on every side is smoothed with a
    Gaussian kernel of standard deviation ``length_px / sqrt(2)`` along rows and columns
    and cropped, so every pixel is a full-kernel sum (no border effect); divided by the
    root of the sum of the squared 2-D kernel weights it has variance 1. A Gaussian
    kernel of standard deviation s convolved with itself is a Gaussian of standard
    deviation s sqrt(2), so the correlation at a lag of r pixels is
    ``exp(-r**2 / (2 * length_px**2))``.

    Parameters
    ----------
    shape : (int, int)
        Image height and width [px].
    length_px : float
        Correlation length [px], > 0.
    rng : None, int, or numpy.random.Generator
        One standard normal per pixel of the padded grid (row-major) is drawn.

    Returns
    -------
    (H, W) float64 array
    """
    rng = np.random.default_rng(rng)
    height, width = (int(v) for v in shape)
    sd = float(length_px) / np.sqrt(2.0)
    radius = int(_FIELD_TRUNCATE * sd + 0.5)          # scipy's kernel radius
    white = rng.standard_normal((height + 2 * radius, width + 2 * radius))
    for axis in (0, 1):
        white = gaussian_filter1d(white, sd, axis=axis, mode="constant",
                                  truncate=_FIELD_TRUNCATE)
    delta = np.zeros(2 * radius + 1)
    delta[radius] = 1.0
    kernel = gaussian_filter1d(delta, sd, mode="constant", truncate=_FIELD_TRUNCATE)
    field = white[radius:radius + height, radius:radius + width]
    return field / float(kernel @ kernel)              # sqrt of (sum k^2)^2


def quantize_disparity(organized: np.ndarray, inv_depth_step: float) -> np.ndarray:
    """Move every point along its ray to the nearest depth of a disparity step.

    A camera that measures the disparity ``d = f b / z`` [px] in sub-pixel steps q reports
    depths ``z_n = 1 / (n * inv_depth_step)``, ``inv_depth_step = q / (f b)`` [1/m], n a
    positive integer: the step of 1/z nearest to the point's is taken (rounding in
    disparity), and the point is scaled by ``z_n / z`` so it stays on its ray.

    Parameters
    ----------
    organized : (..., 3) float64 array [m]
        Points in the optical frame (z = depth); NaN rows and rows with z <= 0 are kept.
    inv_depth_step : float
        Step of 1/z [1/m], > 0.

    Returns
    -------
    (..., 3) float64 array [m]
        A new array.
    """
    pts = np.array(organized, dtype=np.float64, copy=True)
    z = pts[..., 2]
    ok = np.isfinite(pts).all(axis=-1) & (z > 0.0)
    n = np.maximum(np.rint(1.0 / (z[ok] * inv_depth_step)), 1.0)
    pts[ok] *= (1.0 / (n * inv_depth_step) / z[ok])[:, None]
    return pts


def _correlated_error(pts: np.ndarray, noise: NoiseModel, rng: np.random.Generator) -> None:
    """Displace the finite points of ``pts`` (H, W, 3) [m] in place by the correlated error."""
    field = correlated_field(pts.shape[:2], noise.corr_length_px, rng)
    ok = np.isfinite(pts).all(axis=2)
    p = pts[ok]
    shift = noise.corr_ratio * noise.sigma(p[:, 2]) * field[ok]
    pts[ok] = p + (shift / np.linalg.norm(p, axis=1))[:, None] * p


def apply_noise(
    organized: np.ndarray,
    label_image: np.ndarray,
    noise: NoiseModel,
    rng=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Apply a :class:`NoiseModel` to an organized cloud (inputs untouched).

    Order: mixed pixels at depth edges (``mixed_edges > 0``: the optics mix the two
    surfaces before the sensor measures), range noise, then dropout, then holes, then the
    correlated range error (``corr_ratio > 0``), then disparity quantisation
    (``inv_depth_step > 0``: the camera quantises the noisy disparity).  The random draws
    are, in order: the mixed pixels' selection and depths, one standard normal per valid
    pixel (row-major), the dropout selection, per hole its centre, semi-axes and angle,
    then the correlated field (:func:`correlated_field`).  A model without the correlated
    error or the mixed pixels draws exactly what it drew before they existed.

    Parameters
    ----------
    organized : (H, W, 3) float64 array [m]
        Points in the optical frame, NaN = no return.
    label_image : (H, W) int32 array
        Labels, -1 = no return.
    noise : NoiseModel
    rng : None, int, or numpy.random.Generator
        Normalised with :func:`numpy.random.default_rng`.

    Returns
    -------
    organized : (H, W, 3) float64 array [m]
    label_image : (H, W) int32 array
    """
    if not isinstance(noise, NoiseModel):
        raise ValueError(f"noise must be a NoiseModel, got {type(noise).__name__}")
    rng = np.random.default_rng(rng)
    pts = np.array(organized, dtype=np.float64, copy=True)
    lab = np.array(label_image, dtype=np.int32, copy=True)
    if pts.ndim != 3 or pts.shape[2] != 3 or lab.shape != pts.shape[:2]:
        raise ValueError("organized must be (H, W, 3) and label_image (H, W)")
    height, width = lab.shape
    flat = pts.reshape(-1, 3)
    flat_lab = lab.reshape(-1)
    valid = np.flatnonzero(np.isfinite(flat).all(axis=1))

    if noise.mixed_edges > 0.0:
        _mix_edges(pts, lab, noise.mixed_edges, rng)

    if (noise.sigma_at_0_5m > 0.0 or noise.sigma_offset > 0.0) and valid.size:
        p = flat[valid]
        sigma = noise.sigma(p[:, 2])
        rng_noise = rng.standard_normal(valid.size) * sigma
        flat[valid] = p + (rng_noise / np.linalg.norm(p, axis=1))[:, None] * p

    if noise.dropout > 0.0 and valid.size:
        k = int(round(noise.dropout * valid.size))
        drop = rng.choice(valid, size=k, replace=False)
        flat[drop] = np.nan
        flat_lab[drop] = -1

    if noise.holes:
        vv, uu = np.mgrid[0:height, 0:width]
        scale = min(height, width)
        hole = np.zeros((height, width), dtype=bool)
        for _ in range(noise.holes):
            cu, cv = rng.uniform(0.0, width), rng.uniform(0.0, height)
            a, b = np.maximum(rng.uniform(0.02, 0.08, size=2) * scale, 1.0)
            ang = rng.uniform(0.0, np.pi)
            du, dv = uu - cu, vv - cv
            x = du * np.cos(ang) + dv * np.sin(ang)
            y = -du * np.sin(ang) + dv * np.cos(ang)
            hole |= (x / a) ** 2 + (y / b) ** 2 <= 1.0
        pts[hole] = np.nan
        lab[hole] = -1

    if noise.corr_ratio > 0.0 and (noise.sigma_at_0_5m > 0.0 or noise.sigma_offset > 0.0):
        _correlated_error(pts, noise, rng)
    if noise.inv_depth_step > 0.0:
        pts = quantize_disparity(pts, noise.inv_depth_step)
    return pts, lab


#: Neighbouring pixels of two labels further apart in depth than this [m] form a depth
#: edge whose pixels may see both surfaces (:attr:`NoiseModel.mixed_edges`); an object
#: standing on the desk meets it without a jump.
MIXED_EDGE_MIN_JUMP = 0.01


def _edge_partners(depth: np.ndarray, lab: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (flat indices) beside a depth edge and, for each, its neighbour across it."""
    h, w = lab.shape
    idx = np.arange(h * w).reshape(h, w)
    pix, other = [], []
    for a, b in ((idx[:, :-1], idx[:, 1:]), (idx[:-1, :], idx[1:, :])):
        a, b = a.ravel(), b.ravel()
        za, zb = depth.ravel()[a], depth.ravel()[b]
        edge = np.isfinite(za) & np.isfinite(zb) & (lab.ravel()[a] != lab.ravel()[b]) \
            & (np.abs(za - zb) > MIXED_EDGE_MIN_JUMP)
        pix += [a[edge], b[edge]]
        other += [b[edge], a[edge]]
    pix, other = np.concatenate(pix), np.concatenate(other)
    first = np.unique(pix, return_index=True)[1]  # one partner per pixel
    return pix[first], other[first]


def _mix_edges(pts: np.ndarray, lab: np.ndarray, share: float, rng: np.random.Generator
               ) -> None:
    """Give ``share`` of the depth-edge pixels a depth between both sides, in place."""
    flat, flat_lab = pts.reshape(-1, 3), lab.reshape(-1)
    pix, other = _edge_partners(pts[..., 2], lab)
    pick = rng.random(len(pix)) < share
    pix, other = pix[pick], other[pick]
    z, z_other = flat[pix, 2], flat[other, 2]
    t = rng.random(len(pix))
    flat[pix] *= ((z + t * (z_other - z)) / z)[:, None]
    flat_lab[pix] = -1


def mixed_pixel_share(organized: np.ndarray, jump: float = 0.1) -> tuple[int, int]:
    """Count mixed pixels at the depth edges of an organized cloud (H, W, 3) [m].

    The windows of :func:`geomodel_ros.core.mixed_pixels.mixed_pixels` whose two sides
    differ in range by more than ``jump`` [m]: returns (mixed, clean), the edge windows
    holding a run of pixels between the two surfaces and those that do not; mixed / (mixed +
    clean) is comparable between real and rendered frames.
    """
    from geomodel_ros.core.mixed_pixels import mixed_pixels

    ranges = np.linalg.norm(np.asarray(organized, dtype=np.float64), axis=2)
    _, runs, edges = mixed_pixels(ranges, np.full(ranges.shape, float(jump)))
    return runs, edges - runs


# --------------------------------------------------------------------------- scene
@dataclass
class Scene:
    """A rendered synthetic scene.

    Attributes
    ----------
    name : str
    organized : (H, W, 3) float64 array [m]
        Optical-frame points, NaN = no return.
    label_image : (H, W) int32 array
        Object id per pixel, -1 = no return.
    objects : list of GroundTruthObject
        All objects including the desk (id 0, type ``"plane"``).
    intrinsics : dict
        ``fx, fy, cx, cy`` [px], ``width, height`` [px].
    """

    name: str
    organized: np.ndarray
    label_image: np.ndarray
    objects: list
    intrinsics: dict

    @property
    def valid_mask(self) -> np.ndarray:
        """(H, W) bool array, True where the pixel has a finite point."""
        return np.isfinite(self.organized).all(axis=2)

    @property
    def points(self) -> np.ndarray:
        """(N, 3) float64 finite points [m] in row-major pixel order."""
        return self.organized[self.valid_mask]

    @property
    def labels(self) -> np.ndarray:
        """(N,) int32 labels aligned with :attr:`points`."""
        return self.label_image[self.valid_mask].astype(np.int32, copy=False)


# --------------------------------------------------------------------------- geometry
#: desk centre [m] (paper: (-9.030, -43.117, 518.281) mm)
DESK_CENTER = np.array([-9.030, -43.117, 518.281]) * 1e-3
#: unit desk normal, facing the camera
DESK_NORMAL = np.array([0.0, -0.766, -0.643]) / np.linalg.norm([0.0, -0.766, -0.643])
#: desk side length [m]
DESK_SIZE = 0.400
DESK_CENTER.setflags(write=False)
DESK_NORMAL.setflags(write=False)

#: Camera of the paper scenes: the whole desk in view, ~0.5 mm point spacing
#: on it and 360k-375k valid points per scene.
PAPER_CAMERA = PinholeCamera(fx=940.0, fy=940.0, cx=551.5, cy=311.5, width=1104, height=624)
#: Low-resolution camera for fast unit-test scenes (same view, 160 x 120).
TINY_CAMERA = PinholeCamera(fx=140.0, fy=140.0, cx=82.0, cy=62.0, width=160, height=120)


def desk_frame() -> np.ndarray:
    """(3, 3) rotation of the desk: columns x = camera x, y = z cross x, z = normal."""
    x = np.array([1.0, 0.0, 0.0])
    x = x - (x @ DESK_NORMAL) * DESK_NORMAL
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(DESK_NORMAL, x), DESK_NORMAL], axis=1)


#: Yaw of the desk about its normal [rad]. The paper gives the desk's centre and normal only;
#: a small yaw keeps its edges oblique to the pixel rows. An edge parallel to the rows is
#: sampled in one row per pixel, so from points alone it is known only to within one row
#: step (1.6 mm at the desk's far edge here); oblique edges are sampled at every phase.
DESK_YAW = np.radians(10.0)


def _desk() -> Rectangle:
    return Rectangle(DESK_SIZE, DESK_SIZE, center=DESK_CENTER,
                     rotation=desk_frame() @ _rot_z(DESK_YAW))


def _rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _standing(u_mm: float, v_mm: float, yaw_deg: float) -> dict:
    """Pose upright on the desk at desk coordinates (u, v) [mm], yaw about the normal."""
    frame = desk_frame()
    center = DESK_CENTER + 1e-3 * (u_mm * frame[:, 0] + v_mm * frame[:, 1])
    return {"center": center, "rotation": frame @ _rot_z(np.radians(yaw_deg))}


def _lying(u_mm: float, v_mm: float, yaw_deg: float) -> dict:
    """Return a pose lying on the desk (for a cylinder on its side).

    Local z is parallel to the desk at angle yaw in the desk plane, local x = desk normal.
    """
    frame = desk_frame()
    center = DESK_CENTER + 1e-3 * (u_mm * frame[:, 0] + v_mm * frame[:, 1])
    yaw = np.radians(yaw_deg)
    z = np.cos(yaw) * frame[:, 0] + np.sin(yaw) * frame[:, 1]
    x = frame[:, 2]
    return {"center": center, "rotation": np.stack([x, np.cross(z, x), z], axis=1)}


def _rest_on_desk(shape: Shape) -> Shape:
    """Translate a shape along the desk normal so its lowest point touches the desk."""
    lowest = -shape.support(-DESK_NORMAL) - DESK_CENTER @ DESK_NORMAL
    return replace(shape, center=shape.center - lowest * DESK_NORMAL)


def _mm(*values: float) -> list[float]:
    return [1e-3 * v for v in values]


def _scene1() -> list[Shape]:
    a, b, c = _mm(80, 60, 50)
    objs = [Box(a, b, c, **_standing(-100, -105, 10))]
    a, b, c = _mm(100, 50, 30)
    objs.append(Box(a, b, c, **_standing(95, -100, -35)))
    a, b, c = _mm(60, 60, 80)
    objs.append(Box(a, b, c, **_standing(-90, 65, 45)))
    a, b, c = _mm(120, 40, 60)
    objs.append(Box(a, b, c, **_standing(95, 60, 70)))
    return objs


def _scene2() -> list[Shape]:
    return [
        Sphere(*_mm(30), **_standing(-105, -110, 0)),
        Sphere(*_mm(25), **_standing(15, -135, 0)),
        Cylinder(*_mm(40, 60), **_standing(-95, 85, 0)),
        Cylinder(*_mm(20, 80), **_lying(100, 75, 60)),
        Cone(*_mm(30, 50), **_standing(110, -100, 0)),
    ]


def _scene3() -> list[Shape]:
    # Figure 9 of the paper projected onto the desk, spread so that no two
    # objects touch; lying cylinder axis keeps Figure 9's direction.
    return [
        Box(*_mm(50, 50, 50), **_standing(60, -130, 30)),
        Box(*_mm(120, 120, 40), **_standing(-95, 45, 20)),
        Cylinder(*_mm(50, 60), **_standing(70, 60, 0)),
        Cylinder(*_mm(20, 80), **_lying(135, -40, -130)),
        Cone(*_mm(30, 50), **_standing(-110, -95, 0)),
        Sphere(*_mm(30), **_standing(0, -40, 0)),
        Sphere(*_mm(25), **_standing(-20, -150, 0)),
    ]


def _torus_scene() -> list[Shape]:
    return [
        Torus(*_mm(40, 15), **_standing(-60, -40, 0)),
        Box(*_mm(60, 40, 50), **_standing(90, 60, 25)),
    ]


def _tiny_box() -> list[Shape]:
    return [Box(*_mm(80, 60, 50), **_standing(0, 0, 25))]


def _tiny_shapes() -> list[Shape]:
    return [
        Box(*_mm(70, 50, 50), **_standing(-100, -100, 20)),
        Sphere(*_mm(35), **_standing(100, -100, 0)),
        Cylinder(*_mm(40, 70), **_standing(-100, 100, 0)),
        Cone(*_mm(45, 70), **_standing(0, 0, 0)),
        Torus(*_mm(45, 15), **_standing(100, 100, 0)),
    ]


# --------------------------------------------------------------------------- segmentation scenes
#: Moderate-resolution camera of the segmentation test scenes: the paper view at
#: 320 x 181 (point spacing about 1.7 mm on the desk), each scene renders in ~0.1 s.
SEGMENTATION_CAMERA = PAPER_CAMERA.scaled(320 / 1104)


@dataclass(frozen=True)
class _On:
    """An object standing on the top of object ``base`` (its id, 1..K, placed earlier).

    Only its position along the desk normal changes: its lowest point is put exactly on
    the highest point of ``base`` (for upright shapes, bottom face on the top face).  Pose
    it at the base's desk coordinates to centre it.
    """

    shape: Shape
    base: int


def _rest_on(shape: Shape, base: Shape) -> Shape:
    """Translate ``shape`` along the desk normal so its lowest point is ``base``'s highest."""
    lowest = -shape.support(-DESK_NORMAL)
    return replace(shape, center=shape.center + (base.support(DESK_NORMAL) - lowest) * DESK_NORMAL)


def _next_to(u_mm: float, v_mm: float, yaw_deg: float, dx_mm: float, dy_mm: float
             ) -> tuple[float, float]:
    """Return the desk coordinates [mm] of a point (dx, dy) [mm] of an upright object.

    The object stands at (u, v) with yaw ``yaw_deg``; used to place objects face to face.
    """
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    return u_mm + c * dx_mm - s * dy_mm, v_mm + s * dx_mm + c * dy_mm


def _touching() -> list[Shape]:
    # 1: tall box; 2: lower box with its -x face on 1's +x face, slid 20 mm back along
    # it (the front faces are not coplanar); 3: cylinder whose side touches 1's -x face
    # along a vertical line.
    yaw = 25.0
    ua, va = -50.0, -30.0
    objs = [Box(*_mm(60, 60, 90), **_standing(ua, va, yaw))]
    ub, vb = _next_to(ua, va, yaw, 30 + 35, 20)
    objs.append(Box(*_mm(70, 60, 50), **_standing(ub, vb, yaw)))
    uc, vc = _next_to(ua, va, yaw, -30 - 30, 0)
    objs.append(Cylinder(*_mm(30, 70), **_standing(uc, vc, 0)))
    return objs


def _stacked() -> list[Shape]:
    # 1: big box; 2: smaller box centred on it, turned by 15 degrees (the big box's top
    # shows all around it); 3: box; 4: cylinder standing on its centre.
    return [
        Box(*_mm(110, 90, 50), **_standing(-80, -30, 20)),
        _On(Box(*_mm(60, 50, 40), **_standing(-80, -30, 35)), base=1),
        Box(*_mm(80, 80, 40), **_standing(90, 20, -15)),
        _On(Cylinder(*_mm(25, 60), **_standing(90, 20, 0)), base=3),
    ]


def _occluded() -> list[Shape]:
    # A tall box in front of a cylinder that stands 20 mm to its right and 130 mm behind
    # it: about half of the cylinder's visible surface is hidden, the rest is one strip
    # right of the box.  Bounding spheres 13 mm apart.
    return [
        Box(*_mm(60, 40, 120), **_standing(-25, -60, 0)),
        Cylinder(*_mm(30, 80), **_standing(-5, 70, 0)),
    ]


def _apart() -> list[Shape]:
    return [
        Box(*_mm(70, 60, 50), **_standing(-100, -60, 30)),
        Cylinder(*_mm(30, 70), **_standing(90, -60, 0)),
        Sphere(*_mm(35), **_standing(0, 90, 0)),
    ]


_SCENES = {
    "scene1": (PAPER_CAMERA, _scene1),
    "scene2": (PAPER_CAMERA, _scene2),
    "scene3": (PAPER_CAMERA, _scene3),
    "torus": (PAPER_CAMERA, _torus_scene),
    "tiny_box": (TINY_CAMERA, _tiny_box),
    "tiny_shapes": (TINY_CAMERA, _tiny_shapes),
    "touching": (SEGMENTATION_CAMERA, _touching),
    "stacked": (SEGMENTATION_CAMERA, _stacked),
    "occluded": (SEGMENTATION_CAMERA, _occluded),
    "apart": (SEGMENTATION_CAMERA, _apart),
}

#: Names accepted by :func:`render_scene`.
SCENE_NAMES: tuple[str, ...] = tuple(_SCENES)
#: The three scenes of the paper.
PAPER_SCENE_NAMES: tuple[str, ...] = ("scene1", "scene2", "scene3")
#: Scenes with touching, stacked and occluded objects for the segmentation tests.
SEGMENTATION_SCENE_NAMES: tuple[str, ...] = ("touching", "stacked", "occluded", "apart")


def _check_name(name: str) -> None:
    if name not in _SCENES:
        raise ValueError(f"unknown scene {name!r}; allowed names: {', '.join(SCENE_NAMES)}")


def scene_geometry(name: str) -> tuple[PinholeCamera, list[Shape]]:
    """Camera and analytic shapes of a scene (desk first, id = list index).

    Parameters
    ----------
    name : str
        One of :data:`SCENE_NAMES`.

    Returns
    -------
    camera : PinholeCamera
    shapes : list of Shape
        ``shapes[0]`` is the desk, ``shapes[k]`` has label ``k``.
    """
    _check_name(name)
    camera, build = _SCENES[name]
    placed: list[Shape] = []
    for item in build():
        if isinstance(item, _On):
            placed.append(_rest_on(item.shape, placed[item.base - 1]))
        else:
            placed.append(_rest_on_desk(item))
    return camera, [_desk()] + placed


@functools.lru_cache(maxsize=8)
def _render_clean(name: str) -> tuple[np.ndarray, np.ndarray, tuple]:
    camera, shapes = scene_geometry(name)
    organized, labels = camera.render(shapes)
    organized.setflags(write=False)
    labels.setflags(write=False)
    return organized, labels, tuple(s.ground_truth(i) for i, s in enumerate(shapes))


def render_scene(name: str, *, noise: NoiseModel | None = None, rng=None) -> Scene:
    """Render one of the synthetic scenes.

    Parameters
    ----------
    name : str
        One of :data:`SCENE_NAMES`: ``scene1`` (4 cuboids), ``scene2`` (2
        spheres, standing and lying cylinder, cone), ``scene3`` (the paper's
        Figure 9 mixed scene), ``torus`` (torus + box), ``tiny_box`` and
        ``tiny_shapes`` (160 x 120 test scenes); ``touching`` (2 boxes face to
        face, cylinder against a box), ``stacked`` (box on box, cylinder on box),
        ``occluded`` (tall box, half-hidden cylinder) and ``apart`` (box, cylinder,
        sphere) at 320 x 181 for segmentation tests.
    noise : NoiseModel, optional
        Sensor degradations; ``None`` gives the exact ray-cast cloud.
    rng : None, int, or numpy.random.Generator
        Randomness for ``noise`` (normalised with :func:`numpy.random.default_rng`).

    Returns
    -------
    Scene
        The clean render is cached; the returned arrays are fresh copies.
    """
    _check_name(name)
    if noise is not None and not isinstance(noise, NoiseModel):
        raise ValueError(f"noise must be a NoiseModel or None, got {type(noise).__name__}")
    organized, labels, objects = _render_clean(name)
    if noise is None:
        organized, labels = organized.copy(), labels.copy()
    else:
        organized, labels = apply_noise(organized, labels, noise, rng)
    camera = _SCENES[name][0]
    return Scene(
        name=name,
        organized=organized,
        label_image=labels,
        objects=list(objects),
        intrinsics=camera.intrinsics,
    )


# --------------------------------------------------------------------------- room scene
#: Laser-like scanner of the room scene: 400 x 200 rays over about 90 x 53 degrees (5 mrad
#: steps: 5 mm spacing at 1 m, 5 cm at 10 m).
ROOM_CAMERA = PinholeCamera(fx=200.0, fy=200.0, cx=199.5, cy=99.5, width=400, height=200)
#: Range noise of the room scan: sigma 5 mm at every range (a laser's noise barely grows
#: with range), 10 % of the returns missing.
ROOM_NOISE = NoiseModel(sigma_offset=0.005, dropout=0.1)
#: Sensor height above the floor [m] and the pitch [rad] of its optical axis, which looks
#: up by this much: the lowest image row looks 14.6 deg down and meets the floor 5 m
#: away, so the table (at 2.4-3.6 m) shows only its top and its lower part lies below
#: the field of view.
ROOM_SENSOR_HEIGHT = 1.3
ROOM_PITCH = np.radians(12.0)


def _room_shapes() -> list[Shape]:
    """Floor, back, left and right walls, a table and a cabinet, in the sensor's frame.

    Built in a level frame (x right, y down, z forward, sensor at the origin, floor at
    y = ROOM_SENSOR_HEIGHT), then turned so that the optical axis looks up by ROOM_PITCH.
    Room 6 m wide, back wall 9 m away, walls 2.5 m high; table 1.6 x 0.8 x 0.75 m at 3 m,
    cabinet 0.8 x 0.5 x 1.8 m at 6 m (both solid boxes standing on the floor).
    """
    h = ROOM_SENSOR_HEIGHT
    c, s = np.cos(ROOM_PITCH), np.sin(ROOM_PITCH)
    pitch = np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])
    up, fwd, right = np.array([0.0, -1.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.eye(3)[0]

    def frame(x, y, z):
        return np.stack([x, y, z], axis=1)

    def yawed(deg):
        a = np.radians(deg)
        x = np.cos(a) * right + np.sin(a) * fwd
        return frame(x, np.cross(up, x), up)

    level = [
        Rectangle(6.0, 8.5, center=[0.0, h, 4.75], rotation=frame(right, fwd, up)),
        Rectangle(6.0, 2.5, center=[0.0, h - 1.25, 9.0], rotation=frame(right, up, -fwd)),
        Rectangle(8.5, 2.5, center=[-3.0, h - 1.25, 4.75], rotation=frame(fwd, up, right)),
        Rectangle(8.5, 2.5, center=[3.0, h - 1.25, 4.75], rotation=frame(fwd, -up, -right)),
        Box(1.6, 0.8, 0.75, center=[-0.8, h - 0.375, 3.0], rotation=yawed(15.0)),
        Box(0.8, 0.5, 1.8, center=[1.8, h - 0.9, 6.0], rotation=yawed(-10.0)),
    ]
    return [replace(sh, center=pitch @ sh.center, rotation=pitch @ sh.rotation) for sh in level]


def room_scene(*, noise: NoiseModel | None = ROOM_NOISE, rng=None) -> Scene:
    """Render the room scene: walls and floor (planes), a table and a cabinet (cuboids).

    Labels: 0 floor, 1 back wall, 2 left wall, 3 right wall, 4 table, 5 cabinet. Not one
    of :data:`SCENE_NAMES` (no desk): room-scale data at 1-10 m for the scale-adaptive
    modeling.

    Parameters
    ----------
    noise : NoiseModel or None
        Range noise (default :data:`ROOM_NOISE`); None gives the exact ray-cast cloud.
    rng : None, int, or numpy.random.Generator
        Randomness for ``noise``.
    """
    shapes = _room_shapes()
    organized, labels = ROOM_CAMERA.render(shapes)
    if noise is not None:
        organized, labels = apply_noise(organized, labels, noise, rng)
    return Scene(name="room", organized=organized, label_image=labels,
                 objects=[sh.ground_truth(i) for i, sh in enumerate(shapes)],
                 intrinsics=ROOM_CAMERA.intrinsics)
