"""Result types of the modeling: faces and typed, sized primitives."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = ["PRIMITIVE_TYPES", "DIMENSION_NAMES", "FaceSummary", "Primitive", "ModelingResult"]

#: Types an object can be given; ``unknown`` when no rule of the model graph accepts it.
PRIMITIVE_TYPES = ("plane", "cuboid", "cylinder", "cone", "sphere", "unknown")

#: Dimension names per type, all in metres.
DIMENSION_NAMES: dict[str, tuple[str, ...]] = {
    "plane": ("length", "width"),
    "cuboid": ("length", "width", "height"),
    "cylinder": ("radius", "height"),
    "cone": ("radius", "height"),
    "sphere": ("radius",),
    "unknown": (),
}


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
    type : str
        One of :data:`PRIMITIVE_TYPES`.
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
    type: str
    center: NDArray[np.float64]
    rotation: NDArray[np.float64]
    dimensions: dict[str, float]
    point_count: int
    rmse: float
    faces: tuple[FaceSummary, ...] = ()
    reason: str = ""

    def to_dict(self) -> dict:
        """JSON-ready dictionary (the CLI's output schema)."""
        return {
            "id": int(self.id),
            "type": self.type,
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
    """All modeled objects of a scene and the time each stage took [s]."""

    objects: list[Primitive]
    timing: dict[str, float]

    def to_dict(self) -> dict:
        return {"objects": [o.to_dict() for o in self.objects],
                "timing": {k: float(v) for k, v in self.timing.items()}}
