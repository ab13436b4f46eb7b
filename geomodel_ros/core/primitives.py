"""Result types of the modeling: faces and typed, sized primitives."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["PrimitiveType", "PRIMITIVE_TYPES", "DIMENSION_NAMES", "FaceSummary", "Primitive",
           "ModelingResult"]


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
    UNKNOWN = "unknown"

    def __str__(self) -> str:
        """Return the type's name (``"cone"``, not ``"PrimitiveType.CONE"``)."""
        return self.value

    def __format__(self, spec: str) -> str:
        """Format the type's name (f-strings and tables show ``cone``)."""
        return format(self.value, spec)


#: Types an object can be given, in the order of :class:`PrimitiveType`.
PRIMITIVE_TYPES: tuple[PrimitiveType, ...] = tuple(PrimitiveType)

#: Dimension names per type, all in metres.
DIMENSION_NAMES: dict[PrimitiveType, tuple[str, ...]] = {
    PrimitiveType.PLANE: ("length", "width"),
    PrimitiveType.CUBOID: ("length", "width", "height"),
    PrimitiveType.CYLINDER: ("radius", "height"),
    PrimitiveType.CONE: ("radius", "height"),
    PrimitiveType.SPHERE: ("radius",),
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
        Box centre (plane, cuboid), midpoint of the axis segment (cylinder, cone), centre
        (sphere); for ``unknown`` the centroid of the points.
    rotation : (3, 3) float64 array
        Columns are the object's x, y, z axes: z = plane normal / cylinder or cone axis
        (cone: base -> apex) / cuboid third axis. Identity for spheres and ``unknown``.
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

    def __post_init__(self) -> None:
        """Hold a known type name as its :class:`PrimitiveType`."""
        if isinstance(self.type, str) and not isinstance(self.type, PrimitiveType) and \
                self.type in _TYPE_BY_NAME:
            object.__setattr__(self, "type", _TYPE_BY_NAME[self.type])

    def to_dict(self) -> dict:
        """JSON-ready dictionary (the CLI's output schema)."""
        return {
            "id": int(self.id),
            "type": str(self.type),
            "center": [float(v) for v in self.center],
            "rotation": [[float(v) for v in row] for row in self.rotation],
            "dimensions": {k: float(v) for k, v in self.dimensions.items()},
            "point_count": int(self.point_count),
            "rmse": float(self.rmse),
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
    an object (their points are labelled -1).
    """

    objects: list[Primitive]
    timing: dict[str, float]
    supports: dict[int, tuple[NDArray[np.float64], float]] = field(default_factory=dict)
    noise: Any = None
    fragments: int = 0

    def to_dict(self) -> dict:
        """JSON-ready dictionary (the CLI's output schema)."""
        return {"objects": [o.to_dict() for o in self.objects],
                "noise": None if self.noise is None else self.noise.to_dict(),
                "fragments": int(self.fragments),
                "timing": {k: float(v) for k, v in self.timing.items()}}
