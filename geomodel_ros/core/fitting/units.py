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
#: End of the cone unit's reason when its points stop short of the apex
#: (:func:`~.verify.check_apex`). A frustum is the same cone side sized between two
#: circles: every other check of the cone unit (inliers, axis, coverage, arc, half-angle,
#: bulk) applies to it unchanged, so after a cone rejected for another reason on the same
#: task the frustum is not tried (it would fail the same check, at the cost of a fit).
CONE_SHORT_OF_APEX = "(a frustum)"


def _skipped(kind: PrimitiveType, cone: Rejected | None) -> bool:
    """Whether ``kind`` is not worth trying after the task's cone rejection ``cone``."""
    return kind is PrimitiveType.FRUSTUM and cone is not None and \
        not cone.reason.endswith(CONE_SHORT_OF_APEX)


def fit_first(cloud: ObjectCloud, decision: GraphDecision,
              axis_prior: NDArray[np.float64] | None = None,
              rejected: list[Rejected] | None = None
              ) -> tuple[Primitive | None, list[str]]:
    """Try the decision's candidate types in order; the first that fits with finite sizes.

    Returns that primitive (None if none fits) and the reason of every attempt; every
    rejection is also appended to ``rejected`` when given. A frustum after a cone
    rejected for anything but stopping short of its apex is not tried
    (:data:`CONE_SHORT_OF_APEX`).
    """
    task = FitTask(cloud, decision.main_face, decision.axis_of_face, axis_prior)
    reasons = []
    cone: Rejected | None = None
    for name in decision.candidates:
        kind = PrimitiveType(name)
        if _skipped(kind, cone):
            continue
        try:
            outcome = FITTING_UNITS[kind](task)
        except NUMERICAL_FAILURES as exc:
            outcome = Rejected(kind, f"{kind}: numerical failure ({exc})")
        reasons.append(outcome.reason)
        if isinstance(outcome, Fitted) and is_finite_primitive(outcome.primitive):
            return outcome.primitive, reasons
        if rejected is not None and isinstance(outcome, Rejected):
            rejected.append(outcome)
        if kind is PrimitiveType.CONE and isinstance(outcome, Rejected):
            cone = outcome
    return None, reasons
