"""Typed outcome of a fitting unit: a fitted primitive or a rejection with its reason."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Union

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.fitting.cloud import ObjectCloud
from geomodel_ros.core.primitives import Primitive, PrimitiveType

__all__ = ["Fitted", "Rejected", "FitOutcome", "FitTask", "is_finite_primitive"]


@dataclass(frozen=True)
class Fitted:
    """A primitive that was fitted, verified, sized and oriented.

    Attributes
    ----------
    primitive : Primitive
        The result (without faces and reasons: the modeling adds those).
    reason : str
        Why it was accepted (e.g. ``"cylinder verified"``).
    """

    primitive: Primitive
    reason: str


@dataclass(frozen=True)
class Rejected:
    """A type that did not fit.

    Attributes
    ----------
    type : PrimitiveType
        The type that was tried.
    reason : str
        Why it was rejected (human readable, kept in the object's ``reason``).
    misfit : bool
        The model was found but does not explain the object's points: too few inliers
        on it, too few of the points on it, or its points scatter about it beyond the
        measured depth noise (:mod:`~.verify`): the data are not this shape.
    """

    type: PrimitiveType
    reason: str
    misfit: bool = False


#: What every fitting unit returns.
FitOutcome = Union[Fitted, Rejected]


@dataclass(frozen=True)
class FitTask:
    """An object and what the model graph (or a fallback strategy) tells its fitting unit.

    Attributes
    ----------
    cloud : ObjectCloud
        The object.
    main_face : int
        Index of the main (or auxiliary) matching face, -1 if none.
    axis_of_face : tuple[int, ...]
        Cuboids: the box axis (0, 1, 2) of every face, -1 for slivers that fit none.
    axis_prior : (3,) float64 array or None
        Direction a cylinder's or cone's axis must follow (within ``angle_tolerance``);
        None: the main planar face's normal, if there is one.
    """

    cloud: ObjectCloud
    main_face: int = -1
    axis_of_face: tuple[int, ...] = ()
    axis_prior: NDArray[np.float64] | None = None


def is_finite_primitive(primitive: Primitive) -> bool:
    """Return True when every number of ``primitive`` is finite and every size positive."""
    vals = [*primitive.center.ravel(), *primitive.rotation.ravel(),
            *primitive.dimensions.values(), primitive.rmse]
    return bool(np.all(np.isfinite(vals))) and all(v > 0 for v in primitive.dimensions.values())
