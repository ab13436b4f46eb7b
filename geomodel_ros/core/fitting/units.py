"""The fitting units by primitive type, and the runner that tries a list of candidates."""

from __future__ import annotations

from typing import Mapping, Protocol

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.fitting.cloud import ObjectCloud
from geomodel_ros.core.fitting.cone import fit_cone
from geomodel_ros.core.fitting.cuboid import fit_cuboid
from geomodel_ros.core.fitting.cylinder import fit_cylinder
from geomodel_ros.core.fitting.frustum import fit_frustum
from geomodel_ros.core.fitting.plane import fit_plane
from geomodel_ros.core.fitting.result import (FitOutcome, FitTask, Fitted, Rejected,
                                              is_finite_primitive)
from geomodel_ros.core.fitting.sphere import fit_sphere
from geomodel_ros.core.model_graph import GraphDecision
from geomodel_ros.core.primitives import Primitive, PrimitiveType

__all__ = ["FittingUnit", "FITTING_UNITS", "fit_first"]


class FittingUnit(Protocol):
    """Fit -> verify -> size -> orient one primitive type to an object."""

    def __call__(self, task: FitTask) -> FitOutcome:
        """Return the fitted primitive or the rejection with its reason."""


#: One unit per type the model graph proposes.
FITTING_UNITS: Mapping[PrimitiveType, FittingUnit] = {
    PrimitiveType.PLANE: fit_plane,
    PrimitiveType.CUBOID: fit_cuboid,
    PrimitiveType.CYLINDER: fit_cylinder,
    PrimitiveType.CONE: fit_cone,
    PrimitiveType.SPHERE: fit_sphere,
    PrimitiveType.FRUSTUM: fit_frustum,
}

#: Numerical failures of a unit (singular systems, degenerate least squares) that reject
#: its type instead of failing the object.
NUMERICAL_FAILURES = (np.linalg.LinAlgError, ValueError, FloatingPointError)


def fit_first(cloud: ObjectCloud, decision: GraphDecision,
              axis_prior: NDArray[np.float64] | None = None
              ) -> tuple[Primitive | None, list[str]]:
    """Try the decision's candidate types in order; the first that fits with finite sizes.

    Returns that primitive (None if none fits) and the reason of every attempt.
    """
    task = FitTask(cloud, decision.main_face, decision.axis_of_face, axis_prior)
    reasons = []
    for name in decision.candidates:
        kind = PrimitiveType(name)
        try:
            outcome = FITTING_UNITS[kind](task)
        except NUMERICAL_FAILURES as exc:
            outcome = Rejected(kind, f"{kind}: numerical failure ({exc})")
        reasons.append(outcome.reason)
        if isinstance(outcome, Fitted) and is_finite_primitive(outcome.primitive):
            return outcome.primitive, reasons
    return None, reasons
