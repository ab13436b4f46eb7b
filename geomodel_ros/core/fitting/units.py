"""The fitting units by primitive type, and the runner that tries a list of candidates."""

from __future__ import annotations

import math
from typing import Mapping, Protocol

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.fitting.cloud import ObjectCloud
from geomodel_ros.core.fitting.cone import CONE_TOO_NARROW, fit_cone, least_half_angle
from geomodel_ros.core.fitting.cuboid import fit_cuboid
from geomodel_ros.core.fitting.cylinder import fit_cylinder
from geomodel_ros.core.fitting.frustum import fit_frustum
from geomodel_ros.core.fitting.plane import fit_plane
from geomodel_ros.core.fitting.result import (FitOutcome, FitTask, Fitted, Rejected,
                                              is_finite_primitive)
from geomodel_ros.core.fitting.sphere import fit_sphere
from geomodel_ros.core.model_graph import GraphDecision
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import Primitive, PrimitiveType

__all__ = ["FittingUnit", "FITTING_UNITS", "fit_first", "narrow_frustum"]

CYLINDER = PrimitiveType.CYLINDER
FRUSTUM = PrimitiveType.FRUSTUM


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


def _skipped(kind: PrimitiveType, cone: Rejected | None, params: ModelingParams) -> bool:
    """Whether ``kind`` is not worth trying after the task's cone rejection ``cone``.

    A cone rejected as too narrow leaves the frustum its own taper test where the frustum
    has no least half-angle (:func:`~.cone.least_half_angle`).
    """
    if kind is not PrimitiveType.FRUSTUM or cone is None:
        return False
    if cone.reason.endswith(CONE_SHORT_OF_APEX):
        return False
    return not (cone.reason.endswith(CONE_TOO_NARROW)
                and least_half_angle(params, kind) < params.min_cone_half_angle)


def fit_first(cloud: ObjectCloud, decision: GraphDecision,
              axis_prior: NDArray[np.float64] | None = None,
              rejected: list[Rejected] | None = None
              ) -> tuple[Primitive | None, list[str]]:
    """Try the decision's candidate types in order; the first that fits with finite sizes.

    Returns that primitive (None if none fits) and the reason of every attempt; every
    rejection is also appended to ``rejected`` when given. A frustum after a cone
    rejected for anything but stopping short of its apex (or, where the frustum has no
    least half-angle, being too narrow) is not tried (:data:`CONE_SHORT_OF_APEX`). A
    side that tapers by less than ``min_cone_half_angle`` is a cylinder wherever a
    cylinder holds it: after a cone rejected as that narrow, the frustum is tried after
    the cylinder, and a frustum fitted that narrow (:func:`narrow_frustum`) is taken only
    once the cylinder is rejected.
    """
    task = FitTask(cloud, decision.main_face, decision.axis_of_face, axis_prior)
    reasons = []
    order = [PrimitiveType(name) for name in decision.candidates]
    cone: Rejected | None = None
    held: Primitive | None = None
    while order:
        kind = order.pop(0)
        if _skipped(kind, cone, cloud.params) or (held is not None and kind is not CYLINDER):
            continue
        try:
            outcome = FITTING_UNITS[kind](task)
        except NUMERICAL_FAILURES as exc:
            outcome = Rejected(kind, f"{kind}: numerical failure ({exc})")
        reasons.append(outcome.reason)
        if isinstance(outcome, Fitted) and is_finite_primitive(outcome.primitive):
            if held is None and CYLINDER in order and \
                    narrow_frustum(outcome.primitive, cloud.params):
                held = outcome.primitive
                reasons.append("narrower than the least cone half-angle: the cylinder first")
                continue
            return outcome.primitive, reasons
        if rejected is not None and isinstance(outcome, Rejected):
            rejected.append(outcome)
        if kind is PrimitiveType.CONE and isinstance(outcome, Rejected):
            cone = outcome
            if outcome.reason.endswith(CONE_TOO_NARROW) and FRUSTUM in order and \
                    CYLINDER in order and order.index(FRUSTUM) < order.index(CYLINDER):
                order.remove(FRUSTUM)
                order.insert(order.index(CYLINDER) + 1, FRUSTUM)
    return held, reasons


def narrow_frustum(prim: Primitive, params: ModelingParams) -> bool:
    """Whether ``prim`` is a frustum whose half-angle is below ``min_cone_half_angle``."""
    if prim.type is not PrimitiveType.FRUSTUM:
        return False
    d = prim.dimensions
    taper = d["radius"] - d["top_radius"]
    return math.atan2(taper, d["height"]) < params.min_cone_half_angle
