"""Result types of the modeling: faces and typed, sized primitives."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

__all__ = ["PrimitiveType", "PRIMITIVE_TYPES", "DIMENSION_NAMES", "FaceSummary", "Confidence",
           "Primitive", "ModelingResult"]


class PrimitiveType(str, Enum):
    """Type of a modeled object; ``UNKNOWN`` when no rule of the model graph accepts it.

    A ``str`` whose value is the type's name: it compares and hashes equal to that name
    (``PrimitiveType.CONE == "cone"``), and prints, formats and serialises to JSON as it,
    so consumers that know the types by name keep working.
    """

    PLANE = "plane"
    CUBOID = "cuboid"
    CYLINDER = "cylinder"
    CONE = "cone"
    SPHERE = "sphere"
    FRUSTUM = "frustum"
    UNKNOWN = "unknown"

    def __str__(self) -> str:
        """Return the type's name (``"cone"``, not ``"PrimitiveType.CONE"``)."""
        return self.value

    def __format__(self, spec: str) -> str:
        """Format the type's name (f-strings and tables show ``cone``)."""
        return format(self.value, spec)


#: Types an object can be given, in the order of :class:`PrimitiveType`.
PRIMITIVE_TYPES: tuple[PrimitiveType, ...] = tuple(PrimitiveType)

#: Dimension names per type, all in metres. A frustum (truncated cone: cup, bowl, flower
#: pot, bucket) has ``radius`` at its base, the larger circle (the base of the cone it is
#: cut from), ``top_radius`` at the smaller circle, nearer the cone's apex, and ``height``
#: between the two along its axis.
DIMENSION_NAMES: dict[PrimitiveType, tuple[str, ...]] = {
    PrimitiveType.PLANE: ("length", "width"),
    PrimitiveType.CUBOID: ("length", "width", "height"),
    PrimitiveType.CYLINDER: ("radius", "height"),
    PrimitiveType.CONE: ("radius", "height"),
    PrimitiveType.SPHERE: ("radius",),
    PrimitiveType.FRUSTUM: ("radius", "top_radius", "height"),
    PrimitiveType.UNKNOWN: (),
}


_TYPE_BY_NAME: dict[str, PrimitiveType] = {t.value: t for t in PrimitiveType}


@dataclass(frozen=True)
class FaceSummary:
    """One smooth face of an object.

    Attributes
    ----------
    surface : str
        ``"planar"`` or ``"curved"`` (paper section 3.1).
    cf : float
        Normalised multi-scale CF of eq. 5 (divided by the sum of the weights), in [0, 1].
    point_count : int
        Input points on the face.
    normal : (3,) float64 array
        Unit normal at the face centre, oriented towards the sensor.
    """

    surface: str
    cf: float
    point_count: int
    normal: NDArray[np.float64] = field(repr=False)

    def to_dict(self) -> dict:
        return {"surface": self.surface, "cf": float(self.cf), "point_count": int(self.point_count)}


@dataclass(frozen=True)
class Confidence:
    """How far a modeled object's type and size can be trusted, and why.

    ``value = inlier_ratio * 1 / (1 + rmse_ratio**2) * min(1, coverage / 0.5)``, the last
    factor for round shapes only (:mod:`geomodel_ros.core.confidence`); 0 for ``unknown``.

    Attributes
    ----------
    value : float
        The confidence in [0, 1].
    inlier_ratio : float
        Share of the object's points within the noise scale of the fitted surface, [0, 1].
    rmse_ratio : float or None
        RMS distance to the fitted surface of the object's points near it (within three
        noise scales) divided by the noise scale [1]; None when nothing was fitted.
    coverage : float or None
        Cylinder, cone: share of the full circle round the axis that the side's points
        span; sphere: share of the sphere's directions (solid angle) they cover; in
        [0, 1], at most about 0.5 from one viewpoint. None for other types.
    """

    value: float = 0.0
    inlier_ratio: float = 0.0
    rmse_ratio: float | None = None
    coverage: float | None = None

    def to_dict(self) -> dict:
        """JSON-ready terms (the value itself is the object's ``confidence``)."""
        return {"inlier_ratio": float(self.inlier_ratio),
                "rmse_ratio": None if self.rmse_ratio is None else float(self.rmse_ratio),
                "coverage": None if self.coverage is None else float(self.coverage)}


@dataclass(frozen=True)
class Primitive:
    """A modeled object.

    Attributes
    ----------
    id : int
        Object id (the segmentation label).
    type : PrimitiveType
        The object's type. A string that names a type is converted to it on
        construction; any other value is kept as given (input from outside the modeling,
        e.g. markers read back, which consumers must guard against).
    center : (3,) float64 array [m]
        Box centre (plane, cuboid), midpoint of the axis segment (cylinder, cone,
        frustum), centre (sphere); for ``unknown`` the centroid of the points.
    rotation : (3, 3) float64 array
        Columns are the object's x, y, z axes: z = plane normal / cylinder, cone or
        frustum axis (cone: base -> apex; frustum: base (larger circle) -> top, i.e.
        towards the apex of its cone, so a cup standing on its smaller end has z pointing
        down) / cuboid third axis. Identity for spheres and ``unknown``.
    dimensions : dict[str, float]
        Sizes [m] named by :data:`DIMENSION_NAMES`.
    point_count : int
        Input points of the object.
    rmse : float
        Root mean square point-to-surface distance of the object's points [m]
        (NaN-free; 0 for ``unknown``).
    faces : tuple[FaceSummary, ...]
        The object's faces.
    reason : str
        Why the type was chosen or rejected (human readable).
    completed : tuple[str, ...]
        Names of the dimensions that were completed down to a support plane because the
        object's lower part was hidden (the others were observed).
    confidence : Confidence or None
        The modeling's confidence in type and size; None when not estimated (primitives
        built outside the modeling, e.g. read back from messages).
    round_alternative : callable or None
        Inside the modeling only (None on its output, not in :meth:`to_dict`): a plane's
        judge, called once the segmentation is done, of the model the plane gives way to,
        returning it or None (the round model of
        :func:`~geomodel_ros.core.fitting.strategies.round_of_plane`, else the solid of
        :func:`~geomodel_ros.core.fitting.top_face.solid_below_top`, else the box of
        :func:`~geomodel_ros.core.fitting.strategies.box_of_plane`).
    levels : tuple of Level
        Inside the modeling only (empty on its output, not in :meth:`to_dict`): the heights
        above a support where one body of the segment may stand on another
        (:func:`~geomodel_ros.core.fitting.levels.object_levels`), for the segment's split
        (:func:`~geomodel_ros.core.compounds.split_compounds`).
    """

    id: int
    type: PrimitiveType
    center: NDArray[np.float64]
    rotation: NDArray[np.float64]
    dimensions: dict[str, float]
    point_count: int
    rmse: float
    faces: tuple[FaceSummary, ...] = ()
    reason: str = ""
    completed: tuple[str, ...] = ()
    confidence: Confidence | None = None
    round_alternative: Callable[[], Primitive | None] | None = field(default=None, repr=False,
                                                                     compare=False)
    levels: tuple = field(default=(), repr=False, compare=False)

    def __post_init__(self) -> None:
        """Hold a known type name as its :class:`PrimitiveType`."""
        if isinstance(self.type, str) and not isinstance(self.type, PrimitiveType) and \
                self.type in _TYPE_BY_NAME:
            object.__setattr__(self, "type", _TYPE_BY_NAME[self.type])

    def to_dict(self) -> dict:
        """JSON-ready dictionary (the CLI's output schema).

        ``completed`` lists the dimensions completed down to a support (the others were
        observed); ``confidence`` is the value in [0, 1] (null when not estimated) and
        ``confidence_terms`` its terms (:meth:`Confidence.to_dict`).
        """
        conf = self.confidence
        return {
            "id": int(self.id),
            "type": str(self.type),
            "center": [float(v) for v in self.center],
            "rotation": [[float(v) for v in row] for row in self.rotation],
            "dimensions": {k: float(v) for k, v in self.dimensions.items()},
            "completed": list(self.completed),
            "point_count": int(self.point_count),
            "rmse": float(self.rmse),
            "confidence": None if conf is None else float(conf.value),
            "confidence_terms": None if conf is None else conf.to_dict(),
            "faces": [f.to_dict() for f in self.faces],
            "reason": self.reason,
        }


@dataclass
class ModelingResult:
    """All modeled objects of a scene, the time each stage took [s] and the support planes.

    ``supports`` maps the id of each support plane the segmentation found (desk, floor,
    wall) to its plane ``(normal (3,), d [m])``, ``n . x + d = 0`` with the normal towards
    the sensor; empty when the objects were modeled from given labels. ``noise`` is the
    frame's :class:`~geomodel_ros.core.noise.NoiseEstimate` (None with ``noise_model =
    fixed``); ``fragments`` counts the segments left out of ``objects`` as too small to be
    an object (their points are labelled -1); ``supported`` maps each support's id to the
    ids of the objects resting on it (:mod:`geomodel_ros.core.resting`). ``sensor`` is the
    camera recovered from an organized cloud's pixel grid when the cloud was not in that
    camera's optical frame (:class:`~geomodel_ros.core.viewpoint.SensorPose`; everything
    else is then in the cloud's own frame), else None.
    """

    objects: list[Primitive]
    timing: dict[str, float]
    supports: dict[int, tuple[NDArray[np.float64], float]] = field(default_factory=dict)
    noise: Any = None
    fragments: int = 0
    supported: dict[int, list[int]] = field(default_factory=dict)
    sensor: Any = None

    def to_dict(self) -> dict:
        """JSON-ready dictionary (the CLI's output schema)."""
        return {"objects": [o.to_dict() for o in self.objects],
                "noise": None if self.noise is None else self.noise.to_dict(),
                "sensor": None if self.sensor is None else self.sensor.to_dict(),
                "fragments": int(self.fragments),
                "timing": {k: float(v) for k, v in self.timing.items()}}
