"""The one definition of every modeling parameter.

Each :class:`ParamSpec` gives a parameter's name, default, unit, allowed range and
description. The ROS node declares its parameters from :data:`PARAMETERS`, the YAML in
``config/`` lists the same defaults, and the CLI reads the same names. The core itself
only ever sees a frozen :class:`ModelingParams`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

__all__ = [
    "PARAMETERS",
    "ModelingParams",
    "ParamSpec",
    "ParameterError",
    "load_params_file",
]


class ParameterError(ValueError):
    """A parameter value is out of range, of the wrong type, or inconsistent."""


@dataclass(frozen=True)
class ParamSpec:
    """Definition of one parameter.

    Attributes
    ----------
    name : str
        Name used in YAML, ROS and :class:`ModelingParams`.
    default : int | float | bool
        Default value; its Python type is the parameter's type.
    unit : str
        Unit (``m``, ``rad``, ``1`` for dimensionless, ``count``).
    low, high : float | None
        Inclusive allowed range for numbers (``None``: unbounded).
    description : str
        One-sentence meaning, shown by ``ros2 param describe``.
    choices : tuple[str, ...] | None
        The allowed values of a string parameter (``None`` for numbers and bools).
    """

    name: str
    default: int | float | bool | str
    unit: str
    low: float | None
    high: float | None
    description: str
    choices: tuple[str, ...] | None = None

    @property
    def type(self) -> type:
        return type(self.default)

    def check(self, value: Any) -> int | float | bool | str:
        """Return ``value`` converted to this parameter's type, or raise ParameterError."""
        if self.type is str:
            if not isinstance(value, str) or value not in (self.choices or ()):
                raise ParameterError(f"parameter '{self.name}' must be one of "
                                     f"{', '.join(self.choices or ())}, got {value!r}")
            return value
        if self.type is bool:
            if not isinstance(value, bool):
                raise ParameterError(f"parameter '{self.name}' must be a bool, got {value!r}")
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParameterError(
                f"parameter '{self.name}' must be a {self.type.__name__}, got {value!r}"
            )
        if self.type is int:
            if isinstance(value, float) and not value.is_integer():
                raise ParameterError(f"parameter '{self.name}' must be an integer, got {value!r}")
            value = int(value)
        else:
            try:
                value = float(value)
            except OverflowError:
                raise ParameterError(f"parameter '{self.name}' = {value!r} is too large for "
                                     f"a float; allowed range [{self.low}, {self.high}]") from None
            if not math.isfinite(value):
                raise ParameterError(f"parameter '{self.name}' must be finite, got {value!r}")
        if (self.low is not None and value < self.low) or (
            self.high is not None and value > self.high
        ):
            raise ParameterError(
                f"parameter '{self.name}' = {value!r} is outside the allowed range "
                f"[{self.low}, {self.high}] {self.unit}"
            )
        return value


PARAMETERS: tuple[ParamSpec, ...] = (
    # --- input ----------------------------------------------------------------------------
    ParamSpec("max_range", 20.0, "m", 0.1, 1e5,
              "Points farther than this from the sensor origin (the cloud frame's origin) are "
              "dropped like invalid points (label -1) before any voxel arithmetic; the default "
              "suits depth cameras and room scans up to 15 m and more, map-frame clouds need a "
              "larger value."),
    ParamSpec("max_points", 1000000, "count", 1000, 100000000,
              "Scene clouds with more valid points are first averaged on the smallest voxel "
              "grid (seg_voxel_size grown geometrically) that leaves at most this many; every "
              "input point gets its voxel's label, and sizes are exact to that voxel."),
    # --- working resolution and faces ---------------------------------------------------
    ParamSpec("voxel_size", 0.003, "m", 0.0002, 0.2,
              "Voxel edge of the working cloud used for normals, faces and curvature."),
    ParamSpec("max_working_points", 5000, "count", 100, 10000000,
              "Working clouds of large objects (desks, walls) are voxelized coarser so that "
              "they hold about this many points (sizes still come from all points)."),
    ParamSpec("normal_neighbors", 16, "count", 5, 100,
              "Neighbours (on the working cloud) used to estimate normals and surface variation."),
    ParamSpec("face_angle_threshold", 0.2, "rad", 0.01, 1.0,
              "Largest normal angle between neighbours that grow into one smooth face; also the "
              "least turn of two patches (their mean normals, or their normals near the "
              "border) for their border to count as a crease by its median fold."),
    ParamSpec("edge_variation_threshold", 0.04, "1", 0.001, 0.33,
              "Surface variation above which a working point is an edge, not a face seed."),
    ParamSpec("min_face_points", 12, "count", 3, 100000,
              "Fewest working points (voxels) a face must have; smaller pieces join a neighbour."),
    ParamSpec("min_object_points", 60, "count", 4, 10000000,
              "Fewest input points an object needs to be modeled; fewer -> 'unknown'."),
    # --- surface type (paper eqs. 1-6) ----------------------------------------------------
    ParamSpec("cf_threshold", 0.82, "1", 0.0, 1.0,
              "CF_th: a face is planar iff its normalised CF (eq. 5 / sum of weights) exceeds it."),
    ParamSpec("noise_amplitude", 0.0005, "m", 0.0, 0.1,
              "Average noise amplitude of the cloud; eq. 6 uses t = this value in mm."),
    ParamSpec("cf_radius_fraction", 0.5, "1", 0.05, 1.0,
              "Largest of the three CF search radii as a fraction of the face's minimum width."),
    # --- model graph ----------------------------------------------------------------------
    ParamSpec("angle_tolerance", 0.14, "rad", 0.005, 0.6,
              "Tolerance for 'perpendicular' and 'parallel' normal relations."),
    ParamSpec("sphere_curvature_ratio", 0.45, "1", 0.0, 1.0,
              "Median |k2|/|k1| at or above which an all-curved object is a sphere candidate."),
    ParamSpec("developable_curvature_ratio", 0.35, "1", 0.0, 1.0,
              "Median |k2|/|k1| at or below which an all-curved object is a cylinder/cone "
              "candidate."),
    ParamSpec("cone_curvature_variation", 0.25, "1", 0.0, 10.0,
              "Relative spread of k1 (IQR/median) above which cone is tried before cylinder."),
    # --- RANSAC and verification ----------------------------------------------------------
    ParamSpec("ransac_threshold", 0.002, "m", 1e-6, 0.5,
              "Point-to-surface distance under which a point is a RANSAC inlier."),
    ParamSpec("ransac_normal_threshold", 0.5, "rad", 0.01, 3.1416,
              "Largest angle between a point's normal and the model's normal for an inlier."),
    ParamSpec("ransac_max_iterations", 500, "count", 1, 100000,
              "Upper bound on RANSAC hypotheses per model."),
    ParamSpec("ransac_confidence", 0.995, "1", 0.5, 0.999999,
              "Probability of drawing an all-inlier sample used for early termination."),
    ParamSpec("min_inlier_ratio", 0.8, "1", 0.05, 1.0,
              "Share of the surface's points that must be inliers for a fit to verify."),
    ParamSpec("refine_max_points", 5000, "count", 100, 10000000,
              "Most full-resolution points used in the least-squares refinement."),
    ParamSpec("min_radius", 0.002, "m", 0.0, 100.0,
              "Smallest accepted cylinder, cone or sphere radius."),
    ParamSpec("max_radius", 2.0, "m", 0.0, 1000.0,
              "Largest accepted cylinder, cone or sphere radius."),
    ParamSpec("min_cone_half_angle", 0.05, "rad", 0.0, 1.5,
              "Cone fits with a smaller half-angle are cylinders (with noise_model auto a "
              "frustum that narrow is kept where no cylinder fits: its taper is judged "
              "against the measured noise)."),
    ParamSpec("min_arc", 0.785, "rad", 0.0, 6.2832,
              "Smallest arc a cylinder's or cone's points must span around its axis (a "
              "shallow arc of a noisy surface fits any large radius; such objects are "
              "unknown)."),
    # --- sizing and reconstruction --------------------------------------------------------
    ParamSpec("edge_correction", True, "", None, None,
              "Extend open extents by half the point spacing (the sampling gap at an edge)."),
    ParamSpec("reproject_along_rays", True, "", None, None,
              "Input is in the sensor frame (sensor at the origin): before sizing, move points "
              "along their viewing rays onto the fitted surface, removing depth noise."),
    ParamSpec("reconstruction_spacing", 0.002, "m", 0.0001, 1.0,
              "Point spacing of the reconstructed surfaces."),
    # --- scene segmentation ---------------------------------------------------------------
    ParamSpec("seg_voxel_size", 0.004, "m", 0.0005, 0.2,
              "Voxel edge of the working cloud used to segment the scene."),
    ParamSpec("seg_plane_threshold", 0.004, "m", 1e-5, 0.5,
              "Distance from a support plane (desk, floor, wall) within which points belong to "
              "it."),
    ParamSpec("seg_plane_normal_angle", 0.5, "rad", 0.01, 1.5,
              "Largest normal deviation of a support-plane point."),
    ParamSpec("seg_min_support_area", 0.1, "m^2", 0.0, 1000.0,
              "Smallest area of a plane treated as a support surface (desk, floor, wall)."),
    ParamSpec("seg_max_supports", 3, "count", 0, 20,
              "Most support planes extracted before objects are clustered."),
    ParamSpec("seg_concavity_tolerance", 0.1, "1", 0.0, 2.0,
              "Neighbours are not linked where (n_i - n_j).(p_i - p_j)/|p_i - p_j| is below minus "
              "this (a concave crease)."),
    ParamSpec("seg_max_edge_factor", 2.5, "1", 1.0, 20.0,
              "Neighbours farther apart than this many voxels are not linked (depth jumps)."),
    ParamSpec("seg_max_occlusion_gap", 0.15, "m", 0.0, 5.0,
              "Largest gap across which two parts of one surface hidden in the middle by a nearer "
              "object are joined (0 = never)."),
    ParamSpec("seg_join_contained", True, "", None, None,
              "Join a segment lying inside the footprint of a round segment (the inner wall of an "
              "open bowl or cup)."),
    ParamSpec("seg_min_cluster_points", 150, "count", 1, 10000000,
              "Clusters with fewer input points are noise (label -1)."),
    ParamSpec("seed", 0, "count", 0, 2**31 - 1,
              "Seed of the random generator used by RANSAC (results are reproducible)."),
    # --- noise model ----------------------------------------------------------------------
    ParamSpec("noise_model", "auto", "", None, None,
              "auto: estimate the depth noise and point spacing of every frame and raise the "
              "noise-dependent tolerances (noise_amplitude, ransac_threshold, voxel_size, "
              "seg_voxel_size, seg_plane_threshold, reconstruction_spacing) above the values "
              "given where the estimate needs it, per object at its depth, and leave small "
              "unknown fragments out of the objects; fixed: use every value exactly as given.",
              choices=("auto", "fixed")),
    # --- organized clouds -----------------------------------------------------------------
    ParamSpec("viewpoint", "auto", "", None, None,
              "Where the sensor is. auto: an organized cloud whose pixel grid is a pinhole "
              "camera's image but whose frame is not that camera's optical frame (a cloud "
              "transformed into a robot's base frame) is modeled in the camera's frame, "
              "recovered from the grid, and its objects are returned in the cloud's frame; "
              "every other cloud as origin. origin: the cloud's origin is the sensor (as "
              "camera drivers publish it).",
              choices=("auto", "origin")),
    ParamSpec("mixed_pixel_filter", False, "", None, None,
              "Leave out the mixed pixels of organized clouds before segmenting: returns "
              "between two surfaces at a depth edge (time-of-flight cameras' flying pixels, "
              "without the driver's own filter), which bridge objects to what lies behind "
              "them. Off by default: the Kinect-class frames measured have none, and the "
              "filter also takes some one- or two-pixel rims seen edge-on (BENCHMARKS.md)."),
    ParamSpec("decimation", 1, "count", 1, 8,
              "Organized clouds only: segment and model every decimation-th pixel of every "
              "decimation-th row (a camera's decimation filter without averaging), then give "
              "every pixel the label of its block's sample, or across a depth edge of the "
              "nearest sample around within a segmentation link (else -1); point counts count "
              "those pixels. For clouds denser than "
              "the segmentation needs (decimation x the point spacing at most half of "
              "seg_voxel_size, e.g. 1280 x 720 at a Kinect's field of view); on a 640 x 480 "
              "Kinect frame 2 takes a third off the time but under-segments clutter more "
              "(BENCHMARKS.md section 28). 1: every pixel."),
    ParamSpec("organized_fast_path", False, "", None, None,
              "Segment organized clouds (an image of H x W points) on the image grid: working "
              "points from pixel blocks, neighbours from a fixed pixel stencil, no voxel grid "
              "nor nearest-neighbour search (segmentation 1-1.9x faster on 640 x 480 Kinect "
              "frames, but it still under-segments more than the voxel path there, see "
              "BENCHMARKS.md); false: every cloud takes the voxel path."),
)

_SPECS: dict[str, ParamSpec] = {p.name: p for p in PARAMETERS}
#: Eq. 6 takes the noise amplitude t in millimetres.
_MM_PER_M = 1000.0


@dataclass(frozen=True, kw_only=True)
class ModelingParams:
    """Frozen set of modeling parameters (see :data:`PARAMETERS` for units and ranges).

    Construct with keyword arguments (unknown names, positional arguments, wrong types,
    out-of-range or inconsistent values raise :class:`ParameterError`) or
    :meth:`from_mapping`. The fields repeat the names, types and defaults of
    :data:`PARAMETERS` so that editors and type checkers see them; a test keeps the two
    identical.
    """

    # --- input ----------------------------------------------------------------------------
    max_range: float = 20.0
    max_points: int = 1000000

    # --- working resolution and faces -----------------------------------------------------
    voxel_size: float = 0.003
    max_working_points: int = 5000
    normal_neighbors: int = 16
    face_angle_threshold: float = 0.2
    edge_variation_threshold: float = 0.04
    min_face_points: int = 12
    min_object_points: int = 60

    # --- surface type (paper eqs. 1-6) ----------------------------------------------------
    cf_threshold: float = 0.82
    noise_amplitude: float = 0.0005
    cf_radius_fraction: float = 0.5

    # --- model graph ----------------------------------------------------------------------
    angle_tolerance: float = 0.14
    sphere_curvature_ratio: float = 0.45
    developable_curvature_ratio: float = 0.35
    cone_curvature_variation: float = 0.25

    # --- RANSAC and verification ----------------------------------------------------------
    ransac_threshold: float = 0.002
    ransac_normal_threshold: float = 0.5
    ransac_max_iterations: int = 500
    ransac_confidence: float = 0.995
    min_inlier_ratio: float = 0.8
    refine_max_points: int = 5000
    min_radius: float = 0.002
    max_radius: float = 2.0
    min_cone_half_angle: float = 0.05
    min_arc: float = 0.785

    # --- sizing and reconstruction --------------------------------------------------------
    edge_correction: bool = True
    reproject_along_rays: bool = True
    reconstruction_spacing: float = 0.002

    # --- scene segmentation ---------------------------------------------------------------
    seg_voxel_size: float = 0.004
    seg_plane_threshold: float = 0.004
    seg_plane_normal_angle: float = 0.5
    seg_min_support_area: float = 0.1
    seg_max_supports: int = 3
    seg_concavity_tolerance: float = 0.1
    seg_max_edge_factor: float = 2.5
    seg_max_occlusion_gap: float = 0.15
    seg_join_contained: bool = True
    seg_min_cluster_points: int = 150
    seed: int = 0

    # --- noise model ----------------------------------------------------------------------
    noise_model: str = "auto"

    # --- organized clouds -----------------------------------------------------------------
    viewpoint: str = "auto"
    mixed_pixel_filter: bool = False
    decimation: int = 1
    organized_fast_path: bool = False

    def __new__(cls, *args: Any, **kwargs: Any) -> ModelingParams:
        """Reject positional arguments and unknown names with a :class:`ParameterError`."""
        unknown = sorted(set(kwargs) - set(_SPECS))
        if unknown or args:
            what = f"unknown parameter(s) {', '.join(unknown)}" if unknown else \
                "parameters are keyword-only"
            raise ParameterError(f"{what}; known: {', '.join(sorted(_SPECS))}")
        return super().__new__(cls)

    def __post_init__(self) -> None:
        """Convert every value to its parameter's type and check ranges and consistency."""
        for spec in PARAMETERS:
            object.__setattr__(self, spec.name, spec.check(getattr(self, spec.name)))
        self.check_consistency()

    def check_consistency(self) -> None:
        """Raise :class:`ParameterError` when parameters contradict each other."""
        if self.min_radius >= self.max_radius:
            raise ParameterError(
                f"min_radius ({self.min_radius}) must be smaller than "
                f"max_radius ({self.max_radius})"
            )
        if self.developable_curvature_ratio >= self.sphere_curvature_ratio:
            raise ParameterError(
                "developable_curvature_ratio must be smaller than sphere_curvature_ratio "
                f"({self.developable_curvature_ratio} >= {self.sphere_curvature_ratio})"
            )

    @property
    def cf_weights(self) -> tuple[float, float, float]:
        """Weights w1, w2, w3 of eq. 6 with t = noise amplitude in millimetres."""
        e = math.exp(-self.noise_amplitude * _MM_PER_M)
        return (e, 1.0 - e, 2.0 * (1.0 - e))

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], base: "ModelingParams | None" = None
                     ) -> "ModelingParams":
        """Build parameters from ``values`` (missing names keep ``base``'s or default values)."""
        unknown = sorted(set(values) - set(_SPECS))
        if unknown:
            raise ParameterError(
                f"unknown parameter(s) {', '.join(unknown)}; known: {', '.join(sorted(_SPECS))}"
            )
        base = base if base is not None else cls()
        return dataclasses.replace(base, **dict(values))

    def to_dict(self) -> dict[str, Any]:
        return {p.name: getattr(self, p.name) for p in PARAMETERS}


def load_params_file(path: str | Path) -> ModelingParams:
    """Read parameters from YAML: a flat mapping or ROS ``node: {ros__parameters: {...}}``."""
    import yaml

    try:
        data = yaml.safe_load(Path(path).read_text())
    except OSError as exc:
        raise ParameterError(f"cannot read parameter file {path}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        where = getattr(exc, "problem_mark", None)
        at = f" (line {where.line + 1}, column {where.column + 1})" if where is not None else ""
        problem = getattr(exc, "problem", None) or "syntax error"
        raise ParameterError(f"parameter file {path} is not valid YAML{at}: {problem}") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ParameterError(
            f"parameter file {path} must hold a mapping, got {type(data).__name__}")
    # ROS 2 params-file layout: {node_name: {ros__parameters: {...}}}, node may be '/**'.
    for value in data.values():
        if isinstance(value, dict) and "ros__parameters" in value:
            data = value["ros__parameters"] or {}
            break
    return ModelingParams.from_mapping(data)
